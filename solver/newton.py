"""Quasi-static equilibrium (paper eq. 9): a minimum of the total potential, found by a
globalised Newton method on the energy, with load continuation. Only the energy, its gradient,
the tangent's banded factor and the retraction are used: nothing assumes a quadratic link energy.

Each iteration at a fixed load factor

* solves ``(H + μ·D) p = r`` with the tangent's banded factor (:class:`~vertebra.solver.assembly.Tangent`):
  the residual ``r = −∇E``, ``D`` the larger of ``|diag H|`` and the diagonal of the unstressed
  tangent (a Marquardt scaling: every DoF in its own units). Conservative loads: banded Cholesky,
  ``μ`` raised tenfold until the shifted matrix is positive definite, so ``p`` descends even on an
  indefinite tangent (no LU there: it steers Newton towards saddles). Dead moments and follower
  loads (no potential) make ``H`` unsymmetric: banded LU of ``H + μ·D`` with their turning in it
  (the consistent tangent, so that Newton stays quadratic), judged by an energy-like merit (the
  potential minus those loads' work along the step: :func:`~vertebra.solver.globalise.moved`),
  after the full Newton step, which is taken first whenever it halves the residual
  (:func:`~vertebra.solver.globalise.residual_step`: that merit is no merit of these loads —
  dead moments do work round a closed loop of rotations, and beyond the load at which the
  symmetric part turns indefinite the equilibrium is no minimum of it);
* where the tangent proved indefinite and the shift needed is large (``μ ≥`` :data:`BEND_SHIFT`),
  or at a stationary point that is a saddle, weighs a step along the direction of most negative
  curvature (inverse iteration with the shifted factor) against the shifted one;
* caps the step (:meth:`_Stage.step_limit`): no link's rotation changes by more than
  :data:`MAX_TURN`, no translation strain by more than :data:`MAX_STRETCH` of the shortest
  link, no link goes more than half-way from its rotation to π, no cable piece loses more than
  half its length (a larger step is scaled, not turned);
* accepts the first ``α p`` (α = 1, ½, ¼, …) that lowers the energy by an Armijo share of the
  quadratic model's prediction (where that prediction is below the energy's rounding: that does
  not raise the residual); when none does, ``μ`` grows tenfold;
* adapts ``μ`` by the ratio of the actual to the predicted decrease of the full step: ``μ/4``
  when the model was right (``μ`` falls to 0: pure Newton, quadratic convergence), ``×4`` when
  the step had to be cut back.

Only stable equilibria are accepted: a stationary point reached through shifted or LU factors,
or from far away, is accepted when its own tangent is positive definite up to neutral
directions (:func:`is_stable`); a saddle is left along negative curvature.

A state where a link turns towards π, folds through itself, or where a cable's holes meet cannot
be represented: the load is retried in smaller increments, and when a small one leads there too
the solve stops with a :class:`ConvergenceError` that says so (for a link: how many links per
repetition would represent the deformation). Non-finite values stop the solve with a
:class:`ConvergenceError` naming the stage.

Load continuation: the load factor's increment halves when a stage fails and doubles when it
succeeds; intermediate stages converge to 1e-6; a solve stops after :data:`BUDGET` ×
``max_iterations`` iterations. Residuals are measured as max(|force|, |moment| / L) / F over the
free frames, with F the largest out-of-balance load at the rest pose under the full load and L
the trunk's length: dimensionless and invariant under a change of units. Steps are applied by
the strain-space retraction (:func:`~vertebra.solver.state.retract`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.potential import LoadCase, LoadCases, evaluate, nonpotential_forces, out_of_range, tangent
from vertebra.solver import globalise
from vertebra.solver.globalise import NEUTRAL
from vertebra.solver.representable import (COLLAPSE_LIMIT, FOLD_LIMIT, TURN_LIMIT, Unrepresentable,
                                           largest_turn, segment_of, turn_message)
from vertebra.solver.state import State, compose, kinematics, strain_change
from vertebra.solver import contact
from vertebra.core.errors import ConvergenceError

RESOLUTION = 1e-13     # corrections below this fraction of the extent (and radians) are rounding
MAX_TURN = 1.0         # rad: the largest change of a link's rotation in one step
MAX_STRETCH = 0.5      # the largest change of a link's translation strain in one step, per length
SHIFT_START = 1e-10    # μ tried first when the tangent is not positive definite
SHIFT_FLOOR = 1e-9     # μ below this is dropped (pure Newton)
SHIFT_CEILING = 1e12   # μ beyond this leaves steps below rounding: the stage has failed
BEND_SHIFT = 1e-2      # μ from which a negative-curvature step is weighed against the shifted one
TRUSTED_RESIDUAL = 1e-3   # a positive definite tangent this close to equilibrium stays so at it
ESCAPES = 3            # negative-curvature steps allowed per stage
SQRT3 = math.sqrt(3.0)
STRETCHING = 1e-3      # a step changing a translation strain by more than this share of the shortest link
SMALL_INCREMENT = 1.0 / 16.0   # a load increment this small that reaches an unrepresentable state: say so
BUDGET = 10            # a solve stops after BUDGET × max_iterations Newton iterations
OVERTIME = 2           # with contacts, a stage still improving goes on up to this × max_iterations more …
PROGRESS = 25          # … while its residual reached a new best within this many iterations
# continuation under loads without a potential, where the stepping above gives up (_continuation)
PATIENCE = 8           # a continuation stage fails after this many iterations without a new best residual
STAGE_ITERATIONS = 30  # iterations of one continuation stage at most
FINEST = 1e-6          # the smallest load increment continuation tries
LIMIT_POINT = 1e-2     # the tangent's smallest singular value, over its value at rest, below which
                       # the path is taken to end (a limit point or a bifurcation)
TRANSVERSAL = 1e-2     # the load's share along the singular direction from which the end is a limit point


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
    largest_turn: float = 0.0        # largest rotation of a link (rad) at the returned state
    message: str = ""                # why the solve did not converge
    out_of_range: tuple = ()         # RangeExcess: where the returned state leaves the range a
                                     # link energy was fitted on (empty: inside, or no fitted energies)
    bound_violations: tuple = ()     # BoundViolation: actuator quantities beyond the scene's bounds
                                     # (solver.bounds; set by TrunkModel.solve)
    contacts: tuple = ()             # contact.Contact: every candidate contact of the returned state
                                     # with its force (empty: the trunk declares no contact shapes)
    friction: object = None          # FrictionState after a frictional solve (solver.friction; None: frictionless)

    def __repr__(self) -> str:
        tip = ", ".join(f"{v:.6g}" for v in self.state.positions[-1])
        outside = f", out_of_range={len(self.out_of_range)}" if self.out_of_range else ""
        return (f"StaticResult(converged={self.converged}, iterations={self.iterations}, "
                f"residual={self.residual:.3g}, load_steps={self.load_steps}, tip=[{tip}] m{outside})")


def residual_weights(trunk) -> np.ndarray:
    """Per-DoF weights of the residual measure: 1 for forces, 1/L for moments."""
    return np.array([1.0] * 3 + [1.0 / trunk.frames.length_scale] * 3)


def residual_norm(residual: np.ndarray, reference: float, weights: np.ndarray) -> float:
    """max(|force|, |moment| / length scale) / reference over the frames (``weights``:
    :func:`residual_weights`)."""
    return float(np.maximum.reduce(np.abs(residual.reshape(-1, 6) * weights), None)) / reference


def _force_scale(trunk, gradient: np.ndarray) -> float:
    free = gradient[1:]
    return max(np.max(np.abs(free[:, :3]), initial=0.0),
               np.max(np.abs(free[:, 3:]), initial=0.0) / trunk.frames.length_scale)


def is_stable(trunk, ev, matrix=None) -> bool:
    """Is the equilibrium of ``ev`` stable: is its tangent (``matrix`` when already assembled)
    positive definite, up to neutral directions (``H + 1e-9·|diag H|`` is)? Only decidable for
    conservative loads (dead moments and follower loads make the tangent unsymmetric): then
    assumed so."""
    if trunk.loads.unsymmetric:
        return True
    return (matrix or tangent(trunk, ev)).factor(NEUTRAL, definite=True)[0] is not None


def reference_force(trunk, load: LoadCase) -> float:
    """Force scale of the problem: the out-of-balance load at the rest pose under ``load`` (the
    full load), computed once per load case."""
    if load.reference is None:
        load.reference = _force_scale(trunk, evaluate(trunk, trunk.rest_state, load).gradient)
    return load.reference


class _Stage:
    """One Newton run at a fixed load factor: its inputs and what it found."""

    def __init__(self, trunk, load: LoadCase, tolerance: float, max_iterations: int, reference: float,
                 history: list, kinds: set, shift: float, linear: np.ndarray | None = None, friction=None):
        self.iterations = 0
        self.linear = linear                  # the links' rotations in the linear response to the full load
        self.trunk, self.load = trunk, load
        self.tolerance, self.max_iterations = tolerance, max_iterations
        self.reference = reference            # force scale at this load factor
        self.history = history
        self.kinds = kinds                    # factor kinds used, and "rounding-limited" / "unstable" flags
        self.shift = shift                    # μ, carried from stage to stage
        self.weights = residual_weights(trunk)
        self.symmetric = not trunk.loads.unsymmetric
        self.axis, self.shortest = trunk.rest.axis, trunk.rest.shortest   # a link's axial stretch is ρ · axis
        self.turn = 0.0                       # largest link rotation of the current state
        self.stretching = True                # the last step may have changed a link's length
        self.patience = None                  # iterations without a new best residual before the
                                              # stage fails (None: only max_iterations ends it)
        self.overtime = 0                     # iterations beyond max_iterations while the residual
                                              # reaches new bests (within PROGRESS iterations)
        # unilateral contacts (None: the trunk declares none and no contact code runs)
        # (with friction at obstacles, solver/contact_friction.py: their slip rows join the contacts')
        self.constraints = (None if trunk.contact is None else contact.Constraints(trunk) if friction is None
                            else friction.constraints(trunk))

    def norm(self, ev, state=None) -> float:
        """The scaled residual of ``ev`` (with contacts: of the Lagrangian at ``state``, the
        current contact forces included)."""
        if self.constraints is None:
            return residual_norm(ev.gradient[1:], self.reference, self.weights)
        return residual_norm(self.constraints.balance(ev.gradient, state)[1:], self.reference, self.weights)

    def stable(self, ev, matrix=None, state=None) -> bool:
        """:func:`is_stable`; with pressed contacts, on the directions they leave free."""
        if self.constraints is not None:
            if matrix is None:
                matrix = self.constraints.lagrangian(tangent(self.trunk, ev), state)
            matrix = self.constraints.stiffened(matrix, state)
        return is_stable(self.trunk, ev, matrix)

    def converged(self, residual: float, state) -> bool:
        """In balance to the tolerance (with contacts: and no gap open under a force, none closed
        beyond the tolerance)."""
        return residual <= self.tolerance and (self.constraints is None or self.constraints.feasible(state))

    def below_resolution(self, state: State, dq: np.ndarray, alpha: float = 1.0) -> bool:
        """Is every translation of ``α·dq`` below 1e-13 of the extent and every rotation below
        1e-13 rad?"""
        extent = self.trunk.frames.length_scale + float(np.maximum.reduce(np.abs(state.positions), None))
        largest = np.maximum.reduce(np.abs(dq).reshape(-1, 6)).tolist()     # per component, over the frames
        return alpha * max(max(largest[:3]) / extent, max(largest[3:])) <= RESOLUTION

    def at_resolution(self, state: State, ev, matrix, r: np.ndarray, dq: np.ndarray | None, kind: str,
                      residual: float) -> str:
        """The verdict on a state whose Newton step fell below the resolution of its poses:
        "rounding-limited" (in balance to rounding), "stalled" or "unstable". Only the undamped,
        uncapped Newton correction ``dq`` (None: the step taken was damped or capped; it is then
        computed from the unshifted factor) being below resolution says the residual is
        rounding, and the residual must then be what a correction at the resolution explains:
        at most ``|K|`` times it (:meth:`rounding_floor`), or the tolerance."""
        if dq is None:
            factor, kind = matrix.factor(0.0, symmetric=self.symmetric, definite=self.symmetric)
            if factor is None:
                return "stalled"
            dq = factor.solve(r)
            if not self.below_resolution(state, dq):
                return "stalled"
        if residual > max(self.tolerance, self.rounding_floor(state, matrix)):
            return "stalled"
        if not ((kind == "cholesky" and self.constraints is None) or self.stable(ev, matrix, state)):
            return "unstable"
        return "rounding-limited"

    def rounding_floor(self, state: State, matrix) -> float:
        """The scaled residual that a correction at the resolution of the poses (:data:`RESOLUTION`
        of the extent, and radians) can leave: ``|K| δ`` in the residual's norm."""
        extent = self.trunk.frames.length_scale + float(np.maximum.reduce(np.abs(state.positions), None))
        band = np.abs(matrix.symmetric_band())
        n = band.shape[1]
        delta = np.tile(np.array([extent] * 3 + [1.0] * 3) * RESOLUTION, n // 6)
        bound = band[0] * delta
        for k in range(1, band.shape[0]):              # row j + k, column j of the lower band, and its mirror
            bound[k:] += band[k, :n - k] * delta[:n - k]
            bound[:n - k] += band[k, :n - k] * delta[k:]
        if matrix.low_rank is not None:                # the tendons' dense term |U| diag(d) |U|ᵀ δ
            U, d = matrix.low_rank
            bound += np.abs(U) @ (d * (np.abs(U).T @ delta))
        return 2.0 * residual_norm(bound, self.reference, self.weights)

    def step_limit(self, dq: np.ndarray, change: np.ndarray, ev) -> float:
        """The largest multiple of a step (frame increments ``dq``, strain change ``change``) that
        turns no link by more than :data:`MAX_TURN`, stretches none by more than
        :data:`MAX_STRETCH` of the shortest link, takes no link more than half-way from the
        largest rotation to π and leaves every cable piece at least half as long as it is (its
        holes moved to first order; a piece may swing round, but its holes never pass through
        each other): a state approaches what it cannot represent only gradually, never by
        overshooting."""
        largest = np.maximum.reduce(np.abs(change)).tolist()   # per component, over the links
        room = min(MAX_TURN, 0.5 * (math.pi - self.turn))
        stretch = SQRT3 * max(largest[:3])
        self.stretching |= stretch > STRETCHING * self.shortest
        limit = min(room / max(SQRT3 * max(largest[3:]), 1e-300), MAX_STRETCH * self.shortest / max(stretch, 1e-300))
        pieces = ev.pieces
        if pieces is not None:
            # |d + α Δd| ≥ ½ |d| for every piece (Δd = Cᵀ dq its linearised change): the first
            # root in α of |d|² + 2α d·Δd + α²|Δd|² = ¼|d|², where there is one
            moves = np.zeros((self.trunk.frames.count, 6))
            moves[1:] = dq.reshape(-1, 6)
            delta = pieces.change(moves.take(self.trunk.cables.ends, 0, mode="clip").reshape(-1, 12))
            along = np.add.reduce(pieces.d * delta, 1)                          # d·Δd
            squared = np.add.reduce(delta * delta, 1)                           # |Δd|²
            discriminant = along * along - 0.75 * squared * pieces.length ** 2
            closing = (along < 0.0) & (discriminant > 0.0)
            if closing.any():
                roots = (-along[closing] - np.sqrt(discriminant[closing])) / squared[closing]
                limit = min(limit, float(roots.min()))
        return limit

    def represented(self, state: State, ev) -> None:
        """Raise :class:`Unrepresentable` when a link of ``state`` (evaluated in ``ev``) turns
        beyond :data:`TURN_LIMIT` or folds through itself, or a cable piece collapses; keep the
        largest link rotation."""
        xi = ev.links.xi
        record = state.carried_strains()
        self.turn = math.sqrt(record.chain.largest_turn2) if record is not None else largest_turn(xi)
        if self.turn > TURN_LIMIT:
            raise Unrepresentable(turn_message(self.trunk, xi, self.load.scale, self.linear), state)
        if self.constraints is not None and self.trunk.contact.disc_frame.size > 1:
            pair = contact.interpenetrating(self.trunk.contact, self.constraints.at(state))
            if pair is not None:
                raise Unrepresentable(
                    f"{contact.describe(self.trunk.contact, pair)} have gone into each other by "
                    f"more than half their thickness at load factor {self.load.scale:.3g}: a step or a load increment "
                    "pushed one through the other, which the disc–disc gap cannot follow", state)
        pieces = ev.pieces
        if pieces is not None:
            ratio = pieces.length / self.trunk.rest_piece_lengths
            k = int(np.argmin(ratio))
            if ratio[k] < COLLAPSE_LIMIT:
                cables = self.trunk.cables
                vertebra = np.searchsorted(self.trunk.frames.vertebra, [cables.piece_a[k], cables.piece_b[k]])
                raise Unrepresentable(
                    f"cable {self.trunk.actuators.names[cables.owner[k]]!r} between vertebrae {vertebra[0]} and "
                    f"{vertebra[1]} shrinks to {ratio[k]:.2g} of its rest length at load factor {self.load.scale:.3g}: "
                    "the holes of the two vertebrae meet (their discs would collide), which the cable routing "
                    "cannot represent; the tensions bend the robot further than its vertebrae allow", state)
        if self.stretching:           # (a step that changes no link's length noticeably folds none)
            self._folded(state, xi)

    def _folded(self, state: State, xi: np.ndarray) -> None:
        """Raise :class:`Unrepresentable` when a link is compressed below :data:`FOLD_LIMIT`."""
        axial = np.add.reduce(xi[:, :3] * self.axis, 1)
        if float(axial.min()) < FOLD_LIMIT:
            k = int(np.argmin(axial))
            segment, _ = segment_of(self.trunk, k)
            raise Unrepresentable(
                f"link {k} (segment {segment}) is compressed to {axial[k]:.2g} of its length at load factor "
                f"{self.load.scale:.3g}: it folds through itself, which a link cannot represent "
                "(the load crushes the segment)", state)


def _raise_shift(shift: float, factor: float) -> float:
    return max(SHIFT_START, factor * shift)


def _newton(stage: _Stage, state: State):
    """Newton iterations at a fixed load factor (module docstring). Returns (ok, state, residual);
    the iterations taken are counted in ``stage.iterations``."""
    trunk, load, kinds = stage.trunk, stage.load, stage.kinds
    symmetric = stage.symmetric
    ev = evaluate(trunk, state, load)
    constraints = stage.constraints
    residual = stage.norm(ev, state)
    if not math.isfinite(residual + ev.energy):
        raise ConvergenceError(f"non-finite values appeared in the evaluation of the start state (the initial "
                               f"state given, or the last converged stage) at load factor {load.scale:.3g}")
    stage.represented(state, ev)
    r = -ev.gradient[1:].reshape(-1)
    # (the merit's loads without a potential, here; None when the loads are conservative)
    work = None if symmetric else nonpotential_forces(trunk, state, load)
    # the last direction came from the unshifted Cholesky factor (a positive definite tangent) at a
    # state already close to equilibrium: the equilibrium reached from it is taken as stable
    trusted = False
    escapes = 0
    best, best_at = math.inf, 0       # the smallest residual of the stage and its iteration
    while True:
        stage.history.append(residual)
        converged = stage.converged(residual, state)
        if converged:
            if trusted or stage.stable(ev, state=state):
                return True, state, residual
            if escapes == ESCAPES:
                # a saddle that the negative-curvature steps did not leave
                kinds.add("unstable")
                return False, state, residual
        if residual < best:
            best, best_at = residual, stage.iterations
        elif stage.patience is not None and stage.iterations - best_at >= stage.patience:
            return False, state, residual       # circling: no new best residual for a while
        if stage.iterations >= stage.max_iterations and (
                stage.iterations >= stage.max_iterations + stage.overtime or stage.iterations - best_at >= PROGRESS):
            return False, state, residual
        stage.iterations += 1
        stage.stretching = False
        matrix = factored = tangent(trunk, ev)
        if constraints is not None:
            matrix = factored = constraints.lagrangian(matrix, state)     # the Lagrangian's tangent
        shift = stage.shift
        scale = None
        step = unshifted = None
        if not symmetric and constraints is None and not converged:
            # loads without a potential: the full Newton step first, taken when it halves the
            # residual (globalise.residual_step: where the energy-like merit cannot judge it);
            # its factor serves the merit's unshifted step when it is not taken
            unshifted = matrix.factor(0.0, symmetric=False)
            step = globalise.residual_step(stage, state, ev, residual, unshifted[0], r)
            kind = "lu"
        forces = constraints.current() if constraints is not None else None    # the forces the tangent has
        indefinite = False       # a factor of this tangent failed: it is not positive definite
        respringed = False       # the contacts' springs were set again from a step's pressed contacts
        spring = 0.0             # the springs' stiffness along the pressed contacts (0: none)
        while step is None:      # until a step is accepted
            if shift > SHIFT_CEILING:
                return False, state, residual
            if shift and scale is None:
                scale = np.maximum(np.abs(matrix.diagonal()), trunk.rest.stiffness)
            if shift or unshifted is None:
                factor, kind = factored.factor(shift, symmetric=symmetric, scale=scale, definite=symmetric)
            else:
                factor, kind = unshifted
            if (factor is None and constraints is not None and constraints.multipliers.size
                    and spring < contact.STABILITY_SPRING and (factored is matrix or constraints.springs is not None)):
                # springs along the pressed contacts (an augmented Lagrangian): the tangent need
                # only be definite where the contacts leave the trunk free, and the step's QP
                # keeps the pressed contacts as they are; stiffer springs up to those that judge
                # stability (a tangent positive definite on the free directions takes them)
                spring = contact.STEP_SPRING if not spring else min(contact.SPRING_GROWTH * spring,
                                                                   contact.STABILITY_SPRING)
                factored = constraints.stiffened(matrix, state, spring)
                continue
            if factor is None:
                indefinite = True
                shift = _raise_shift(shift, 10.0)
                continue
            dq = curvature = None
            if not converged:
                if constraints is None:
                    dq = factor.solve(r)
                    balanced = r
                else:
                    # the sequential-QP step on the linearised gaps (solver/contact.py)
                    constrained = constraints.step(factor, r, state)
                    if constrained is None:
                        shift = _raise_shift(shift, 10.0)
                        continue
                    if factored is not matrix and not respringed and constraints.released(constrained):
                        # the step opens a contact that holds a spring: springs on those it keeps
                        factored = constraints.stiffened(matrix, state, spring, constrained)
                        respringed = True
                        continue
                    dq, balanced = constrained.dq, constrained.balanced
                    constraints.accept(constrained)
                rp = float(balanced @ dq)
                if not rp > 0.0:                    # an LU direction that does not descend (or NaN)
                    shift = _raise_shift(shift, 10.0)
                    continue
                if constraints is None:
                    curvature = rp - shift * float(dq @ (scale * dq)) if shift else rp    # pᵀHp: (H + μD)p = r
                else:
                    # pᵀHp of the Lagrangian's tangent itself: rp less the shift's and the springs'
                    # shares would leave the springs' rounding (k (Gp)², Gp ≈ 0 to the solve's accuracy)
                    curvature = matrix.quadratic(dq)
                change = strain_change(dq, ev.links)
                if stage.linear is None and ev.at_rest and not shift:
                    # the linear response from rest: what the load asks of each link, to first order
                    turns = change[:, 3:]
                    stage.linear = np.sqrt(np.add.reduce(turns * turns, 1)) / load.scale
                alpha = min(1.0, stage.step_limit(dq, change, ev))
                if stage.below_resolution(state, dq, alpha):
                    # the step is below the floating-point resolution of the poses: either the
                    # residual left is rounding (stop here and report it as it is), or the
                    # damping or a cap made the step short and the solve has stalled
                    if constraints is not None:
                        # (with contacts: the residual at the step's forces — a load that a contact
                        # touching at the start takes whole moves nothing)
                        residual = stage.norm(ev, state)
                    verdict = stage.at_resolution(state, ev, matrix, balanced, dq if not shift and alpha == 1.0 else None,
                                                  kind, residual)
                    kinds.add(verdict)
                    if verdict != "rounding-limited":
                        return False, state, residual
                    kinds.add(kind)
                    return True, state, residual
            if converged or (indefinite and shift >= BEND_SHIFT):
                # a negative-curvature step (as far as the strain-space caps allow) where it
                # promises more than the shifted Newton step: how a stationary point with an
                # indefinite tangent (a saddle) is left, and how a column compressed far beyond
                # its buckling load buckles (where the shift that makes the tangent positive
                # definite leaves only a short, gradient-like step). With contacts: on the
                # directions the pressed contacts leave free, at their forces before this
                # iteration's complementarity problem, and no farther than the other candidate
                # contacts' linearised gaps allow (globalise.bend)
                if constraints is not None:
                    if scale is None:
                        scale = np.maximum(np.abs(matrix.diagonal()), trunk.rest.stiffness)
                    taken = constraints.current()
                    constraints.resume(forces, state)
                bend = globalise.bend(stage, ev, r, factor, shift, scale, matrix, state)
                if bend is None and converged:
                    if constraints is None:
                        return True, state, residual        # the curvature is not negative: stable
                    kinds.add("unstable")         # the springs' test found it unstable, the free
                    return False, state, residual   # directions no negative curvature: refused
                if bend is not None and (dq is None or bend[-1] > alpha * rp - 0.5 * alpha * alpha * curvature):
                    dq, change, rp, curvature, _ = bend
                    alpha, kind = 1.0, "curvature"
                    escapes += converged
                elif constraints is not None:
                    constraints.resume(taken, state)
            # (with contacts, the residual a step must not raise is the one at the step's forces)
            before = residual if constraints is None or converged else stage.norm(ev, state)
            step = globalise.line_search(stage, state, ev, before, dq, change, alpha, rp, curvature, work)
            if step is not None:
                break
            if kind == "curvature" and converged:
                kinds.add("unstable")
                return False, state, residual
            shift = _raise_shift(shift, 10.0)
        trial, ev_trial, alpha, decrease, predicted, quality = step
        # how well the quadratic model predicted the full step sets μ for the next iteration
        if kind != "curvature":
            if quality >= 0.75:
                shift = 0.0 if shift / 4.0 < SHIFT_FLOOR else shift / 4.0
            elif quality < 0.25:
                shift = _raise_shift(shift, 4.0)
        stage.shift = shift
        trusted = kind == "cholesky" and residual <= TRUSTED_RESIDUAL
        kinds.add(kind)
        state, ev = trial, ev_trial
        if constraints is not None and (kind != "cholesky" or alpha < 1.0 or factored is not matrix):
            # after a shifted, stiffened or cut-back step: the pressed contacts' forces that
            # balance the new state best (a step whose complementarity problem overshot must not
            # carry its forces into the next tangent; a full Newton step's forces are these to
            # second order; a step below the energy's rounding that the step's forces left off
            # balance was judged, and is taken, at these: globalise.line_search)
            constraints.reestimate(ev.gradient, state, stage.weights)
        residual = stage.norm(ev, state)
        if not math.isfinite(residual):
            raise ConvergenceError(f"non-finite forces appeared after a Newton step at load factor {load.scale:.3g}")
        stage.represented(state, ev)
        r = -ev.gradient[1:].reshape(-1)
        work = None if symmetric else nonpotential_forces(trunk, state, load)


@dataclass
class _Continued:
    """What :func:`_continuation` reached."""

    converged: bool
    reached: tuple            # (load factor, state) of the last equilibrium on the path
    state: State              # the state returned: the last equilibrium, or where a stage found a state the
                              # links cannot represent
    residual: float           # and its residual
    load: LoadCase            # and its load case
    iterations: int
    stages: int
    message: str              # why it stopped ("" when converged)


def _predicted(trunk, path: tuple, target: float) -> State:
    """The start of the stage at load factor ``target``: the secant through the last two
    equilibria on the path (``path``: (earlier, last), each (load factor, state); earlier None:
    the last one itself), extrapolated in the links' strains and composed from the base."""
    earlier, (scale, state) = path
    if earlier is None or earlier[0] >= scale:
        return state
    xi, xi_before = kinematics(state).xi, kinematics(earlier[1]).xi
    t = (target - scale) / (scale - earlier[0])
    return compose(state.quaternions[0], state.positions[0], xi + t * (xi - xi_before))


def _continuation(trunk, loads: LoadCases, actuation: np.ndarray, path: tuple, reference: float, tolerance: float,
                  max_iterations: int, history: list, kinds: set, shift: float, linear) -> _Continued:
    """Load continuation from the last equilibrium of ``path`` ((earlier, last), each (load factor,
    state); :func:`_predicted`) where the load stepping of :func:`solve` gave up under loads without
    a potential. Dead moments and follower loads make the equilibria non-unique and Newton from a
    distant start may circle (their work round a closed loop of rotations is not zero): each stage
    starts from the secant predictor through the last two equilibria, fails once :data:`PATIENCE`
    iterations bring no new best residual (or after :data:`STAGE_ITERATIONS`), and the increment
    halves on failure and doubles on success, down to :data:`FINEST`, within ``BUDGET ×
    max_iterations / 2`` iterations. Where it cannot go on, the reason is named: a state the links
    cannot represent (as in :func:`solve`); a limit point, where the tangent's smallest singular
    value (:func:`~vertebra.solver.globalise.smallest_singular_value`) has fallen below
    :data:`LIMIT_POINT` of its value at rest — the equilibrium path turns back and the trunk would
    snap through, which continuation in the load factor cannot follow; or stages that do not
    converge although the tangent stays regular."""
    budget = BUDGET * max_iterations // 2
    earlier, (scale, state) = path
    increment = min(1.0 / 16.0, 1.0 - scale)
    iterations = stages = 0
    residual, why = math.inf, ""
    while iterations < budget:
        target = min(1.0, scale + increment)
        load = loads(actuation, target)
        stage = _Stage(trunk, load, tolerance if target >= 1.0 else max(tolerance, 1e-6),
                       min(max_iterations, STAGE_ITERATIONS, budget - iterations), reference * target, history,
                       kinds, shift, linear)
        stage.patience = PATIENCE
        try:
            ok, stopped, residual = _newton(stage, _predicted(trunk, (earlier, (scale, state)), target))
            why = ""
        except Unrepresentable as error:
            ok, stopped, why = False, error.state, str(error)
        iterations += stage.iterations
        stages += 1
        shift, linear = stage.shift, stage.linear
        if ok:
            earlier, scale, state = (scale, state), target, stopped
            if scale >= 1.0:
                return _Continued(True, (scale, state), state, residual, load, iterations, stages, "")
            increment = min(2.0 * increment, 1.0 - scale)
        else:
            increment *= 0.5
            if increment < FINEST:
                break
    if why and increment < SMALL_INCREMENT:
        return _Continued(False, (scale, state), stopped, residual, load, iterations, stages, why)
    # the last equilibrium on the path is what is returned, with why the path ends there
    load = loads(actuation, scale)
    residual = residual_norm(evaluate(trunk, state, load).gradient[1:], reference * max(scale, 1e-300),
                             residual_weights(trunk))
    return _Continued(False, (scale, state), state, residual, load, iterations, stages,
                      _turning_back(trunk, loads, actuation, scale, state, increment, iterations, budget))


def _turning_back(trunk, loads: LoadCases, actuation: np.ndarray, scale: float, state: State, increment: float,
                  iterations: int, budget: int) -> str:
    """Why continuation stopped at the equilibrium ``state`` at load factor ``scale``. Where the
    tangent ``K`` is near singular against the one at rest (smallest singular value below
    :data:`LIMIT_POINT` of it, in the rest stiffness's metric ``S``) the path ends in one of two
    ways: a limit point, where the load's derivative ``f = ∂r/∂λ`` has a part along the left
    singular direction ``u`` (``uᵀSf ≠ 0``: no equilibrium ``x(λ)`` continues beyond, the load
    factor turns back), or a bifurcation (``uᵀSf ≈ 0``: branches cross). Else: what was tried."""
    metric = trunk.rest.stiffness
    load = loads(actuation, scale)
    ev = evaluate(trunk, state, load)
    found = globalise.smallest_singular_value(tangent(trunk, ev), metric)
    at_rest = globalise.smallest_singular_value(
        tangent(trunk, evaluate(trunk, trunk.rest_state, loads(actuation, 0.0))), metric)
    tried = (f"in increments down to {increment:.2g} of the load" if increment < FINEST
             else f"within {iterations} continuation iterations (of {budget})")
    ratio = None if found is None or at_rest is None or not at_rest[0] else found[0] / at_rest[0]
    if ratio is not None and ratio < LIMIT_POINT:
        u = found[1]
        # the load's derivative in the metric: the gradient at no load less the one at this load factor
        f = ((evaluate(trunk, state, loads(actuation, 0.0)).gradient - ev.gradient)[1:].reshape(-1) / scale
             / np.sqrt(metric))
        along = abs(float(u @ f)) / max(float(np.linalg.norm(f)), 1e-300) if u is not None else 1.0
        if along >= TRANSVERSAL:
            return (f"no equilibrium found by continuation past load factor {scale:.4g} ({tried}): the equilibrium "
                    f"path turns back there (a limit point: the tangent's smallest singular value has fallen to "
                    f"{ratio:.2g} of its value at rest, and the load pushes along its singular direction), so beyond "
                    "it the trunk would snap through to another pose, which load continuation cannot follow; lower "
                    f"the loads to below {scale:.3g} of them, or solve from another pose (`initial`) on the side the "
                    "trunk should snap to")
        return (f"no equilibrium found by continuation past load factor {scale:.4g} ({tried}): the equilibrium path "
                f"branches there (a bifurcation: the tangent's smallest singular value has fallen to {ratio:.2g} of its "
                f"value at rest, and the load has no part along its singular direction: {along:.2g}); lower the loads "
                f"to below {scale:.3g} of them, or solve from another pose (`initial`) on the branch the trunk should take")
    regular = (f" although the tangent there stays regular (smallest singular value {ratio:.2g} of its value at "
               "rest: the path does not turn back)" if ratio is not None else "")
    return (f"no equilibrium found by continuation past load factor {scale:.4g} ({tried}){regular}: Newton from the "
            "equilibria reached does not converge at the next load factors (loads without a potential — dead moments, "
            "follower loads — have non-unique equilibria); lower the loads, or solve from another pose (`initial`)")


def solve(trunk, loads: LoadCases, actuation: np.ndarray, initial: State | None, *, tolerance: float,
          max_iterations: int, load_steps: int, raise_on_failure: bool = True, friction=None) -> StaticResult:
    """Equilibrium under ``actuation`` from ``initial`` (a warm start; None: the rest state, with
    the load stepped in ``load_steps`` stages); ``loads`` makes (and keeps) the load cases.
    ``friction``: a :class:`~vertebra.solver.contact_friction.Session` (friction at obstacle
    contacts: each converged stage is committed to it, and ``result.friction`` is its state).
    Raises :class:`ConvergenceError` (carrying the partial result) on failure unless
    ``raise_on_failure`` is False."""
    start = time.perf_counter()
    full = loads(actuation, 1.0)
    reference = reference_force(trunk, full)
    if not math.isfinite(reference):
        raise ConvergenceError("non-finite values appeared in the actuation or the loads (the out-of-balance "
                               "force at rest is not finite)")
    history, kinds = [], set()
    pressed = None            # the contact forces of the last stage (contact.Constraints)
    state = (initial or trunk.rest_state).copy()
    if reference == 0.0:
        # nothing loads the rest pose: the start is the answer when it is in balance, else its
        # own out-of-balance force sets the scale
        gradient = evaluate(trunk, state, full).gradient
        if not np.any(gradient[1:]):
            return StaticResult(True, 0, 0.0, state, actuation, [0.0], 1, "none",
                                {"solve_s": time.perf_counter() - start}, largest_turn=_turn(state),
                                friction=None if friction is None else friction.state_of(None, state))
        reference = _force_scale(trunk, gradient)

    scale, increment = 0.0, 1.0 / load_steps
    if initial is not None:
        increment = 1.0   # warm start: try the full load from the given pose first
    iterations, stages = 0, 0
    last_good = state_new = state
    converged = False
    residual = math.inf
    shift, linear = 0.0, None
    message = ""
    # the equilibrium before last_good on the loading path, (load factor, state), for continuation's
    # predictor (None: last_good is the first, or a warm start that is no equilibrium at 0)
    previous = None
    from_rest = initial is None
    while True:
        target = min(1.0, scale + increment)
        load = loads(actuation, target)
        stage = _Stage(trunk, load, tolerance if target >= 1.0 else max(tolerance, 1e-6),
                       min(max_iterations, BUDGET * max_iterations - iterations),
                       reference * max(target, 1e-300), history, kinds, shift, linear, friction)
        if stage.constraints is not None:
            # a contact stage still improving at max_iterations goes on (within the budget): contacts
            # that change along a long fall (a soft trunk snapping onto its discs) take many short
            # steps, and a smaller increment would start that fall again from the last equilibrium
            stage.overtime = max(0, min(OVERTIME * max_iterations, BUDGET * max_iterations - iterations
                                        - stage.max_iterations))
        try:
            ok, state_new, residual = _newton(stage, last_good)
        except Unrepresentable as why:
            # a large load increment may overshoot into a state the links cannot represent
            # where the loading path does not go: retry in smaller increments, and say why
            # once small increments lead there too
            message, state_new, ok = str(why), why.state, False
            if target - scale <= SMALL_INCREMENT:
                iterations += stage.iterations
                stages += 1
                break
        else:
            message = ""
        iterations += stage.iterations
        stages += 1
        # (with contacts, a failed stage's shift, raised until its steps fell below resolution, is
        # not carried into the smaller increment: every retry would start, and stall, there)
        shift, linear = (stage.shift if ok or stage.constraints is None else shift), stage.linear
        if stage.constraints is not None:
            pressed = stage.constraints
        if ok:
            if friction is not None:
                friction.commit(stage.constraints, state_new)
            if from_rest or scale > 0.0:
                previous = (scale, last_good)
            last_good, scale = state_new, target
            if scale >= 1.0:
                converged = True
                break
            increment = min(2.0 * increment, 1.0 - scale)
        else:
            if (initial is not None and scale == 0.0 and last_good is not trunk.rest_state and stages == 1
                    and (friction is None or friction.history is None)):
                last_good = trunk.rest_state.copy()   # warm start failed: step the load from rest
                from_rest = True
                if friction is not None:
                    friction.restart(last_good)
                increment = 1.0 / load_steps
                continue
            increment *= 0.5
            if increment < 1e-4 or iterations >= BUDGET * max_iterations:
                break
    if not converged and not message and trunk.loads.unsymmetric and trunk.contact is None and "unstable" not in kinds:
        # loads without a potential, where the stepping above gave up: continuation
        continued = _continuation(trunk, loads, actuation, (previous, (scale, last_good)), reference,
                                  tolerance, max_iterations, history, kinds, shift, linear)
        iterations += continued.iterations
        stages += continued.stages
        converged, message, residual, load = continued.converged, continued.message, continued.residual, continued.load
        scale, last_good = continued.reached
        state_new = last_good if converged else continued.state
    if converged and trunk.contact is not None:
        overlap = contact.overlapping(trunk.contact, last_good)
        if overlap is not None:
            # the safety net behind the contacts of non-adjacent discs: an equilibrium through two
            # discs that its contacts did not hold apart is not one
            converged, state_new = False, last_good
            message = (f"the discs of vertebrae {overlap[0]} and {overlap[1]} overlap by {overlap[2]:.3g} m at the "
                       "equilibrium found, which their contact did not prevent (docs/contact.md), so it is not an "
                       "equilibrium; lower the loads or tensions, or declare smaller discs")
    limited = "rounding-limited" in kinds
    saddles = "unstable" in kinds
    stalled = "stalled" in kinds
    kinds -= {"rounding-limited", "unstable", "stalled"}
    final = last_good if converged else state_new
    if not converged and not message and saddles and residual <= tolerance:
        # in balance, refused for stability: say that, not the residual
        message = (f"the equilibrium found at load factor {load.scale:.4g} is unstable and was refused: it is in balance "
                   f"(scaled residual {residual:.3g} ≤ {tolerance:g}) but its tangent is indefinite"
                   + (" on the directions the pressed contacts leave free (the robot would buckle or roll sideways off "
                      "what it touches)" if trunk.contact is not None else " (a saddle: the robot would buckle)")
                   + f"; no stable equilibrium was found beyond load factor {scale:.4g} in {iterations} iterations and "
                   f"{stages} load stages. Lower the loads or tensions, stiffen the backbone, or start from another "
                   "pose (`initial`) on the side the robot should buckle to")
    if not converged and not message:
        message = (f"Newton did not converge: scaled residual {residual:.3g} > {tolerance:g} after {iterations} "
                   f"iterations and {stages} load stages (reached load factor {scale:.4g})"
                   + ("; equilibria found on the way were unstable (indefinite tangent) and refused"
                      if saddles else "")
                   + ("; the steps fell below the floating-point resolution of the poses while the residual was "
                      "still above what rounding explains (no step lowered the energy: it may overflow or the "
                      "loads are beyond what the trunk can carry)" if stalled else ""))
    excess = (out_of_range(trunk, kinematics(final).xi, loads(actuation, 1.0 if converged else load.scale))
              if trunk.links.fitted else ())
    if excess and not converged:
        worst = max(excess, key=lambda e: e.excess)
        message += (f"; {len({e.link for e in excess})} link(s) of nonlinear entries left their fitted range "
                    f"(largest: {worst}): beyond it an entry runs on its linear stiffness plus the fit's boundary "
                    "force — widen the entry's sampled range (`vertebra design … --sampling …`) or let "
                    "`vertebra prepare` size it from the scene")
    contacts = ()
    if trunk.contact is not None:
        contacts = (pressed.report(final) if pressed is not None
                    else contact.report(trunk.contact, final, np.zeros((0, 3), int), np.zeros(0)))
    result = StaticResult(converged, iterations, float(residual), final, actuation, history, stages,
                          "+".join(sorted(kinds)) or "none", {"solve_s": time.perf_counter() - start},
                          rounding_limited=limited and converged, largest_turn=_turn(final),
                          message=message, out_of_range=excess, contacts=contacts,
                          friction=None if friction is None else friction.state_of(pressed, final))
    if not converged and raise_on_failure:
        raise ConvergenceError(message, result)
    return result


def _turn(state: State) -> float:
    record = state.carried_strains()
    if record is not None:
        return math.sqrt(record.chain.largest_turn2)
    return largest_turn(kinematics(state).xi)
