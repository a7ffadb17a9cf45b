"""Inverse simulation (paper §IV, eqs. 9–13): constraint-space QP and the controller.

``qp`` needs only numpy/scipy (and a QP library, imported lazily);
``controller`` drives a ``solver.TrunkModel`` (linearise → W → QP → step).
"""

from vertebra.solver.inverse.controller import InverseController, InverseSettings, InverseStep, invert
from vertebra.solver.inverse.qp import (
    BACKENDS,
    DEFAULT_BACKEND,
    DEFAULT_REGULARISATION,
    ConstraintProblem,
    ConstraintSolution,
    QPBackend,
    available_backends,
    get_backend,
    quadratic_form,
    register_backend,
    solve_constraint_problem,
)

__all__ = [
    "InverseController",
    "InverseSettings",
    "InverseStep",
    "invert",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "DEFAULT_REGULARISATION",
    "ConstraintProblem",
    "ConstraintSolution",
    "QPBackend",
    "available_backends",
    "get_backend",
    "quadratic_form",
    "register_backend",
    "solve_constraint_problem",
]
