"""Quasi-static equilibrium (paper eq. 9) by Newton's method with line search and load stepping.

* Each Newton direction solves the tangent's banded factor (:class:`~vertebra.solver.assembly.Tangent`):
  Cholesky of its symmetric part when loads are conservative, LU when dead moments make it
  unsymmetric; when a direction is rejected the factor is retried with ``H + μ·|diag H|``.
* Backtracking (Armijo) line search on an energy-like merit: the total potential minus the
  linearised work of dead moments (differences within 1e-12 of the potential count as rounding).
* Automatic load stepping: the load factor's increment halves when a stage fails and doubles
  when it succeeds; intermediate stages converge to 1e-6; a stage without progress for 20
  iterations is abandoned early.
* Only stable equilibria: when Newton reached an equilibrium through indefinite tangents and
  loads are conservative, it is accepted only if its own tangent is positive definite.
* Steps are applied by the strain-space retraction (:func:`~vertebra.solver.state.retract`).

Residuals are measured as max(|force|, |moment| / L) / F over the free frames, with F the
largest out-of-balance load at the rest pose under the full load and L the trunk's length:
dimensionless and invariant under a change of units.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.energy import LoadCase, evaluate, tangent
from vertebra.solver.state import State, retract
from vertebra.store.errors import ConvergenceError

SHIFTS = (0.0, 1e-8, 1e-6, 1e-4, 1e-2, 1.0)     # μ of the factors tried for one Newton direction
RESOLUTION = 1e-13     # corrections below this fraction of the extent (and radians) are rounding


@dataclass
class StaticResult:
    """Outcome of a forward solve, with its diagnostics."""

    converged: bool
    iterations: int
    residual: float
    state: State
    actuation: np.ndarray
    residual_history: list = field(default_factory=list)
    load_steps: int = 1
    factorization: str = "cholesky"
    timings: dict = field(default_factory=dict)
    rounding_limited: bool = False   # stopped because the Newton correction fell below the
                                     # floating-point resolution of the poses (residual is rounding)

    def __repr__(self) -> str:
        tip = ", ".join(f"{v:.6g}" for v in self.state.positions[-1])
        return (f"StaticResult(converged={self.converged}, iterations={self.iterations}, "
                f"residual={self.residual:.3g}, load_steps={self.load_steps}, tip=[{tip}] m)")


def residual_weights(trunk) -> np.ndarray:
    """Per-DoF weights of the residual measure: 1 for forces, 1/L for moments."""
    return np.array([1.0] * 3 + [1.0 / trunk.frames.length_scale] * 3)


def residual_norm(residual: np.ndarray, reference: float, weights: np.ndarray) -> float:
    """max(|force|, |moment| / length scale) / reference over the frames (``weights``:
    :func:`residual_weights`)."""
    return float(np.abs(residual.reshape(-1, 6) * weights).max() / reference)


def _force_scale(trunk, gradient: np.ndarray) -> float:
    free = gradient[1:]
    return max(np.max(np.abs(free[:, :3]), initial=0.0),
               np.max(np.abs(free[:, 3:]), initial=0.0) / trunk.frames.length_scale)


def is_stable(trunk, ev, memo, matrix=None) -> bool:
    """Is the equilibrium of ``ev`` stable: is its tangent (``matrix`` when already assembled)
    positive definite? Only decidable for conservative loads (dead moments make the tangent
    unsymmetric): then assumed so."""
    if trunk.loads.has_dead_moments:
        return True
    return (matrix or tangent(trunk, ev, memo)).factor()[1] == "cholesky"


def reference_force(trunk, actuation: np.ndarray, memo) -> float:
    """Force scale of the problem: the out-of-balance load at the rest pose under the full load."""
    def compute():
        load = memo.load_case(actuation, 1.0)
        return _force_scale(trunk, evaluate(trunk, trunk.rest_state, load, memo).gradient)
    return memo.reference_force(actuation, compute)


class _Stage:
    """One Newton run at a fixed load factor: its inputs and what it found."""

    def __init__(self, trunk, memo, load: LoadCase, tolerance: float, max_iterations: int, reference: float,
                 history: list, kinds: set):
        self.trunk, self.memo, self.load = trunk, memo, load
        self.tolerance, self.max_iterations = tolerance, max_iterations
        self.reference = reference            # force scale at this load factor
        self.history = history
        self.kinds = kinds                    # factor kinds used, and "rounding-limited" / "unstable" flags
        self.weights = residual_weights(trunk)
        self._resolution = np.ones(6)         # per-DoF scale of a correction (translations: 1/extent)

    def norm(self, ev) -> float:
        return residual_norm(ev.gradient[1:], self.reference, self.weights)

    def stable(self, ev, matrix=None) -> bool:
        return is_stable(self.trunk, ev, self.memo, matrix)

    def below_resolution(self, state: State, dq: np.ndarray) -> bool:
        """Is every translation below 1e-13 of the extent and every rotation below 1e-13 rad?"""
        weights = self._resolution
        weights[:3] = 1.0 / (self.trunk.frames.length_scale + float(np.abs(state.positions).max()))
        return float(np.abs(dq.reshape(-1, 6) * weights).max()) <= RESOLUTION


def _newton(stage: _Stage, state: State):
    """Newton iterations at a fixed load factor. Returns (ok, state, iterations, residual).

    The tangent is assembled only where a Newton step is taken (not at the converged state).
    An equilibrium reached through indefinite tangents is accepted only when its own tangent
    is positive definite: a saddle is not a quasi-static answer, and the caller then steps the
    load from the last stable state instead."""
    trunk, memo, load, kinds = stage.trunk, stage.memo, stage.load, stage.kinds
    symmetric = not trunk.loads.has_dead_moments
    ev = evaluate(trunk, state, load, memo)
    r = -ev.gradient[1:].reshape(-1)
    residual = stage.norm(ev)
    moments = load.dead[1:, 3:].reshape(-1) if trunk.loads.has_dead_moments else None
    best, best_at = residual, 0
    last_kind = "cholesky"
    for iteration in range(stage.max_iterations + 1):
        stage.history.append(residual)
        if not math.isfinite(residual):
            return False, state, iteration, residual
        if residual <= stage.tolerance:
            if last_kind != "cholesky" and not stage.stable(ev):
                kinds.add("unstable")
                return False, state, iteration, residual
            return True, state, iteration, residual
        if residual < 0.5 * best:
            best, best_at = residual, iteration
        if iteration == stage.max_iterations or iteration - best_at > 20:
            break     # out of iterations, or no progress for 20 iterations: smaller load step
        accepted = False
        matrix = tangent(trunk, ev, memo)
        for shift in SHIFTS:
            factor, kind = matrix.factor(shift, symmetric=symmetric)
            if factor is None:
                continue
            dq = factor.solve(r)
            if stage.below_resolution(state, dq):
                # the correction is below the floating-point resolution of the poses: the
                # residual left is rounding, not error; stop here and report it as it is
                if kind != "cholesky" and not stage.stable(ev, matrix):
                    kinds.add("unstable")
                    return False, state, iteration, residual
                kinds.add(kind)
                kinds.add("rounding-limited")
                return True, state, iteration, residual
            slope = -float(r @ dq)
            if slope >= 0.0 and shift == 0.0 and kind != "cholesky":
                continue      # indefinite tangent: the pure Newton step is no descent direction
            alpha = 1.0
            while alpha > 1e-3:
                trial = retract(state, dq if alpha == 1.0 else alpha * dq, ev.links)
                ev_trial = evaluate(trunk, trial, load, memo)
                res_trial = stage.norm(ev_trial)
                work = 0.0 if moments is None else alpha * float(moments @ dq.reshape(-1, 6)[:, 3:].reshape(-1))
                merit_ok = ev_trial.energy - work <= ev.energy + 1e-4 * alpha * slope + 1e-12 * abs(ev.energy)
                if math.isfinite(res_trial) and merit_ok:
                    accepted = True
                    break
                alpha *= 0.5
            if accepted:
                kinds.add(kind)
                last_kind = kind
                break
        if not accepted:
            return False, state, iteration + 1, residual
        state, ev, residual = trial, ev_trial, res_trial
        r = -ev.gradient[1:].reshape(-1)
    return False, state, iteration, residual


def solve(trunk, memo, actuation: np.ndarray, initial: State | None, *, tolerance: float,
          max_iterations: int, load_steps: int, raise_on_failure: bool = True) -> StaticResult:
    """Equilibrium under ``actuation`` from ``initial`` (a warm start; None: the rest state, with
    the load stepped in ``load_steps`` stages). Raises :class:`ConvergenceError` (carrying the
    partial result) on failure unless ``raise_on_failure`` is False."""
    start = time.perf_counter()
    reference = reference_force(trunk, actuation, memo)
    history, kinds = [], set()
    state = (initial or trunk.rest_state).copy()
    if reference == 0.0:
        # nothing loads the rest pose: the start is the answer when it is in balance, else its
        # own out-of-balance force sets the scale
        load = memo.load_case(actuation, 1.0)
        gradient = evaluate(trunk, state, load, memo).gradient
        if not np.any(gradient[1:]):
            return StaticResult(True, 0, 0.0, state, actuation, [0.0], 1, "none",
                                {"solve_s": time.perf_counter() - start})
        reference = _force_scale(trunk, gradient)

    scale, increment = 0.0, 1.0 / load_steps
    if initial is not None:
        increment = 1.0   # warm start: try the full load from the given pose first
    iterations, stages = 0, 0
    last_good = state
    converged = False
    residual = math.inf
    while True:
        target = min(1.0, scale + increment)
        load = memo.load_case(actuation, target)
        stage = _Stage(trunk, memo, load, tolerance if target >= 1.0 else max(tolerance, 1e-6), max_iterations,
                       reference * max(target, 1e-300), history, kinds)
        ok, state_new, its, residual = _newton(stage, last_good)
        iterations += its
        stages += 1
        if ok:
            last_good, scale = state_new, target
            if scale >= 1.0:
                converged = True
                break
            increment = min(2.0 * increment, 1.0 - scale)
        else:
            if initial is not None and scale == 0.0 and last_good is not trunk.rest_state and stages == 1:
                last_good = trunk.rest_state.copy()   # warm start failed: step the load from rest
                increment = 1.0 / load_steps
                continue
            increment *= 0.5
            if increment < 1e-4 or iterations > 50 * max_iterations:
                break
    limited = "rounding-limited" in kinds
    saddles = "unstable" in kinds
    kinds -= {"rounding-limited", "unstable"}
    result = StaticResult(converged, iterations, float(residual), last_good if converged else state_new,
                          actuation, history, stages, "+".join(sorted(kinds)) or "none",
                          {"solve_s": time.perf_counter() - start}, rounding_limited=limited and converged)
    if not converged and raise_on_failure:
        raise ConvergenceError(
            f"Newton did not converge: scaled residual {residual:.3g} > {tolerance:g} after {iterations} "
            f"iterations and {stages} load stages (reached load factor {scale:.4g})"
            + ("; equilibria found on the way were unstable (indefinite tangent) and refused" if saddles else ""),
            result)
    return result
