"""Lightweight runtime solver: trunks of frames and compliance links (numpy/scipy only).

Errors raised here are exported with it: :class:`ConvergenceError` (a solve failed; carries the
partial result) and the input errors (:class:`InputError` and its kinds, each naming the source,
field and reason), all :class:`VertebraError`.
"""

from vertebra.core.lie import pose_matrix
from vertebra.solver.model import Linearisation, State, StaticResult, TrunkModel, build_model
from vertebra.solver.scene import Scene, load_scene, parse_scene
from vertebra.core.errors import (CatalogueError, ConvergenceError, InputError, OptionError, SceneError,
                                   SpecError, TrajectoryError, VertebraError)

__all__ = ["CatalogueError", "ConvergenceError", "InputError", "Linearisation", "OptionError", "Scene",
           "SceneError", "SpecError", "State", "StaticResult", "TrajectoryError", "TrunkModel", "VertebraError",
           "build_model", "load_scene", "parse_scene", "pose_matrix"]
