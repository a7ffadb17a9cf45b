"""Constraint-space QP of the inverse model (paper §IV, eq. 13).

After the projection into constraint space (``solver.inverse.space``) the inverse step is a
small dense problem in the actuator efforts ``λ`` (n actuators, m = 3·effectors rows)::

    δe(λ) = δe_free + W_ea λ            predicted effector gaps         (paper eq. 11)
    δa(λ) = δa_free + W_aa λ            predicted actuator displacements (paper eq. 12)

    minimise   ½ ‖Wₑ^{1/2} δe(λ)‖²  +  ½ ρ Σᵢ dᵢ λᵢ²                 (paper eq. 13 + regulariser)
               [ + ½ δ s Σᵢ dᵢ (λᵢ − λ0ᵢ)² ]                            (damping, when asked)
    subject to λ_lower ≤ λ ≤ λ_upper,   δa_lower ≤ δa(λ) ≤ δa_upper

The regulariser makes the answer unique when ``W_eaᵀ W_ea`` is only semi-definite
(16 tendons, one 3-D target). It is the **actuation energy** each actuator spends on its own
displacement, ``dᵢ λᵢ² = |W_aa,ii| λᵢ²`` (joules whatever the actuator: N·m for a cable,
Pa·m³ for a chamber), so it is invariant to the units of each actuator and homogeneous across
mixed cable/chamber actuation. ``ρ = ε·s`` with a dimensionless ``ε`` (default 1e-8) and
``s = meanᵢ(Hᵢᵢ/dᵢ)`` (m²/J; ``H`` the weighted Hessian of the effector term): every ratio
``Hᵢᵢ/dᵢ`` has the same units for every actuator, and a mean does not grow with the number of
actuators. Without ``W_aa``, ``dᵢ = Hᵢᵢ`` (Marquardt scaling). ``ε`` biases the fixed point of
the converged inverse by ≈ ε × (effector motion) ≪ 1e-6 m (``benchmarks/bench_qp.py``) and
leaves the active-set solver a Hessian of condition ≲ 1/ε.

A problem may ask for Levenberg–Marquardt **damping** ``δ`` (dimensionless, scaled like ``ε``):
it penalises the change from the current actuation ``λ0``, so that directions the effectors
barely feel to first order (a straight trunk's effector moves along its axis only by
compressing it) do not take large efforts that the linearisation cannot vouch for. It is
centred on ``λ0``, so a converged fixed point (λ = λ0) is not biased by it.

**Least effort** (``slack`` given, the controller's default ``effort="least"``): the weight ``ε``
above trades effector error for effort, so it stays tiny (1e-8, only to keep the problem
definite and off directions the effectors barely feel). A second QP then picks, among the
efforts that keep every effector row of the first answer within ``slack`` (m),
``|W_ea (λ − λ₁)| ≤ slack``, the one of least actuation energy ``½ Σᵢ dᵢ λᵢ²`` (same box and
displacement rows; :func:`least_effort_form`): redundant actuators are released instead of
co-contracting, and the error is the first stage's. A damped first stage (a tick's) stays
near ``λ0``; the second does not, within the tick's box.

:func:`solve_constraint_problem` builds the :func:`quadratic_form` in the coordinates its
backend asks for (``solver.inverse.backends``), solves it, clips the answer into the λ box
and returns a :class:`ConstraintSolution`; :meth:`ConstraintSolution.diagnostics` computes the
objective, stationarity and active sets when asked.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.inverse.backends import DEFAULT_BACKEND, QPBackend, get_backend
from vertebra.solver.inverse.space import ConstraintProblem, _read_only

__all__ = ["QuadraticForm", "quadratic_form", "ConstraintSolution", "QPDiagnostics", "solve_constraint_problem"]


@dataclass
class QuadraticForm:
    """``½ λᵀPλ + qᵀλ + c`` with box ``lower ≤ λ ≤ upper`` and rows ``row_lower ≤ G λ ≤ row_upper``
    (only the actuator-displacement rows with a finite bound, actuators ``rows``).

    In the Jacobi-scaled coordinates ``y = λ / scale`` when built with ``scaled`` (``scale =
    1/√Pᵢᵢ``, unit diagonal; rows normalised to unit largest entry), else ``scale`` is ones.
    ``regularisation_weight`` (ρ) and ``energy_diagonal`` (d) are those of ``λ``. ``feasibility``:
    how far an active-set backend may leave a constraint (the form's units; None: its default).
    """

    P: np.ndarray
    q: np.ndarray
    c: float
    lower: np.ndarray
    upper: np.ndarray
    G: np.ndarray
    row_lower: np.ndarray
    row_upper: np.ndarray
    rows: np.ndarray
    regularisation_weight: float
    energy_diagonal: np.ndarray
    scale: np.ndarray
    feasibility: float | None = None


_NO_ROWS: dict = {}  # n -> the (0, n) matrix and (0,) bounds of a box-only problem (no entries to change)
_ONES: dict = {}     # n -> read-only ones(n): the scale of unscaled forms, and row sums


def _no_rows(n: int) -> tuple:
    rows = _NO_ROWS.get(n)
    if rows is None:
        rows = _NO_ROWS[n] = (np.zeros((0, n)), np.zeros(0), np.zeros(0))
    return rows


def _ones(n: int) -> np.ndarray:
    ones = _ONES.get(n)
    if ones is None:
        ones = _ONES[n] = _read_only(np.ones(n))
    return ones


def quadratic_form(problem: ConstraintProblem, displacement_bounds=None, *, scaled: bool = False) -> QuadraticForm:
    """The QP of paper eq. 13 with the energy regulariser (module docstring).
    ``displacement_bounds`` (lower, upper) replace the space's limits (same finite entries)."""
    space = problem.space
    de, W_ea = problem.delta_e_free, problem.W_ea
    if space.unit_weights:
        P = W_ea.T.dot(W_ea)
        q = W_ea.T.dot(de)
        c = 0.5 * float(de.dot(de))
    else:
        w = space.effector_weights
        Wsq = W_ea * w[:, None]
        P = W_ea.T.dot(Wsq)
        q = Wsq.T.dot(de)
        c = 0.5 * float(de.dot(w * de))
    n = P.shape[0]
    diagonal = P.reshape(-1)[:: n + 1]  # a view of P's diagonal (P is a new C-contiguous array)
    d = energy_diagonal(problem, diagonal)
    s = float((diagonal / d).dot(_ones(n))) / n  # the mean of Hᵢᵢ/dᵢ
    if not s > 0:
        s = 1.0
    rho = space.regularisation * s
    # Levenberg–Marquardt damping of the change from λ0, when asked: ½ δ s Σ dᵢ (λᵢ − λ0ᵢ)²
    damping = problem.damping * s
    diagonal += (rho + damping) * d  # P = H + (ρ + δ s) diag(d), symmetric by construction (Wᵀ diag(w) W)
    if damping:
        pull = (damping * d) * problem.lambda0
        q -= pull                   # (q is this function's own array)
        c += 0.5 * float(pull.dot(problem.lambda0))
    lower, upper = problem.lambda_lower, problem.lambda_upper
    rows = space.rows
    if rows.size:
        dlo, dhi = (space.displacement_lower, space.displacement_upper) if displacement_bounds is None \
            else displacement_bounds
        G = problem.W_aa[rows]
        row_lower = dlo[rows] - problem.delta_a_free[rows]
        row_upper = dhi[rows] - problem.delta_a_free[rows]
    else:
        G, row_lower, row_upper = _no_rows(n)
    if scaled:
        root = np.sqrt(diagonal)
        scale = 1.0 / root
        P *= scale[:, None] * scale  # P and q are this function's own arrays
        q *= scale
        lower, upper = lower * root, upper * root
        if rows.size:
            G, row_lower, row_upper = _unit_rows(G * scale, row_lower, row_upper)
    else:
        scale = _ones(n)
    return QuadraticForm(P, q, c, lower, upper, G, row_lower, row_upper, rows, rho, d, scale)


def energy_diagonal(problem: ConstraintProblem, diagonal: np.ndarray | None = None) -> np.ndarray:
    """The actuation-energy weights ``dᵢ = |W_aa,ii|`` of the regulariser (module docstring;
    without ``W_aa``: ``diagonal``, the effector Hessian's), floored at 1e-12 of the largest so
    that an actuator with no own displacement stays regularised. A new array."""
    d = np.abs(problem.W_aa.diagonal()) if problem.W_aa is not None else diagonal.copy()
    values = d.tolist()     # (finite, a problem's arrays are; few: Python's min and max beat numpy's reductions)
    dmax = max(values)
    floor = 1e-12 * dmax if dmax > 0 else 1.0
    if min(values) < floor:
        d = np.maximum(d, floor)
    return d


def _unit_rows(G: np.ndarray, row_lower: np.ndarray, row_upper: np.ndarray) -> tuple:
    """Rows ``row_lower ≤ G y ≤ row_upper`` (``G``: this caller's own array) normalised to a
    largest entry of 1 per row."""
    unit = 1.0 / np.maximum.reduce(np.abs(G), axis=1, initial=1e-300)
    G *= unit[:, None]
    return G, row_lower * unit, row_upper * unit


@dataclass
class QPDiagnostics:
    """Optimality of a constraint-space solution (:meth:`ConstraintSolution.diagnostics`)."""

    objective: float  # of the regularised QP at the answer
    stationarity: float  # projected-gradient step in effector units (m): 0 at a box-QP optimum; NaN with rows
    active_lower: np.ndarray  # bool (n,): within 1e-9 (relative) of the bound
    active_upper: np.ndarray
    active_displacement_lower: np.ndarray
    active_displacement_upper: np.ndarray


@dataclass
class ConstraintSolution:
    """Result of one constraint-space solve: the efforts, the linear prediction at them, and how
    the backend fared. :meth:`diagnostics` gives the objective, stationarity and active sets."""

    actuation: np.ndarray  # λ (n,), inside the λ box
    delta_e: np.ndarray  # predicted effector gaps (m,)
    delta_a: np.ndarray | None  # predicted actuator displacements (n,)
    effector_error: float  # ‖δe‖ (m), unweighted
    iterations: int
    converged: bool
    status: str  # "optimal" | "max_iterations" | "relaxed" | backend status
    backend: str
    time_s: float
    displacement_relaxation: np.ndarray  # how far infeasible displacement limits were widened (n,; read-only zeros if not)
    regularisation_weight: float
    problem: ConstraintProblem = field(repr=False, compare=False)
    displacement_bounds: tuple = field(repr=False, compare=False)  # the (possibly widened) limits solved with

    def diagnostics(self) -> QPDiagnostics:
        """Objective, stationarity and active bounds at :attr:`actuation` (computed on each call)."""
        problem, lam = self.problem, self.actuation
        form = quadratic_form(problem, self.displacement_bounds)
        g = form.P @ lam + form.q
        objective = 0.5 * float(lam @ (g + form.q)) + form.c
        lo, hi = problem.lambda_lower, problem.lambda_upper
        # "active" = within 1e-9 of the bound, relative to the bound or the effort itself
        atol = 1e-9 * np.maximum(np.abs(lam), np.where(np.isfinite(lo), np.abs(lo), 0.0)) + 1e-300
        n = lam.size
        active_dlo = active_dhi = np.zeros(n, dtype=bool)
        if form.rows.size:
            dlo, dhi = self.displacement_bounds
            da = self.delta_a
            atol_d = 1e-9 * np.abs(da) + 1e-300
            active_dlo, active_dhi = da <= dlo + atol_d, da >= dhi - atol_d
            stationarity = math.nan
        else:
            diag = form.P.diagonal()
            projected = np.clip(lam - g / diag, lo, hi)
            stationarity = float(np.max(np.abs(projected - lam) * np.sqrt(diag)))
        return QPDiagnostics(objective, stationarity, lam <= lo + atol, lam >= hi - atol, active_dlo, active_dhi)


def _least_violating(problem: ConstraintProblem):
    """Closest reachable actuator displacements when the displacement limits cannot all hold.

    Bounded least squares (``scipy.optimize.lsq_linear``) over λ in its box and a point ``t``
    in the displacement box: ``min ‖δa_free + W_aa λ − t‖²``. Returns the best λ and ``δa`` there.
    """
    from scipy.optimize import lsq_linear

    space, n = problem.space, problem.n_actuators
    A = np.hstack([problem.W_aa, -np.eye(n)])
    # scale columns so that λ (N or Pa) and t (m or m³) are comparable for the solver
    col = np.maximum(np.abs(A).max(axis=0), 1e-300)
    lb = np.concatenate([problem.lambda_lower, space.displacement_lower]) * col
    ub = np.concatenate([problem.lambda_upper, space.displacement_upper]) * col
    res = lsq_linear(A / col, -problem.delta_a_free, bounds=(lb, ub), method="bvls", tol=1e-14)
    lam = np.clip(res.x[:n] / col[:n], problem.lambda_lower, problem.lambda_upper)
    return lam, problem.delta_a_free + problem.W_aa @ lam


def _breaks(da, dlo, dhi):
    """Displacements below/above their limits beyond 1e-9 relative."""
    slack = 1e-9 * np.maximum(np.abs(da), np.abs(np.where(np.isfinite(dlo), dlo, 0.0))) + 1e-300
    return da < dlo - slack, da > dhi + slack


def _feasible_start(problem: ConstraintProblem, start: np.ndarray):
    """A start meeting the displacement limits, and the limits to solve with: the warm start if it
    meets them, else the least-violating λ; limits it cannot meet are widened to it (relaxed)."""
    space = problem.space
    dlo, dhi = space.displacement_lower, space.displacement_upper
    below, above = _breaks(problem.predict(start)[1], dlo, dhi)
    if not (below.any() or above.any()):
        return start, (dlo, dhi), None
    start, da = _least_violating(problem)
    below, above = _breaks(da, dlo, dhi)
    if not (below.any() or above.any()):
        return start, (dlo, dhi), None
    relaxation = np.where(below, dlo - da, 0.0) + np.where(above, da - dhi, 0.0)
    return start, (np.where(below, da, dlo), np.where(above, da, dhi)), relaxation


_ZEROS: dict = {}  # n -> read-only zeros(n): no relaxation, the least-effort stage's linear term


def _zeros(n: int) -> np.ndarray:
    zeros = _ZEROS.get(n)
    if zeros is None:
        zeros = _ZEROS[n] = _read_only(np.zeros(n))
    return zeros


def least_effort_form(problem: ConstraintProblem, first: np.ndarray, slack, displacement_bounds, *,
                      scaled: bool = False, energy: np.ndarray | None = None) -> QuadraticForm:
    """The second stage of the least-effort QP (module docstring): ``½ Σᵢ dᵢ λᵢ²`` (d the
    actuation-energy diagonal of :func:`quadratic_form`, normalised to its largest entry) over
    the λ box, the displacement rows and the effector rows ``|W_ea (λ − first)| ≤ slack`` (m per
    row): the efforts that keep every effector row of the first stage's answer ``first``.
    ``energy``: the first stage's ``energy_diagonal`` (computed here when not given)."""
    space = problem.space
    n, W = problem.n_actuators, problem.W_ea
    if energy is None:
        energy = energy_diagonal(problem, np.einsum("ij,ij->j", W, W))
    d = energy * (1.0 / max(energy.tolist()))
    np.maximum(d, 1e-12, out=d)
    reached = W.dot(first)
    dlo, dhi = displacement_bounds
    rows = space.rows
    if rows.size:
        G = np.concatenate([problem.W_aa[rows], W])
        row_lower = np.concatenate([dlo[rows] - problem.delta_a_free[rows], reached - slack])
        row_upper = np.concatenate([dhi[rows] - problem.delta_a_free[rows], reached + slack])
    else:
        G, row_lower, row_upper = W, reached - slack, reached + slack
    lower, upper = problem.lambda_lower, problem.lambda_upper
    if scaled:
        root = np.sqrt(d)
        scale = 1.0 / root
        P = _identity(n)
        lower, upper = lower * root, upper * root
        G, row_lower, row_upper = _unit_rows(G * scale, row_lower, row_upper)
    else:
        P = np.diag(d)
        G = G.copy() if G is W else G
        scale = _ones(n)
    # (its linear term: the same read-only zeros at every call, as the scaled Hessian is one identity)
    return QuadraticForm(P, _zeros(n), 0.0, lower, upper, G, row_lower, row_upper, rows, 0.0, d, scale,
                         LEAST_EFFORT_FEASIBILITY)


# how far the least-effort stage's answer may leave its rows (unit rows in the scaled form; DAQP's
# default, 1e-6, is ~10 % of the effector rows' band of 2·slack): tight, so that the answer is the
# stage's optimum to rounding whichever working set DAQP starts from (its model's last one)
LEAST_EFFORT_FEASIBILITY = 1e-9


_IDENTITY: dict = {}  # n -> read-only identity(n)


def _identity(n: int) -> np.ndarray:
    eye = _IDENTITY.get(n)
    if eye is None:
        eye = _IDENTITY[n] = _read_only(np.eye(n))
    return eye


def solve_constraint_problem(problem: ConstraintProblem, backend: str | QPBackend = DEFAULT_BACKEND, *,
                             tolerance: float = 1e-10, absolute_tolerance: float = 0.0,
                             max_iterations: int | None = None, slack: float | None = None) -> ConstraintSolution:
    """Solve one inverse step; the answer never leaves the λ box.

    ``backend`` is a registered name or a :class:`~solver.inverse.backends.QPBackend`.
    ``tolerance`` (iterative backends) is relative to the weighted free gap
    ``‖Wₑ^{1/2} δe_free‖``: Gauss–Seidel stops when no sweep moves the effectors by more than
    ``tolerance`` times it, or by more than ``absolute_tolerance`` (m). When the displacement
    limits cannot all be met inside the λ box (linearisation error next to a stroke limit), they
    are widened by the least amount that makes them feasible, ``status`` says ``"relaxed"`` and
    ``displacement_relaxation`` by how much. An unreachable target needs nothing special: the QP
    returns the closest reach and ``effector_error`` says how far it is.

    A backend object kept between calls may carry state from one solve to the next: DAQP's
    solves the least-effort stage from the working set its last such solve left
    (:class:`~vertebra.solver.inverse.backends.DaqpBackend`).
    """
    t0 = time.perf_counter()
    solver = get_backend(backend) if isinstance(backend, str) else backend
    lower, upper = problem.lambda_lower, problem.lambda_upper
    start = problem.start()
    bounds, relaxation = None, None
    space = problem.space
    if space.rows.size:
        start, bounds, relaxation = _feasible_start(problem, start)
    form = quadratic_form(problem, bounds, scaled=solver.scaled)
    tol = max(tolerance * math.sqrt(2.0 * form.c), absolute_tolerance, 1e-300)
    budget = solver.default_max_iterations if max_iterations is None else max_iterations
    out = solver.solve(form, start / form.scale, tolerance=tol, max_iterations=budget)
    lam = np.minimum(np.maximum(out.actuation * form.scale, lower), upper)
    iterations, status, converged = out.iterations, out.status, out.converged
    limits = (space.displacement_lower, space.displacement_upper) if bounds is None else bounds
    if slack is not None and converged:
        # second stage: the least effort among the efforts that keep the first stage's effector gaps
        second = least_effort_form(problem, lam, slack, limits, scaled=solver.scaled,
                                   energy=form.energy_diagonal if problem.W_aa is not None else None)
        out2 = solver.solve(second, lam / second.scale, tolerance=tol, max_iterations=budget)
        iterations += out2.iterations
        if out2.converged:
            lam = np.minimum(np.maximum(out2.actuation * second.scale, lower), upper)
    de, da = problem.predict(lam)
    relaxed = relaxation is not None
    return ConstraintSolution(
        actuation=lam, delta_e=de, delta_a=da, effector_error=math.sqrt(de.dot(de)), iterations=iterations,
        converged=converged, status="relaxed" if (relaxed and converged) else status,
        backend=solver.name, time_s=time.perf_counter() - t0,
        displacement_relaxation=relaxation if relaxed else _zeros(lam.size),
        regularisation_weight=form.regularisation_weight, problem=problem, displacement_bounds=limits)
