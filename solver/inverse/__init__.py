"""Inverse simulation (paper §IV, eqs. 9–13): the actuation that brings effectors to targets.

``space`` (constraint space: bounds, weights, regulariser; the projection of a linearisation),
``qp`` (the QP and its driver), ``backends`` (QP solvers behind one Protocol and one registry)
and ``trajectory`` need only numpy/scipy (and a QP library, imported when first used);
``controller`` drives a ``solver.TrunkModel`` (linearise → project → QP → step).
"""

from vertebra.solver.inverse.backends import (
    BACKENDS,
    DEFAULT_BACKEND,
    BackendOutput,
    QPBackend,
    available_backends,
    get_backend,
    register_backend,
)
from vertebra.solver.inverse.controller import InverseController, InverseSettings, InverseStep, invert
from vertebra.solver.inverse.qp import ConstraintSolution, QPDiagnostics, QuadraticForm, quadratic_form, solve_constraint_problem
from vertebra.solver.inverse.space import DEFAULT_REGULARISATION, ConstraintProblem, ConstraintSpace, Projection

__all__ = [
    "InverseController",
    "InverseSettings",
    "InverseStep",
    "invert",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "DEFAULT_REGULARISATION",
    "BackendOutput",
    "ConstraintProblem",
    "ConstraintSolution",
    "ConstraintSpace",
    "Projection",
    "QPBackend",
    "QPDiagnostics",
    "QuadraticForm",
    "available_backends",
    "get_backend",
    "quadratic_form",
    "register_backend",
    "solve_constraint_problem",
]
