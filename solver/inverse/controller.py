"""Inverse simulation of a trunk (paper §IV): linearise → constraint space → QP → step.

At a state ``q`` with actuation ``λ0`` the runtime model gives the out-of-balance force
``r``, the banded factor of ``K``, the actuator forces ``B`` and the Jacobians ``Ja``,
``Je`` (docs/solver-api.md). One multi-right-hand-side banded solve
``[K⁻¹r, K⁻¹B]`` (cost linear in frames × actuators) gives everything::

    dq(λ)  = K⁻¹ r + K⁻¹B (λ − λ0)                                  (paper eq. 10)
    δe(λ)  = e − target + Je K⁻¹ r − W_ea λ0 + W_ea λ,  W_ea = Je K⁻¹ B  (paper eq. 11)
    δa(λ)  = a + Ja K⁻¹ r − W_aa λ0 + W_aa λ,           W_aa = Ja K⁻¹ B  (paper eq. 12)

The QP (``solver.inverse.qp``, paper eq. 13) is posed in the *total* actuation λ, so its
bounds are the actuator limits and its regulariser the actuation energy. Then either

* **tick** (real time): ``state ← model.step(state, dq(λ))`` — one Newton-like update per
  control tick; the next tick's ``K⁻¹ r`` term corrects the remaining imbalance; or
* **converged** (static inverse): ``model.solve(λ, initial=step)`` to equilibrium, then
  linearise again, until the effector error is within tolerance or stops falling.

Both warm-start from the previous state, actuation and QP solution along a trajectory.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg.lapack import dpbtrs as _dpbtrs

from vertebra.solver.banded import BandedFactor
from vertebra.solver.inverse.qp import (
    DEFAULT_BACKEND,
    DEFAULT_REGULARISATION,
    ConstraintProblem,
    ConstraintSolution,
    solve_constraint_problem,
)
from vertebra.store.errors import ConvergenceError

__all__ = ["InverseSettings", "InverseStep", "InverseController", "constraint_problem", "invert", "MODES"]


@dataclass(frozen=True)
class InverseSettings:
    """Knobs of the inverse. ``tolerance`` is the effector error (m) counted as reached."""

    mode: str = "converged"
    backend: str = DEFAULT_BACKEND
    regularisation: float = DEFAULT_REGULARISATION
    tolerance: float = 1e-6
    max_iterations: int = 30  # outer linearise–QP–solve iterations (converged mode)
    patience: int = 3  # converged mode gives up after this many iterations without progress …
    progress: float = 0.01  # … where progress means cutting the best error by this fraction
    actuation_tolerance: float = 1e-4  # … and, reached or not, once λ changes by less than this (relative)
    settle_iterations: int = 3  # extra iterations allowed, once reached, for λ to settle
    qp_tolerance: float = 1e-10

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {sorted(MODES)}, got {self.mode!r}")
        if not (self.tolerance > 0 and math.isfinite(self.tolerance)):
            raise ValueError(f"tolerance must be a positive length (m), got {self.tolerance}")
        if not (math.isfinite(self.regularisation) and self.regularisation >= 0):
            raise ValueError(f"regularisation must be finite and ≥ 0, got {self.regularisation}")
        if not (self.qp_tolerance > 0):
            raise ValueError(f"qp_tolerance must be > 0, got {self.qp_tolerance}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be ≥ 1, got {self.max_iterations}")
        if not (0.0 < self.progress < 1.0) or self.patience < 1:
            raise ValueError(f"need 0 < progress < 1 and patience ≥ 1, got {self.progress}, {self.patience}")


@dataclass
class InverseStep:
    """Outcome of one inverse step (one target), with diagnostics."""

    actuation: np.ndarray  # (n_act,) cables then chambers
    state: object  # solver.State
    targets: np.ndarray  # (n_eff, 3)
    positions: np.ndarray  # (n_eff, 3) effector positions at ``state``
    errors: np.ndarray  # (n_eff,) |position − target| (m)
    displacements: np.ndarray  # (n_act,) actuator displacements at ``state`` (tick: linearised prediction)
    reached: bool  # every error ≤ tolerance
    equilibrium: bool  # ``state`` is a converged equilibrium (converged mode)
    iterations: int  # outer iterations
    qp: ConstraintSolution  # last QP
    timings: dict = field(default_factory=dict)  # linearise_s, W_s, qp_s, step_s, solve_s, total_s
    status: str = ""
    actuation_change: float = math.nan  # relative change of λ in the last iteration (converged mode)


def constraint_problem(lin, targets: np.ndarray, actuation: np.ndarray, *, weights: np.ndarray,
                       lambda_bounds, displacement_bounds, regularisation: float,
                       lambda0: np.ndarray | None = None):
    """Project a linearisation into constraint space (paper eqs. 10–12).

    Returns ``(problem, K⁻¹r, K⁻¹B, timings)``. One banded solve with ``1 + n_act``
    right-hand sides; ``W_ea`` uses only the rows of ``K⁻¹[r, B]`` that the effector
    Jacobian touches (the effectors' frames).
    """
    t0 = time.perf_counter()
    X, W_ea, delta_e_free, W_aa, delta_a_free, t1, _, _ = _project(lin, targets, actuation)
    problem = ConstraintProblem(
        W_ea=W_ea, delta_e_free=delta_e_free,
        lambda_lower=lambda_bounds[0], lambda_upper=lambda_bounds[1],
        effector_weights=np.repeat(weights, 3), W_aa=W_aa, delta_a_free=delta_a_free,
        displacement_lower=displacement_bounds[0], displacement_upper=displacement_bounds[1],
        lambda0=actuation if lambda0 is None else lambda0, regularisation=regularisation,
    )
    t2 = time.perf_counter()
    return problem, X[:, 0], X[:, 1:], {"solve_KB_s": t1 - t0, "W_s": t2 - t0}


def _project(lin, targets, actuation, full=False):
    """The arrays of :func:`constraint_problem`: ``X = K⁻¹[r, B]``, ``W_ea``, ``δe_free``,
    ``W_aa``, ``δa_free``, the time the banded solve ended and ``Je X``, ``Ja X``.
    ``Je X`` takes the nonzero columns of ``Je`` (the effector frames' DoFs) and the rows of
    ``X`` they meet, or with ``full`` (the controller) every column: the other products are
    exact zeros, which leave the sums as they are, and the search is saved."""
    X = _solve_rhs(lin)
    t1 = time.perf_counter()
    Je = lin.effector_jacobian
    if full:
        JeX = Je @ X
    else:
        columns = np.flatnonzero(np.any(Je != 0.0, axis=0))  # the effector frames' DoFs only
        JeX = Je[:, columns] @ X.take(columns, axis=0)
    JaX = lin.actuator_jacobian @ X
    W_ea, W_aa = JeX[:, 1:], JaX[:, 1:]
    # e − target + Je K⁻¹r − W_ea λ0 (and a + Ja K⁻¹r − W_aa λ0), left to right in new arrays
    delta_e_free = (lin.effector_positions - targets).reshape(-1)
    delta_e_free += JeX[:, 0]
    delta_e_free -= W_ea @ actuation
    delta_a_free = lin.actuator_displacements + JaX[:, 0]
    delta_a_free -= W_aa @ actuation
    return X, W_ea, delta_e_free, W_aa, delta_a_free, t1, JeX, JaX


def _solve_rhs(lin):
    """``X = K⁻¹[r, B]``: ``lin.solve`` of the stacked right-hand sides, or for a banded
    Cholesky factor the same LAPACK call (``dpbtrs``, what ``BandedFactor.solve`` makes) on a
    Fortran-ordered stack it may overwrite: no copies or wrappers (same numbers, same layout)."""
    B = lin.actuator_forces
    factor = lin.factor
    direct = type(factor) is BandedFactor and factor.kind == "cholesky"
    rhs = np.empty((B.shape[0], 1 + B.shape[1]), order="F" if direct else "C")
    rhs[:, 0] = lin.residual
    rhs[:, 1:] = B
    if not direct:
        return lin.solve(rhs)
    X, info = _dpbtrs(factor.data, rhs, lower=1, overwrite_b=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"banded solve failed (LAPACK info {info})")
    return X


class InverseController:
    """Runs the inverse on one compiled model; keeps state and actuation between targets
    (warm start along a trajectory). Build once, call :meth:`step` many times.

    ``lambda_bounds``, ``displacement_bounds`` and ``weights`` are read-only copies of the
    model's: they are validated once and reused every step while they stay the same
    objects (assign new arrays to change them)."""

    def __init__(self, model, settings: InverseSettings | None = None, *, actuation=None, state=None):
        self.model = model
        self.settings = settings or InverseSettings()
        n_act = len(model.actuator_names)
        if n_act == 0:
            raise ValueError("the scene has no actuators (cables or chambers) to invert for")
        if len(model.effector_names) == 0:
            raise ValueError("the scene has no effectors to bring to targets")
        lo, hi = (_frozen(b) for b in model.actuator_bounds)
        self.lambda_bounds = (lo, hi)
        self.displacement_bounds = tuple(_frozen(b) for b in model.displacement_bounds)
        start = np.zeros(n_act) if actuation is None else np.asarray(actuation, dtype=float)
        self.actuation = np.clip(start, lo, hi)
        self.state = (state or model.rest_state).copy()
        self.equilibrium = False
        self.weights = _frozen(model.effector_weights)
        self._hot = None  # what every step reuses (see _constraint_problem)

    # ------------------------------------------------------------------ pieces
    def _errors(self, positions, targets):
        d = positions - targets
        d *= d
        s = np.add.reduce(d, axis=1)
        return np.sqrt(s, out=s)  # np.linalg.norm(d, axis=1) without its wrapper (nor new arrays)

    def _constraint_problem(self, lin, targets):
        """:func:`constraint_problem` for this controller (same arrays, same errors). The
        bounds, weights and regulariser are validated with the first linearisation and
        reused while they stay the same objects; later problems only check that their new
        arrays are finite (:meth:`ConstraintProblem._relinearised`)."""
        t0 = time.perf_counter()
        hot = self._hot
        if (hot is None or hot.model is not self.model or hot.lambda_bounds is not self.lambda_bounds
                or hot.displacement_bounds is not self.displacement_bounds or hot.weights is not self.weights
                or hot.regularisation != self.settings.regularisation):
            hot = self._hot = _HotPath(self)
        X, W_ea, delta_e_free, W_aa, delta_a_free, t1, JeX, JaX = _project(lin, targets, self.actuation, full=True)
        problem = (None if hot.template is None else
                   hot.template._relinearised(W_ea, delta_e_free, W_aa, delta_a_free, self.actuation,
                                              (JeX, JaX), owned=True))
        if problem is None:  # first step, or arrays needing the validation (which raises as usual)
            lo, hi = self.lambda_bounds
            dlo, dhi = self.displacement_bounds
            problem = hot.template = ConstraintProblem(
                W_ea=W_ea, delta_e_free=delta_e_free, lambda_lower=lo, lambda_upper=hi,
                effector_weights=np.repeat(self.weights, 3), W_aa=W_aa, delta_a_free=delta_a_free,
                displacement_lower=dlo, displacement_upper=dhi, lambda0=self.actuation,
                regularisation=self.settings.regularisation)
        t2 = time.perf_counter()
        return problem, X[:, 0], X[:, 1:], {"solve_KB_s": t1 - t0, "W_s": t2 - t0}

    def _linearised_step(self, targets, timings):
        """linearise → W → QP at the current state/actuation. Returns (qp solution, dq)."""
        t0 = time.perf_counter()
        lin = self.model.linearise(self.state, self.actuation)
        t1 = time.perf_counter()
        problem, Kr, KB, t_w = self._constraint_problem(lin, targets)
        sol = solve_constraint_problem(problem, self.settings.backend, tolerance=self.settings.qp_tolerance)
        t2 = time.perf_counter()
        dq = Kr + KB @ (sol.actuation - self.actuation)
        if timings:  # converged mode: summed over the iterations
            timings["linearise_s"] = timings.get("linearise_s", 0.0) + (t1 - t0)
            timings["W_s"] = timings.get("W_s", 0.0) + t_w["W_s"]
            timings["qp_s"] = timings.get("qp_s", 0.0) + sol.time_s
            timings["inverse_s"] = timings.get("inverse_s", 0.0) + (t2 - t0)
        else:
            timings.update(linearise_s=t1 - t0, W_s=t_w["W_s"], qp_s=sol.time_s, inverse_s=t2 - t0)
        return sol, dq

    def _result(self, targets, sol, iterations, timings, t_start, equilibrium, status=""):
        positions = self.model.effector_positions(self.state)
        errors = self._errors(positions, targets)
        tolerance = self.settings.tolerance
        reached = True
        for e in errors.tolist():  # a few effectors: Python floats beat two numpy calls
            if not e <= tolerance:  # (NaN: not reached)
                reached = False
                break
        # tick: the QP's linearised prediction at the stepped state (the model's own
        # evaluation cost 0.1 ms of a ~2 ms tick); converged: the model's value
        displacements = (sol.delta_a.copy() if not equilibrium and sol is not None and sol.delta_a is not None
                         else self.model.actuator_displacements(self.state, self.actuation))
        timings["total_s"] = time.perf_counter() - t_start
        step = object.__new__(InverseStep)  # every field given: the generated __init__ only assigns them
        step.__dict__.update(
            actuation=self.actuation.copy(), state=self.state, targets=targets.copy(),
            positions=positions, errors=errors, displacements=displacements, reached=reached,
            equilibrium=equilibrium, iterations=iterations, qp=sol, timings=timings, status=status,
            actuation_change=math.nan)
        return step

    # ------------------------------------------------------------------ modes
    def tick(self, targets) -> InverseStep:
        """One linearise–QP–step (real-time mode): no Newton solve; ``state`` is the
        linearised prediction, not an equilibrium (the next tick corrects it)."""
        targets = self._targets(targets)
        t_start = time.perf_counter()
        timings: dict = {}
        sol, dq = self._linearised_step(targets, timings)
        t0 = time.perf_counter()
        self.state = self.model.step(self.state, dq)
        self.actuation = sol.actuation
        self.equilibrium = False
        timings["step_s"] = time.perf_counter() - t0
        return self._result(targets, sol, 1, timings, t_start, False, status="tick")

    def converge(self, targets) -> InverseStep:
        """Static inverse: repeat linearise → QP → equilibrium solve until the effectors are
        within tolerance or the error stops falling (unreachable: closest reach)."""
        targets = self._targets(targets)
        t_start = time.perf_counter()
        timings: dict = {"solve_s": 0.0}
        s = self.settings
        if not self.equilibrium:
            self._equilibrate(self.actuation, self.state, timings)
        error = float(np.max(self._errors(self.model.effector_positions(self.state), targets)))
        best, idle, reached_for, change = error, 0, 0, math.nan
        sol, status, iterations = None, "max_iterations", 0
        for iterations in range(1, s.max_iterations + 1):
            sol, dq = self._linearised_step(targets, timings)
            lam_old, state_old = self.actuation, self.state
            new_error = math.inf
            # what the linear model promises (a bound may force it above the current error)
            predicted = float(np.max(np.linalg.norm(sol.delta_e.reshape(-1, 3), axis=1)))
            acceptable = max(error, 1.1 * predicted + s.tolerance)
            # Backtrack on the actuation change when the linear prediction overshoots
            # (large steps) or the equilibrium solve fails.
            for fraction in (1.0, 0.5, 0.25, 0.125, 0.0625):
                lam = lam_old + fraction * (sol.actuation - lam_old)
                guess = self.model.step(state_old, fraction * dq)
                try:
                    self._equilibrate(lam, guess, timings)
                except ConvergenceError:
                    try:  # the stepped guess may be poor: start from the last equilibrium
                        self._equilibrate(lam, state_old, timings)
                    except ConvergenceError:
                        self.actuation, self.state = lam_old, state_old
                        continue
                new_error = float(np.max(self._errors(self.model.effector_positions(self.state), targets)))
                if new_error <= acceptable or fraction == 0.0625:
                    break
            if not math.isfinite(new_error):
                status = "equilibrium_failed"
                self.actuation, self.state = lam_old, state_old
                break
            error = new_error
            # Relative change of the actuation. Reaching the target is not enough: in the
            # redundant null space the effort settles on the unique regularised fixed point
            # only when λ stops moving (so the answer does not depend on the path taken).
            change = float(np.max(np.abs(self.actuation - lam_old)) /
                           max(np.max(np.abs(self.actuation)), np.max(np.abs(lam_old)), 1e-300))
            settled = change <= s.actuation_tolerance
            if error <= s.tolerance:
                status = "reached"
                reached_for += 1
                # In the redundant null space the Gauss–Newton fixed point of the regularised
                # problem can cycle (the neglected curvature of e(λ) times the µm residual is
                # of the order of the tiny regulariser): allow a few iterations to settle,
                # then keep the last reached λ (docs/inverse.md, "uniqueness").
                if settled or reached_for > s.settle_iterations:
                    break
                continue
            if error < (1.0 - s.progress) * best:
                best, idle = error, 0
            else:
                idle += 1
                if (idle >= s.patience and settled) or idle >= 3 * s.patience:
                    status = "closest_reach"  # the error stopped falling: unreachable or a bound binds
                    break
            status = "max_iterations"
        result = self._result(targets, sol, iterations, timings, t_start, self.equilibrium, status=status)
        result.actuation_change = change
        return result

    def step(self, targets) -> InverseStep:
        """One step in the configured mode."""
        return MODES[self.settings.mode](self, targets)

    def track(self, trajectory) -> list[InverseStep]:
        """Targets (n_steps, n_eff, 3) in order, warm-starting each step from the last."""
        trajectory = np.asarray(trajectory, dtype=float)
        return [self.step(t) for t in trajectory]

    # ------------------------------------------------------------------ helpers
    def _equilibrate(self, actuation, guess, timings):
        t0 = time.perf_counter()
        try:
            result = self.model.solve(actuation, initial=guess)
        finally:
            timings["solve_s"] = timings.get("solve_s", 0.0) + time.perf_counter() - t0
        self.actuation = np.asarray(actuation, dtype=float).copy()
        self.state = result.state
        self.equilibrium = True

    def _targets(self, targets) -> np.ndarray:
        n_eff = len(self.model.effector_names)
        if type(targets) is np.ndarray and targets.dtype == np.float64 and targets.size == 3 * n_eff:
            t = targets.reshape(n_eff, 3)
            flat = t.reshape(-1)
            total = flat.dot(flat)
            if math.isfinite(total):  # all finite (a NaN or ±inf makes the sum of squares non-finite)
                return t
        t = np.asarray(targets, dtype=float).reshape(n_eff, 3) if np.size(targets) == 3 * n_eff else None
        if t is None:
            raise ValueError(f"targets must hold {n_eff}×3 values (effectors "
                             f"{', '.join(self.model.effector_names)}), got shape {np.shape(targets)}")
        if not np.isfinite(t).all():
            bad = [self.model.effector_names[k] for k in np.flatnonzero(~np.isfinite(t).all(axis=1))]
            raise ValueError(f"effector(s) {', '.join(bad)} have no target")
        return t


MODES = {"converged": InverseController.converge, "tick": InverseController.tick}


def _frozen(values) -> np.ndarray:
    """A read-only float copy."""
    a = np.array(values, dtype=float)
    a.flags.writeable = False
    return a


class _HotPath:
    """What every step of one controller reuses while its model, bounds, weights and
    regulariser stay the same: the last validated problem."""

    def __init__(self, controller):
        self.model = controller.model
        self.lambda_bounds = controller.lambda_bounds
        self.displacement_bounds = controller.displacement_bounds
        self.weights = controller.weights
        self.regularisation = controller.settings.regularisation
        self.template = None


def invert(model, targets=None, *, actuation=None, state=None, **settings) -> InverseStep:
    """One inverse solve on ``model`` (converged mode unless ``mode="tick"``): the
    actuation bringing the effectors to ``targets`` (default: the scene's targets).
    ``settings`` are :class:`InverseSettings` fields."""
    controller = InverseController(model, InverseSettings(**settings), actuation=actuation, state=state)
    return controller.step(model.effector_targets if targets is None else targets)
