"""A canonical constraint-space problem shared by the QP tests and benchmarks (target paths on
robots: ``solver.gallery.targets``)."""

from __future__ import annotations

import numpy as np


def synthetic_problem(seed, n_act=16, n_rows=3, n_dof=60, reach=0.5):
    """A tendon-like constraint-space problem ``(W_ea, δe_free, W_aa, λ_target)`` from a random
    SPD stiffness; ``reach`` < 1 makes the target reachable with λ ≥ 0."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n_dof, n_dof))
    K = A @ A.T + n_dof * np.eye(n_dof)
    Ja = rng.normal(size=(n_act, n_dof)) * 1e-2
    Je = rng.normal(size=(n_rows, n_dof))
    Kinv_B = np.linalg.solve(K, -Ja.T)
    W_ea, W_aa = Je @ Kinv_B, Ja @ Kinv_B
    lam_target = rng.uniform(0.0, 10.0, n_act)
    return W_ea, -(W_ea @ lam_target) * reach, W_aa, lam_target
