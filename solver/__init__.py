"""Lightweight runtime solver: trunks of frames and compliance links (numpy/scipy only)."""

from vertebra.solver.model import Linearisation, State, StaticResult, TrunkModel, build_model
from vertebra.solver.scene import Scene, load_scene, parse_scene

__all__ = ["Linearisation", "Scene", "State", "StaticResult", "TrunkModel", "build_model",
           "load_scene", "parse_scene"]
