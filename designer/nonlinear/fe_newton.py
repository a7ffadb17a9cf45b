"""Newton's method with a line search on an energy-like merit, and load stepping.

Shared by the segment (:mod:`.segment`) and the trunk (:mod:`.trunk`). A problem
implements :class:`NewtonProblem`; states are opaque to this module.

* Newton: evaluate gradient and tangent; stop when the problem says the residual is
  within tolerance; otherwise solve for the step. When the step is not a descent
  direction of the merit (the tangent is indefinite away from equilibrium) the
  tangent is shifted, ``H + μ diag H``, with μ growing tenfold from 1e-3. Backtracking
  (Armijo) on the merit; a trial state whose merit is not finite (an inverted
  element) is cut back like any other. Near convergence the merit differences fall
  to round-off: a step whose predicted decrease is below that level is taken whole.
  The full step's trial is evaluated with its tangent at once and its merit read from
  that evaluation, which the next iteration reuses (full steps are the rule: one
  assembly per iteration instead of an assembly and a merit evaluation); shorter
  trials evaluate the merit alone.
* Inexact Newton: the step's linear solve needs only the accuracy the iteration can
  use; :func:`forcing` gives the problem the relative residual to reach, ``η = min(η_max,
  max(r, 0.1 rtol / r))`` at residual ratio ``r`` (quadratic convergence kept: the
  solve's error ``η r`` is no larger than the ``O(r²)`` remainder of Newton's model;
  and a solve that lands the next residual below the tolerance is accurate enough).
* Load stepping (:func:`march`): the load path is parametrised by ``s ∈ [0, 1]``; the
  problem moves a converged state to ``s + Δs`` with a predictor; a step whose Newton
  iteration fails is halved, one that converged quickly lets the next one double, and
  a step that cannot be cut below ``min_step`` raises :class:`ConvergenceError` naming
  the stage, the fraction reached and whether the tangent had lost positive
  definiteness (a limit point, e.g. an inflation instability under pressure control).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vertebra.core.errors import ConvergenceError


@dataclass(frozen=True)
class NewtonSettings:
    rtol: float = 1e-10             # residual / force scale at convergence
    max_iterations: int = 25
    armijo: float = 1e-4
    min_step_length: float = 1.0 / 256.0
    roundoff: float = 1e-11          # relative size of merit differences treated as round-off
    max_shifts: int = 4
    min_step: float = 1.0 / 4096.0   # smallest load-step fraction before giving up
    grow_iterations: int = 4         # a load step converged in at most this many iterations doubles the next
    max_forcing: float = 1e-2        # loosest relative residual of a step's linear solve (inexact Newton)

    def __post_init__(self):
        if not (0 < self.rtol < 1):
            raise ValueError(f"rtol must be in (0, 1), got {self.rtol}")


@dataclass
class Step:
    direction: object
    slope: float                     # directional derivative of the merit along the step
    info: dict = field(default_factory=dict)


class NewtonProblem(Protocol):
    def evaluate(self, state, hessian: bool = True): ...

    def residual_ratio(self, state, evaluation) -> float:
        """Residual over its tolerance scale (converged when ≤ rtol)."""

    def step(self, state, evaluation, shift: float = 0.0, forcing: float = 0.0) -> Step:
        """Newton step; its linear solve may stop at the relative residual ``forcing`` (0: the
        problem's own tolerance, and never looser than a problem that needs more allows)."""

    def retract(self, state, step: Step, alpha: float): ...

    def merit(self, state, step: "Step | None" = None, alpha: float = 0.0, evaluation=None) -> float:
        """Merit of ``state``, reached by ``alpha`` × ``step`` from the line search's start (the
        linearised work of non-potential loads along the step is subtracted); read from
        ``evaluation`` (of ``state``) when given."""

    def merit_scale(self, evaluation) -> float: ...


class NewtonFailure(Exception):
    def __init__(self, reason: str, report: "NewtonReport"):
        super().__init__(reason)
        self.reason = reason
        self.report = report


@dataclass
class NewtonReport:
    iterations: int = 0
    residual: float = math.inf
    line_search_cuts: int = 0
    shifted_steps: int = 0
    indefinite: bool = False
    negative_pivots: int | None = None


def forcing(residual: float, settings: NewtonSettings) -> float:
    """Relative residual a Newton step's linear solve must reach at residual ratio ``residual``
    (inexact Newton, see the module docstring)."""
    if residual <= 0.0:
        return settings.max_forcing
    return min(settings.max_forcing, max(residual, 0.1 * settings.rtol / residual))


def newton(problem: NewtonProblem, state, settings: NewtonSettings):
    """Converged ``(state, evaluation, report)``, or :class:`NewtonFailure`."""
    report = NewtonReport()
    evaluation = problem.evaluate(state, hessian=True)
    for iteration in range(settings.max_iterations + 1):
        if evaluation is None:
            evaluation = problem.evaluate(state, hessian=True)
        report.residual = problem.residual_ratio(state, evaluation)
        report.iterations = iteration
        if not math.isfinite(report.residual):
            raise NewtonFailure("residual is not finite", report)
        if report.residual <= settings.rtol:
            return state, evaluation, report
        if iteration == settings.max_iterations:
            break
        state, evaluation = _line_search(problem, state, evaluation, settings, report)
    raise NewtonFailure(f"no convergence in {settings.max_iterations} iterations "
                        f"(residual/tolerance scale {report.residual:.3g})", report)


def _line_search(problem, state, evaluation, settings, report):
    """``(accepted state, its evaluation or None)``."""
    merit0 = problem.merit(state, evaluation=evaluation)
    scale = problem.merit_scale(evaluation)
    eta = forcing(report.residual, settings)
    shift = 0.0
    for attempt in range(settings.max_shifts + 1):
        step = problem.step(state, evaluation, shift, eta)
        if step.info.get("negative_pivots"):
            report.negative_pivots = step.info["negative_pivots"]
            report.indefinite = True
        if step.slope < 0.0:
            break
        report.indefinite = True
        report.shifted_steps += 1
        shift = 1e-3 if shift == 0.0 else 10.0 * shift
    else:
        raise NewtonFailure("no descent direction even with a shifted tangent", report)
    alpha = 1.0
    while alpha >= settings.min_step_length:
        trial = problem.retract(state, step, alpha)
        trial_evaluation = None
        if alpha == 1.0:                          # the full step: evaluated whole, reused if accepted
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                trial_evaluation = problem.evaluate(trial, hessian=True)
        merit = problem.merit(trial, step, alpha, evaluation=trial_evaluation)
        if math.isfinite(merit):
            if merit <= merit0 + settings.armijo * alpha * step.slope:
                return trial, trial_evaluation
            if abs(step.slope) <= settings.roundoff * scale and abs(merit - merit0) <= 10 * settings.roundoff * scale:
                return trial, trial_evaluation    # round-off regime: the merit cannot resolve the step
        alpha *= 0.5
        report.line_search_cuts += 1
    raise NewtonFailure("line search failed (no decrease of the merit along the Newton step)", report)


class LoadPath(Protocol):
    def advance(self, state, s_from: float, s_to: float):
        """State at path fraction ``s_to`` predicted from the converged ``state`` at ``s_from``."""

    def converged(self, state, evaluation, s: float):
        """Hook after a converged load step at path fraction ``s`` (e.g. to remember it for a secant
        predictor, or for the tangent at ``s = 1``); returns the state."""


@dataclass
class MarchReport:
    load_steps: int = 0
    newton_iterations: int = 0
    cut_steps: int = 0
    indefinite: bool = False
    negative_pivots: int | None = None
    time_s: float = 0.0
    history: list = field(default_factory=list)    # (s, iterations) of each converged step


def march(problem, path: LoadPath, state, settings: NewtonSettings, *, first_step: float = 1.0,
          max_step: float = 1.0, stage: str = "solve"):
    """Follow the load path from s = 0 (``state`` converged there) to s = 1."""
    start = time.perf_counter()
    report = MarchReport()
    s, ds = 0.0, min(first_step, max_step)
    evaluation = None
    while s < 1.0:
        s_to = 1.0 if s + ds >= 1.0 - 1e-12 else s + ds
        trial = path.advance(state, s, s_to)
        try:
            trial, evaluation, nr = newton(problem, trial, settings)
        except NewtonFailure as failure:
            report.cut_steps += 1
            report.newton_iterations += failure.report.iterations
            report.indefinite |= failure.report.indefinite
            if failure.report.negative_pivots is not None:
                report.negative_pivots = failure.report.negative_pivots
            ds = 0.5 * (s_to - s)
            if ds < settings.min_step:
                report.time_s = time.perf_counter() - start
                limit = (" The tangent stiffness lost positive definiteness on the way"
                         + (f" ({report.negative_pivots} negative pivots)" if report.negative_pivots else "")
                         + ": a limit point of the load path (e.g. an inflation instability under pressure "
                         "control) — no equilibrium follows it on this path." if report.indefinite else "")
                raise ConvergenceError(f"{stage}: no equilibrium at load fraction {s_to:.6g} (converged up to "
                                       f"{s:.6g}; the load step was cut below {settings.min_step:g}): "
                                       f"{failure.reason}.{limit}", result=(state, report)) from None
            continue
        report.load_steps += 1
        report.newton_iterations += nr.iterations
        report.history.append((s_to, nr.iterations))
        if nr.negative_pivots:
            report.negative_pivots = nr.negative_pivots
            report.indefinite = True
        state = path.converged(trial, evaluation, s_to)
        s = s_to
        if nr.iterations <= settings.grow_iterations:
            ds = min(2.0 * ds, max_step)
    report.time_s = time.perf_counter() - start
    return state, evaluation, report
