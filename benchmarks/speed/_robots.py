"""What the speed benchmarks share: the gallery robots and their actuations."""

from __future__ import annotations

import numpy as np

# the gallery robots of the inverse tick (tendon robots of the paper and a two-section one)
TICK_SCENES = ("paper_3v_4t", "paper_5v_16t", "tendon_two_section")


def model_of(name: str):
    from vertebra import solver
    from vertebra.solver.gallery import load

    return solver.build_model(load(name))


def active_actuation(model) -> np.ndarray:
    """The scene's actuation, or (when it is all zero, as in the paper scenes) 3 N on every
    fourth cable (one tendon per termination group, bending the trunk to one side)."""
    a = np.array(model.default_actuation, dtype=float)
    if not np.any(a):
        a[:model.n_cables:4] = 3.0
    return a


def tick_start(model):
    """The fixed state of the tick benchmarks: 0.3 N (clipped to the bounds) on every actuator,
    its equilibrium, and targets 1 mm off the effectors there."""
    lo, hi = model.actuator_bounds
    lam = np.clip(np.full(len(model.actuator_names), 0.3), lo, hi)
    state = model.solve(lam).state
    return lam, state, model.effector_positions(state) + 1e-3


def circle_targets(centre: np.ndarray, n: int, radius: float = 1e-3, per_turn: int = 100) -> np.ndarray:
    """``n`` targets on a circle of ``radius`` in x–y around every effector of ``centre``, one
    turn per ``per_turn`` targets."""
    angles = 2 * np.pi * np.arange(n) / per_turn
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    return centre[None] + radius * ring[:, None]
