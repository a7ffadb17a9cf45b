"""Inverse simulation of a trunk (paper §IV): linearise → project → QP → step.

An :class:`InverseController` is built once per model: it validates its settings, builds the
:class:`~solver.inverse.space.ConstraintSpace` (bounds, weights, regulariser) and resolves
its QP backend. Each inverse step then

1. **linearises** the model at the current state and actuation (``model.linearise``);
2. **projects** the linearisation into constraint space (``space.project``: one banded solve
   ``K⁻¹[r, B]``, then ``W_ea``, ``W_aa`` and the free gaps, paper eqs. 10–12);
3. solves the **QP** in the total actuation λ (``solve_constraint_problem``, paper eq. 13),
   whose box is the actuator limits: by default (``effort="least"``) the best reachable
   effector error first, then the least actuation energy among the efforts that keep it;
   ``effort="penalty"`` weighs the error against the energy in one QP (``regularisation``);
4. **steps** within a trust region (:class:`~solver.inverse.trust.TrustRegion`): effectors aim
   at most a radius from where they are, and the step ``(λ − λ0, dq)`` is scaled so that no
   frame moves or turns by more than the radii;

   * ``tick`` mode (real time): the λ box is narrowed to ``λ0 ± max_change`` (the actuators'
     per-tick changes) and ``state ← model.step(state, α·dq)``, one Newton-like update per
     control tick whose remaining imbalance the next tick's ``K⁻¹r`` corrects. The step is
     applied only when it lowers the total potential under the new actuation by at least a
     tenth of what the linearisation predicts and when the equilibrium under it lies within
     half the effectors' motion of the state reached (``|Je K⁻¹ r|`` there, :data:`MISS`);
     otherwise it is cut back (α/4, twice), and not applied at all when that fails too;
   * ``converged`` mode (static inverse): ``model.solve(λ, initial=stepped state)`` to
     equilibrium, repeated — far targets through intermediate ones — until the effectors are
     within tolerance, the error stops falling, or the iteration or time budget ends (closest
     reach so far).

The radii adapt to how well each step's prediction held. A controller built without a state
starts at the equilibrium of its start actuation (none, clipped into the bounds, unless given).
Both modes warm-start from the previous state, actuation and QP answer along a trajectory. Each
step reports where its linear model put the effectors (``predicted_positions``,
``predicted_errors``) beside where they are (``positions``, ``errors``). :meth:`InverseController.settled`
reports a tick at the equilibrium its actuation reaches.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.inverse.backends import DEFAULT_BACKEND, get_backend
from vertebra.solver.inverse.contacts import ContactProjection, contact_step, penetration
from vertebra.solver.inverse.friction_contacts import frictional_step
from vertebra.solver.inverse.qp import ConstraintSolution, solve_constraint_problem
from vertebra.solver.inverse.space import DEFAULT_REGULARISATION, ConstraintSpace
from vertebra.solver.inverse.trust import GOOD, TrustRegion
from vertebra.core.errors import ConvergenceError, OptionError, SceneError
from vertebra.solver import contact_friction, friction
from vertebra.solver.potential import evaluate, nonpotential_forces, potential

__all__ = ["InverseSettings", "InverseStep", "InverseController", "invert", "MODES", "DEFAULT_TOLERANCE"]

# effector error (m) counted as reached, per mode: a converged static inverse is exact up to the
# solver tolerances; one linearise–QP step per tick lags a moving target
DEFAULT_TOLERANCE = {"converged": 1e-6, "tick": 1e-3}
ACCEPT = 0.1    # a tick is applied when the potential falls by at least this share of the prediction
CUTS = 3        # attempts of one step (the first, then two cut back by ¼ each)
DAMPING = 1e-4  # Levenberg–Marquardt damping of the QP (ticks, and converged steps towards far targets)
EFFORTS = ("least", "penalty")   # how the QP resolves redundant actuation (InverseSettings.effort)
GUARD = DEFAULT_REGULARISATION   # the least-effort QP's first stage: keeps it definite and off the near-null directions (bias ≈ 1e-8 × motion)
SECANTS = 4     # with friction: QPs again with the return map's affine piece at the best answer
HALVINGS = (1.0, 0.5, 0.25, 0.125, 0.0625)   # … each answer taken as far along as it lowers the merit
MISS = 0.5      # a tick is cut back when the equilibrium is farther from its prediction than this share of its motion
REUSE_CHANGE = 0.15   # (tangent_reuse) a factor is used again while the cables' tensions (and the chambers' pressures) lie within this share of their largest value at its linearisation


@dataclass(frozen=True)
class InverseSettings:
    """Knobs of the inverse. ``tolerance`` is the effector error (m) counted as reached
    (default per mode, :data:`DEFAULT_TOLERANCE`). Invalid values raise :class:`OptionError`."""

    mode: str = "converged"
    backend: str = DEFAULT_BACKEND
    regularisation: float = DEFAULT_REGULARISATION  # the effort weight of the penalty QP (effort="penalty")
    tolerance: float | None = None
    effort: str = "least"   # "least": best reachable error first, then the least effort; "penalty": one regularised QP
    effort_slack: float = 1e-4  # share of ``tolerance`` per effector row the least-effort stage may give up
    max_iterations: int = 30  # outer linearise–QP–solve iterations (converged mode)
    time_budget: float = 2.0  # s per target (converged mode): then the closest reach so far
    patience: int = 3  # converged mode gives up after this many iterations without progress …
    progress: float = 0.01  # … where progress means cutting the best error by this fraction
    actuation_tolerance: float = 1e-4  # … and, reached or not, once λ changes by less than this (relative)
    settle_iterations: int = 3  # extra iterations allowed, once reached, for λ to settle
    qp_tolerance: float = 1e-10
    # tick mode: a tick's tangent factor is used again for up to this many following ticks (chord
    # steps: no tangent assembled or factored), while each tick is applied in full and its
    # prediction holds; 0 (default): every tick linearises with its own tangent. Trades tracking
    # accuracy for time (docs/inverse.md, "Reusing the tangent").
    tangent_reuse: int = 0

    def __post_init__(self):
        if self.mode not in MODES:
            raise OptionError(f"must be one of {', '.join(sorted(MODES))}, got {self.mode!r}", field="mode")
        if self.tolerance is None:
            object.__setattr__(self, "tolerance", DEFAULT_TOLERANCE[self.mode])
        if not (self.tolerance > 0 and math.isfinite(self.tolerance)):
            raise OptionError(f"must be a positive length (m), got {self.tolerance}", field="tolerance")
        if not (math.isfinite(self.regularisation) and self.regularisation >= 0):
            raise OptionError(f"must be finite and ≥ 0, got {self.regularisation}", field="regularisation")
        if self.effort not in EFFORTS:
            raise OptionError(f"must be one of {', '.join(EFFORTS)}, got {self.effort!r}", field="effort")
        if not (math.isfinite(self.effort_slack) and 0 < self.effort_slack <= 1):
            raise OptionError(f"must lie in (0, 1], got {self.effort_slack}", field="effort_slack")
        if not (self.qp_tolerance > 0):
            raise OptionError(f"must be > 0, got {self.qp_tolerance}", field="qp_tolerance")
        if self.max_iterations < 1:
            raise OptionError(f"must be ≥ 1, got {self.max_iterations}", field="max_iterations")
        if not self.time_budget > 0:
            raise OptionError(f"must be a positive time (s), got {self.time_budget}", field="time_budget")
        if not (0.0 < self.progress < 1.0):
            raise OptionError(f"must lie in (0, 1), got {self.progress}", field="progress")
        if self.patience < 1:
            raise OptionError(f"must be ≥ 1, got {self.patience}", field="patience")
        if not (isinstance(self.tangent_reuse, (int, np.integer)) and self.tangent_reuse >= 0):
            raise OptionError(f"must be an integer ≥ 0, got {self.tangent_reuse!r}", field="tangent_reuse")
        get_backend(self.backend)  # an unknown name raises here


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
    equilibrium: bool  # ``state`` is a converged equilibrium
    iterations: int  # outer iterations
    qp: ConstraintSolution | None  # last QP
    timings: dict = field(default_factory=dict)  # linearise_s, W_s, qp_s, inverse_s, step_s, solve_s, total_s
    status: str = ""
    actuation_change: float = math.nan  # relative change of λ in the last iteration (converged mode)
    equilibrium_failure: str = ""  # why :meth:`InverseController.settled` found no equilibrium
    fraction: float = 1.0  # share of the QP's step applied (tick: 0 when the step was not applied)
    out_of_range: tuple = ()  # RangeExcess: where ``state`` leaves the range a link energy was fitted on
    # where the step's linear model put the effectors (tick: the positions at the controller's own
    # state, its prediction; converged: the last QP's prediction) and their errors from the targets
    predicted_positions: np.ndarray | None = None
    predicted_errors: np.ndarray | None = None
    # with cable friction (docs/friction.md): the friction state the step's command was applied to
    # and the one it left (a tick: the return map at its predicted state); None without friction
    history: object = None
    friction: object = None

    def stuck(self, model) -> dict:
        """With friction: per cable, the interior holes of its route (1 = the first after the
        actuated hole) where the cable is stuck in :attr:`friction` (empty without friction)."""
        if self.friction is None:
            return {}
        pieces = friction.routes(model.trunk.cables).pieces
        return {name: (np.flatnonzero(self.friction.slip[pieces[k][1:]] == 0) + 1).tolist()
                for k, name in enumerate(model.actuator_names[:model.n_cables])}

    @property
    def prediction_miss(self) -> np.ndarray | None:
        """|position − predicted position| per effector (m): how far the reported state lies
        from where the step's linear model put the effectors (0 for a tick before it is
        :meth:`InverseController.settled`)."""
        if self.predicted_positions is None:
            return None
        return _errors(self.positions, self.predicted_positions)


def _errors(positions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """|position − target| per effector."""
    d = positions - targets
    d *= d
    return np.sqrt(d.dot(_THREE))


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """``a`` equals ``b`` to 1e-9 of ``a``'s largest value (a piece's model and the return map)."""
    return float(np.abs(a - b).max(initial=0.0)) <= 1e-9 * float(np.abs(a).max(initial=0.0))


_THREE = np.ones(3)


def _largest(v: np.ndarray) -> float:
    """The largest length of the 3-vectors in ``v`` (n_effectors·3 values, effector rows); NaN
    when a value is. (A few effectors: Python floats beat numpy's calls.)"""
    values = v.tolist()
    largest = 0.0
    for k in range(0, len(values), 3):
        x, y, z = values[k:k + 3]
        squared = x * x + y * y + z * z
        if not squared <= largest:
            if squared != squared:          # NaN
                return squared
            largest = squared
    return math.sqrt(largest)


class InverseController:
    """Runs the inverse on one compiled model; keeps state and actuation between targets
    (warm start along a trajectory). Build once, call :meth:`step` many times.

    ``space`` (:class:`ConstraintSpace`) holds the bounds, weights and regulariser, validated
    once; assign a new space to change them."""

    def __init__(self, model, settings: InverseSettings | None = None, *, actuation=None, state=None,
                 history=None):
        source = model.scene.source
        if len(model.actuator_names) == 0:
            raise SceneError("no [[cable]] or [[chamber]] to invert for", file=source, field="cable")
        if len(model.effector_names) == 0:
            raise SceneError("no [[effector]] to bring to a target", file=source, field="effector")
        self.model = model
        self.settings = settings or InverseSettings()
        least = self.settings.effort == "least"
        self.space = ConstraintSpace.of_model(model, GUARD if least else self.settings.regularisation)
        self._slack = self.settings.effort_slack * self.settings.tolerance if least else None
        self.backend = get_backend(self.settings.backend)
        start = np.zeros(self.space.n_actuators) if actuation is None else np.asarray(actuation, dtype=float)
        self.actuation = np.clip(start, self.space.lambda_lower, self.space.lambda_upper)
        self.state = (state or model.rest_state).copy()
        self.equilibrium = False
        # with cable friction: the friction state the robot is in (docs/friction.md) — a tick
        # commits its predicted state's, a converged step its equilibrium's; given a start state
        # without one, the state is taken as reached by a pull from rest
        self.history = history
        self._incipient = None  # the holes the last frictional linearisation took as sliding on
        if state is None:
            # the robot starts at rest under its start actuation: at that equilibrium (a tick's
            # linear model is only as good as its start), from the rest pose when none is found
            try:
                self._equilibrate(self.actuation, self.state, {}, history)
            except ConvergenceError:
                self.state, self.equilibrium = model.rest_state.copy(), False
                self.history = None
        self.trust = TrustRegion.of_model(model)
        self._judged = None     # the trial of the last state applied (its next linearisation reuses it)
        # (settings.tangent_reuse) the factor the next tick may use again: (factor, trunk, the state
        # it may be used at, ticks it has been used for, the actuation it was linearised at), or None
        self._chord = None
        self._held = 0.0        # the last applied tick's quality (the lower of its energy decrease and prediction)

    # ------------------------------------------------------------------ pieces
    def _linearised_step(self, targets, timings, box=None, damping=None, base=None, secants=0,
                         contact_history=None):
        """linearise → project → QP at the current state and actuation, the effectors aiming
        within the trust region and λ in ``box`` (None: the actuator limits); the QP is damped
        by ``damping`` (None: :data:`DAMPING` while the trust region holds an effector back from
        its target, else none); adds to ``timings``. Returns the linearisation, the projection,
        the QP solution and the aim.

        ``base``: with cable friction, the friction state the command is applied to; the QP sees
        the frictional transmission (:func:`~vertebra.solver.friction.linearise`), the holes that
        slid last taken as sliding on. A tick (``secants`` > 0: :data:`SECANTS`) then solves the QP
        of the exact piecewise-linear transmission by Newton's method on the return map's pieces
        (:meth:`_pieces`, at most ``secants`` QPs more); a converged step (``secants`` = 0), where
        its answer reverses such a cable's command (those holes would stick), linearises the
        cable again with them stuck and solves the QP again — its equilibrium solves correct the
        rest. ``self._incipient`` keeps the holes taken as sliding on (the return maps that judge
        the step start from them)."""
        t0 = time.perf_counter()
        if base is None:
            chord = self._chord
            reused = (chord[0] if chord is not None and chord[1] is self.model.trunk and chord[2] is self.state
                      and secants else None)
            lin = (self.model.linearise(self.state, self.actuation, previous=self._judged) if reused is None else
                   self.model.linearise(self.state, self.actuation, previous=self._judged, factor=reused))
        else:
            incipient = base.incipient(self.model.trunk)
            lin, current, continued = friction.linearise(self.model.trunk, self.state, self.actuation, base,
                                                         incipient)
        t1 = time.perf_counter()
        aim = self.trust.aim(lin.effector_positions, targets, self.model.effector_is_axis)
        if damping is None:
            damping = 0.0 if aim is targets else DAMPING
        projection = self.space.project(lin, aim, self.actuation, box, damping)
        t2 = time.perf_counter()
        found = None
        if self.model.trunk.contact is not None and base is None:
            # the contacts' forces as variables of the QP, complementary with their gaps (with
            # capstan friction on the cables the frictional QP below runs without them; with
            # friction at obstacles, their tangential forces too, the contacts anchored where the
            # step starts: docs/contact.md)
            started = self._contact_base(contact_history)
            found = (contact_step(self.model.trunk, self.state, lin, projection, self.backend,
                                  tolerance=self.settings.qp_tolerance, slack=self._slack) if started is None else
                     frictional_step(self.model.trunk, self.state, lin, projection, self.backend, started,
                                     tolerance=self.settings.qp_tolerance, slack=self._slack))
        if found is not None:
            projection, sol = found
        else:
            sol = solve_constraint_problem(projection.problem, self.backend, tolerance=self.settings.qp_tolerance,
                                           slack=self._slack)
        t3 = time.perf_counter()
        if base is not None:
            n_cables = self.model.n_cables
            reversed_ = np.flatnonzero(continued * np.sign(sol.actuation[:n_cables] - self.actuation[:n_cables]) < 0)
            if reversed_.size and not secants:      # (a tick's pieces below take the reversal exactly)
                owner = self.model.trunk.cables.owner
                incipient = np.where(np.isin(owner, reversed_), 0, incipient).astype(np.int8)
                lin, current, _ = friction.linearise(self.model.trunk, self.state, self.actuation, base, incipient)
                projection = self.space.project(lin, aim, self.actuation, box, damping)
                sol = solve_constraint_problem(projection.problem, self.backend,
                                               tolerance=self.settings.qp_tolerance, slack=self._slack)
            # the return map is piecewise linear in the commands (holes start or stop sliding as
            # their bands are reached), and at these poses each cable's pieces depend on its own
            # command alone. A tick solves the QP of that exact piecewise-linear transmission by
            # Newton's method on the pieces: each answer is judged by the effectors' gap the
            # linearisation predicts for the return map's exact forces there (the merit), and the
            # QP solved again with each cable's transmission the return map's own affine piece at
            # the best answer (its chord from the start plus its slope there), the new answer taken
            # as far along the way as it lowers the merit (halving), until an answer lies on the
            # pieces its model was made of (the model is exact there), ``secants`` times at most.
            # A tendon's runs make the tangent too: where an answer changes its holes' statuses,
            # the tangent is that of the runs at the answer (the imbalance at the start stays the
            # start's). The step's linear model is then the chord to the answer (exact there).
            if secants:
                lin, projection, sol, incipient = self._pieces(lin, projection, sol, current, base, incipient, aim,
                                                               box, damping, secants, continued)
            self._incipient = incipient
        t4 = time.perf_counter()
        get = timings.get
        timings["linearise_s"] = get("linearise_s", 0.0) + (t1 - t0)
        timings["W_s"] = get("W_s", 0.0) + (t2 - t1)
        timings["qp_s"] = get("qp_s", 0.0) + (t3 - t2)
        timings["inverse_s"] = get("inverse_s", 0.0) + (t3 - t0) + (t4 - t3 if t4 > t3 else 0.0)
        return lin, projection, sol, aim

    def _pieces(self, lin, projection, sol, current, base, incipient, aim, box, damping, rounds, continued):
        """A tick's QP on the exact piecewise-linear frictional transmission (:meth:`_linearised_step`).
        Every cable whose holes slid last sits at a kink at its start: pulled on, they slide on;
        reversed, they stick. Each cable is therefore kept on the side of its start that the first
        answer chose (a cable it left unchanged: the side its holes slide on, ``continued``), and
        the pieces on that side are walked."""
        trunk = self.model.trunk
        n_cables = self.model.n_cables
        tendon_pieces = trunk.actuators.stroke_driven[trunk.cables.owner]
        tendons = trunk.actuators.stroke_driven
        poses = friction.geometry(trunk, self.state)
        start, residual = current, lin.residual
        lam0 = self.actuation
        gap0 = (lin.effector_positions - aim).reshape(-1)

        def piece(answer, forces):
            """The return map at ``answer``: its exact forces there, its piece, and the merit."""
            reached, chord, slope = friction.piecewise(trunk, self.state, base, start, lam0, answer, incipient,
                                                       forces, poses)
            exact = chord @ (answer[:n_cables] - lam0[:n_cables])
            gap = gap0 + projection.effector_motion(residual + exact)
            return [float(gap @ gap), answer, reached, chord, slope, exact]

        model_forces = lin.actuator_forces[:, :n_cables].copy()
        offset = np.zeros(model_forces.shape[0])
        best = piece(sol.actuation, model_forces)
        lower, upper = (self.space.lambda_lower, self.space.lambda_upper) if box is None else box
        side = np.sign(sol.actuation - lam0)
        side[:n_cables] = np.where(side[:n_cables] == 0, continued, side[:n_cables])
        box = (np.where(side > 0, np.maximum(lower, lam0), lower), np.where(side < 0, np.minimum(upper, lam0), upper))
        for _ in range(rounds):
            merit, answer, reached, chord, slope, exact = best
            change = answer[:n_cables] - lam0[:n_cables]
            tendon_moved = tendon_pieces.any() and not np.array_equal(reached.slip[tendon_pieces],
                                                                      current.slip[tendon_pieces])
            # the answer lies on the pieces its model was made of: the model is exact there
            if (not tendon_moved and _close(slope, model_forces)
                    and _close(model_forces @ change + offset, exact)):
                break
            if tendon_moved:
                incipient = np.where(tendon_pieces, reached.slip, incipient).astype(np.int8)
                command = lam0.copy()
                command[:n_cables][tendons] = answer[:n_cables][tendons]
                lin, current, _ = friction.linearise(trunk, self.state, command, base, incipient)
                best = piece(answer, lin.actuator_forces[:, :n_cables])
                merit, answer, reached, chord, slope, exact = best
            # F(λ) = chord·change + slope·(λ − answer) = slope·(λ − λ0) + (chord − slope)·change
            model_forces, offset = slope, exact - slope @ change
            lin.residual = residual + offset
            lin.actuator_forces[:, :n_cables] = slope
            projection = self.space.project(lin, aim, lam0, box, damping)
            target = solve_constraint_problem(projection.problem, self.backend, tolerance=self.settings.qp_tolerance,
                                              slack=self._slack).actuation
            improved = False
            for share in HALVINGS:
                trial = piece(answer + share * (target - answer), model_forces)
                if trial[0] < merit:
                    best, improved = trial, True
                    break
            if not improved:
                break
        merit, answer, reached, chord, slope, exact = best
        lin.residual = residual
        lin.actuator_forces[:, :n_cables] = chord
        projection = self.space.project(lin, aim, lam0, box, damping)
        de, da = projection.problem.predict(answer)
        sol = dataclasses.replace(sol, actuation=answer, delta_e=de, delta_a=da, problem=projection.problem,
                                  effector_error=math.sqrt(float(de @ de)))
        return lin, projection, sol, incipient

    def _result(self, targets, sol, iterations, timings, t_start, equilibrium, status, displacements=None,
                predicted=None):
        positions = self.model.effector_positions(self.state)
        errors = _errors(positions, targets)
        if predicted is None:
            predicted = positions
        tolerance = self.settings.tolerance
        if displacements is None:
            displacements = self.model.actuator_displacements(self.state, self.actuation)
        timings["total_s"] = time.perf_counter() - t_start
        return InverseStep(
            actuation=self.actuation.copy(), state=self.state, targets=targets.copy(), positions=positions,
            errors=errors, displacements=displacements, reached=float(np.maximum.reduce(errors)) <= tolerance,
            equilibrium=equilibrium, iterations=iterations, qp=sol, timings=timings, status=status,
            out_of_range=self.model.out_of_range(self.state, self.actuation), predicted_positions=predicted,
            predicted_errors=errors.copy() if predicted is positions else _errors(predicted, targets))

    # ------------------------------------------------------------------ modes
    def tick(self, targets) -> InverseStep:
        """One linearise–project–QP–step (real-time mode) inside the trust region and the per-tick
        actuator changes: no Newton solve; ``state`` is the linearised prediction, not an
        equilibrium (the next tick corrects it), and the reported displacements are the QP's
        prediction. A step whose prediction fails is cut back, or not applied (``fraction``)."""
        targets = self._targets(targets)
        t_start = time.perf_counter()
        timings: dict = {}
        base = self._friction_base()
        started = self._contact_base()         # (friction at obstacles: the tick is an increment from here)
        lam0 = self.actuation
        lin, projection, sol, aim = self._linearised_step(targets, timings, self.space.tick_box(self.actuation),
                                                          DAMPING, base, SECANTS, started)
        t0 = time.perf_counter()
        fraction = self._advance(lin, projection, sol.actuation, aim is not targets, base)
        if started is not None and fraction > 0.0:
            self.history = contact_friction.at_state(self.state)      # the next tick anchors where this one ends
        self._chord = self._reusable(lin, lam0, fraction, base is not None or started is not None)
        self.equilibrium = False
        timings["step_s"] = time.perf_counter() - t0
        status = "tick" if fraction == 1.0 else ("cut back" if fraction > 0.0 else "not applied")
        result = self._result(targets, sol, 1, timings, t_start, False, status,
                              displacements=sol.delta_a if fraction == 1.0 else
                              projection.problem.predict(self.actuation)[1])
        result.fraction = fraction
        if base is not None or started is not None:
            result.history, result.friction = base if base is not None else started, self.history
        return result

    def _reusable(self, lin, lam0, fraction: float, frictional: bool):
        """What the next tick may linearise with (``settings.tangent_reuse``): this tick's factor
        at the state it reached, when the tick was applied in full and its prediction held
        (quality ≥ :data:`~vertebra.solver.inverse.trust.GOOD`) and the factor has been used for
        fewer than ``tangent_reuse`` ticks; else None (the next tick factors its own tangent)."""
        reuse = self.settings.tangent_reuse
        model = self.model
        if (not reuse or frictional or fraction != 1.0 or self._held < GOOD or model.trunk.contact is not None
                or model.n_tendons):
            return None
        chord = self._chord
        if chord is None or chord[0] is not lin.factor:     # this tick's own tangent, linearised at λ0
            used, start = 0, lam0
        else:
            used, start = chord[3] + 1, chord[4]            # (this tick included)
        if used >= reuse:
            return None
        # the cables' tangent grows with their tensions (a chamber's with its pressure): used again
        # only while the actuation stays near the one it was linearised at
        n = model.n_cables
        for before, now in ((start[:n], self.actuation[:n]), (start[n:], self.actuation[n:])):
            if before.size and not (float(np.abs(now - before).max()) <= REUSE_CHANGE * float(np.abs(before).max())):
                return None
        return lin.factor, model.trunk, self.state, used, start

    def _advance(self, lin, projection, lam_target, aimed: bool, base=None) -> float:
        """Move state and actuation by the largest share ``α`` of the linearised step towards
        ``lam_target`` that the trust region allows and whose prediction holds: the potential
        under the new actuation falls by at least :data:`ACCEPT` of the quadratic model's
        prediction, and the equilibrium under it lies within :data:`MISS` of the effectors'
        motion (plus what is left of the start's own imbalance) from the state reached, by the
        start's tangent: ``|Je K⁻¹ r(state)|``. Cut back by ¼ when it does not (twice); returns
        the share applied (0: none).
        ``aimed``: the trust region moved an effector's target closer.

        ``base``: with cable friction, the friction state the command is applied to. There is no
        potential; the potential judged is that of the span tensions the return map gives under
        the new actuation at the start's poses (held fixed along the step, as the linearisation
        holds them), the equilibrium's distance is measured from the imbalance under the return
        map's tensions at the state reached (the frictional residual given the history), and an
        applied step commits the friction state there (:meth:`FrictionState.after
        <vertebra.solver.friction.FrictionState.after>`) for the next tick."""
        model, lam0, state0 = self.model, self.actuation, self.state
        d_lam = lam_target - lam0
        dq = projection.state_change(lam_target, d_lam)
        alpha = self.trust.fraction(dq)
        cut = aimed or alpha < 1.0
        r = lin.residual
        r_dq = float(dq.dot(r))
        b_dq = float(dq.dot(lin.actuator_forces.dot(d_lam)))
        n_cables = model.n_cables
        # the effectors' linear motion per unit α, and how far the start lies from its own
        # equilibrium (the part of the step that corrects an imbalance left by the last tick)
        motion = _largest(lin.effector_jacobian.dot(dq))
        imbalance = _largest(projection.Je_K_inv_r)
        floor = 0.01 * self.settings.tolerance
        # with contacts: how deep the start lies in an obstacle (a tick may not go deeper than that
        # or the floor: the QP keeps the linearised gaps, the retraction's second order may not)
        # (whatever the QP's projection: without a contact near the start, or where the contacts'
        # QP failed, the step is the contact-free one and may still reach an obstacle)
        contacts = model.trunk.contact
        entered = penetration(contacts, state0) if contacts is not None else 0.0
        # ∂E/∂λ of the cables: their lengths L(q) = L0 + stroke
        cables = d_lam[:n_cables]
        d_energy = float(cables.dot(model.rest_cable_lengths)) + float(cables.dot(lin.actuator_displacements[:n_cables]))
        exact_energy = model.n_chambers or model.n_tendons
        quality = 0.0
        work = (nonpotential_forces(model.trunk, state0, model.loads(lam0, 1.0)) if model.trunk.loads.unsymmetric
                else None)
        if base is not None:
            trunk = model.trunk
            start = friction.geometry(trunk, state0)
        for _ in range(CUTS):
            whole = alpha == 1.0        # (then α·x is x: not multiplied)
            lam = lam0 + (d_lam if whole else alpha * d_lam)
            # the model of the potential under λ along α·dq: E_λ(q) − r_λ·d + ½ dᵀK d, with
            # r_λ = r + B(λ − λ0) and K dq = r + B d_lam
            predicted = alpha * (1.0 - 0.5 * alpha) * r_dq + 0.5 * alpha * alpha * b_dq
            try:     # (a pressure beyond a chamber's inflation limit point has no potential: not applied)
                if base is not None:    # friction: the return map's span tensions under λ at the start's poses
                    load = friction.transmission(trunk, base, lam, *start, self._incipient).load(trunk, lam, 1.0)
                    before = potential(trunk, state0, load).energy
                elif exact_energy:
                    before = model.potential(state0, lam)
                else:      # the potential is linear in tension-driven cables' tensions: E_λ(q) = E_λ0(q) + (λ − λ0)·L(q)
                    before = lin.energy + alpha * d_energy
                trial = model.step(state0, dq if whole else alpha * dq)
                judged = model.trial(trial, lam) if base is None else potential(trunk, trial, load)
                after = judged.energy
            except ConvergenceError:
                before = after = math.nan
            if work is not None:            # loads without a potential: their linearised work
                after -= alpha * float(work @ dq)
            decrease = before - after
            noise = 1e-12 * abs(before)
            quality = decrease / predicted if predicted > noise else (1.0 if decrease >= -noise else 0.0)
            if contacts is not None and quality >= ACCEPT and penetration(contacts, trial) > max(floor, entered):
                quality = 0.0            # a trial that enters an obstacle (or disc) deeper than the start is cut back
            if quality >= ACCEPT:        # (False for NaN)
                # the prediction: the equilibrium under λ lies ≈ Je K⁻¹ r(trial) from the trial state
                # (the start's factor); a step that lands farther than MISS of its motion from it is
                # cut back like one whose energy does not fall
                try:
                    if base is None:
                        judged = model.evaluate(trial, lam, previous=judged)
                    else:           # the imbalance under the return map's tensions at the state reached
                        following = friction.transmission(trunk, base, lam, *friction.geometry(trunk, trial),
                                                          self._incipient)
                        judged = evaluate(trunk, trial, following.load(trunk, lam, 1.0))
                    # (|Je K⁻¹ r|, r = −gradient: the sign does not change the length)
                    imbalance_at = judged.gradient[1:].reshape(-1)
                    if isinstance(projection, ContactProjection):    # the contacts carry their forces
                        imbalance_at = imbalance_at - projection.contact_forces(lam)
                    miss = _largest(projection.effector_motion(imbalance_at))
                except (ConvergenceError, FloatingPointError):
                    miss = math.inf
                allowed = MISS * alpha * motion + (1.0 - alpha) * imbalance + floor
                # the prediction's quality: 1 when exact, ½ at the allowed miss
                held = 1.0 - MISS * miss / allowed
                if miss <= allowed:
                    self.state, self.actuation, self._judged = trial, lam, judged
                    if base is not None:
                        self.history = friction.FrictionState.after(base, following, lam, trial)
                        self._judged = None
                    self._held = min(quality, held)
                    self.trust.update(self._held, cut)
                    return alpha
                quality = min(quality, held)
            alpha *= 0.25
            cut = True
        self.trust.update(quality if math.isfinite(quality) else 0.0, cut)
        return 0.0

    def converge(self, targets) -> InverseStep:
        """Static inverse: repeat linearise → project → QP → equilibrium solve, each step inside
        the trust region (far targets through intermediate ones), until the effectors are within
        tolerance, the error stops falling (unreachable: closest reach), or the iteration or time
        budget ends (status ``"budget"``: the closest reach so far)."""
        targets = self._targets(targets)
        t_start = time.perf_counter()
        deadline = t_start + self.settings.time_budget
        timings: dict = {"solve_s": 0.0}
        s = self.settings
        if not self.equilibrium:
            self._equilibrate(self.actuation, self.state, timings, self._friction_base() or self._contact_base())
        # with friction: the friction state the robot is in; every equilibrium tried below is the
        # answer's command applied to it (one increment: the robot receives the answer only)
        base = self._friction_base()
        started = self._contact_base()
        history = base if base is not None else started
        error = float(np.max(_errors(self.model.effector_positions(self.state), targets)))
        best, idle, reached_for, change = error, 0, 0, math.nan
        closest = (error, self.actuation, self.state, self.history)
        sol, status, iterations, predicted_positions = None, "max_iterations", 0, None
        for iterations in range(1, s.max_iterations + 1):
            if time.perf_counter() > deadline:
                status, iterations = "budget", iterations - 1
                break
            lin, projection, sol, aim = self._linearised_step(targets, timings, base=base, contact_history=started)
            dq = projection.state_change(sol.actuation)
            lam_old, state_old, history_old = self.actuation, self.state, self.history
            d_lam = sol.actuation - lam_old
            alpha = self.trust.fraction(dq)
            cut = aim is not targets or alpha < 1.0
            new_error, quality = math.inf, 0.0
            for _ in range(CUTS):
                lam = lam_old + alpha * d_lam
                # what the linear model promises at λ for the real targets (a bound may keep it
                # above the current error)
                gap = projection.problem.predict(lam)[0].reshape(-1, 3) + (aim - targets)
                predicted = math.sqrt(float(np.maximum.reduce(np.add.reduce(gap * gap, 1))))
                if self._settle(lam, self._stepped(state_old, alpha * dq), state_old, timings, history):
                    new_error = float(np.max(_errors(self.model.effector_positions(self.state), targets)))
                    # how much of the promised improvement came (not judged below the tolerance:
                    # there the errors are the equilibrium solves' rounding)
                    promised = error - predicted
                    quality = ((error - new_error) / promised if promised > s.tolerance
                               else float(new_error <= error + s.tolerance))
                    if new_error <= max(error, 1.1 * predicted + s.tolerance):
                        predicted_positions = targets + gap
                        break
                self.actuation, self.state, self.history = lam_old, state_old, history_old
                new_error = math.inf
                alpha *= 0.25
                cut = True
            self.trust.update(quality, cut)
            if not math.isfinite(new_error):
                status = "equilibrium_failed"
                break
            error = new_error
            if error < closest[0]:
                closest = (error, self.actuation, self.state, self.history)
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
        if status == "budget" and closest[0] < error:
            error, self.actuation, self.state, self.history = closest      # the closest reach found in the time given
            predicted_positions = None
        result = self._result(targets, sol, iterations, timings, t_start, self.equilibrium, status,
                              predicted=predicted_positions)
        result.actuation_change = change
        if history is not None:
            result.history, result.friction = history, self.history
        return result

    def step(self, targets) -> InverseStep:
        """One step in the configured mode."""
        return MODES[self.settings.mode](self, targets)

    def settled(self, step: InverseStep) -> InverseStep:
        """``step`` reported at the equilibrium its actuation reaches: a tick's state is a linear
        prediction, so the model is solved under the commanded actuation from it (the controller
        keeps its own state). An equilibrium step is returned as it is; when the solve fails, the
        step is returned with ``equilibrium_failure`` saying why. With friction the command is
        applied to the friction state the tick started from (``step.history``) and the step's
        ``friction`` is the equilibrium's."""
        if step.equilibrium:
            return step
        try:
            solved = self.model.solve(step.actuation, initial=step.state, history=step.history)
        except ConvergenceError as error:
            return dataclasses.replace(step, equilibrium_failure=str(error))
        state = solved.state
        positions = self.model.effector_positions(state)
        errors = _errors(positions, step.targets)
        tolerance = self.settings.tolerance
        return dataclasses.replace(
            step, state=state, positions=positions, errors=errors, equilibrium=True,
            displacements=self.model.actuator_displacements(state, step.actuation),
            reached=all(e <= tolerance for e in errors.tolist()), out_of_range=solved.out_of_range,
            friction=solved.friction if step.friction is not None else None)

    def track(self, trajectory, *, settle: bool = False, on_step=None) -> list[InverseStep]:
        """Targets (n_steps, n_eff, 3) in order, warm-starting each step from the last. With
        ``settle`` each step is reported :meth:`settled` (solved after the step is timed);
        ``on_step(index, step)`` is called after each step."""
        steps = []
        for i, targets in enumerate(np.asarray(trajectory, dtype=float)):
            step = self.step(targets)
            if settle:
                step = self.settled(step)
            if on_step is not None:
                on_step(i, step)
            steps.append(step)
        return steps

    # ------------------------------------------------------------------ helpers
    def _stepped(self, state, dq):
        """``state`` moved by ``dq``, or None when the step does not give finite poses."""
        try:
            return self.model.step(state, dq)
        except ConvergenceError:
            return None

    def _settle(self, actuation, guess, fallback, timings, history=None) -> bool:
        """Equilibrium under ``actuation`` (applied to the friction state ``history``) from
        ``guess``, else from ``fallback``; False when neither converges (state and actuation then
        unchanged)."""
        for start in (guess, fallback):
            if start is None:
                continue
            try:
                self._equilibrate(actuation, start, timings, history)
                return True
            except ConvergenceError:
                continue
        return False

    def _equilibrate(self, actuation, guess, timings, history=None):
        """Equilibrium under ``actuation`` from ``guess`` — with friction, the command applied to
        ``history`` (None: a pull from rest) — as the controller's state."""
        t0 = time.perf_counter()
        try:
            result = self.model.solve(actuation, initial=guess, history=history)
        finally:
            timings["solve_s"] = timings.get("solve_s", 0.0) + time.perf_counter() - t0
        self.actuation = np.asarray(actuation, dtype=float).copy()
        self.state = result.state
        self.history = result.friction
        self.equilibrium = True

    def _friction_base(self):
        """With cable friction, the friction state the robot is in (:attr:`history`; made when
        missing as that of a pull from rest to the controller's state and actuation); None
        without friction — the frictionless controller runs no friction code."""
        if not self.model.trunk.actuators.frictional:
            return None
        if self.history is None:
            trunk = self.model.trunk
            rest = friction.FrictionState.rest(trunk)
            current = friction.transmission(trunk, rest, self.actuation, *friction.geometry(trunk, self.state))
            self.history = friction.FrictionState.after(rest, current, self.actuation, self.state)
        return self.history

    def _contact_base(self, given=None):
        """With friction at obstacle contacts, the friction state the robot is in (``given``, else
        :attr:`history`, else the controller's state taken as reached there); None without it."""
        if not contact_friction.frictional(self.model.trunk):
            return None
        if given is not None:
            return given
        if isinstance(self.history, contact_friction.ContactFriction):
            return self.history
        return contact_friction.at_state(self.state)

    def _targets(self, targets) -> np.ndarray:
        """``targets`` as a finite (n_eff, 3) float array (:class:`OptionError` naming what is wrong)."""
        names = self.model.trunk.effectors.names
        t = np.asarray(targets, dtype=float)
        if t.size != 3 * len(names):
            raise OptionError(f"must hold {len(names)}×3 values (effectors {', '.join(names)}), "
                              f"got shape {t.shape}", field="targets")
        if t.ndim != 2 or t.shape[1] != 3:
            t = t.reshape(len(names), 3)
        flat = t.reshape(-1)
        if not math.isfinite(flat.dot(flat)) and not np.isfinite(t).all():  # (a dot that overflows: finite)
            bad = [names[k] for k in np.flatnonzero(~np.isfinite(t).all(axis=1))]
            raise OptionError(f"effector(s) {', '.join(bad)} have no finite target", field="targets")
        return t


MODES = {"converged": InverseController.converge, "tick": InverseController.tick}


def invert(model, targets=None, *, actuation=None, state=None, **settings) -> InverseStep:
    """One inverse solve on ``model`` (converged mode unless ``mode="tick"``): the
    actuation bringing the effectors to ``targets`` (default: the scene's targets).
    ``settings`` are :class:`InverseSettings` fields."""
    controller = InverseController(model, InverseSettings(**settings), actuation=actuation, state=state)
    return controller.step(model.effector_targets if targets is None else targets)
