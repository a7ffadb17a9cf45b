"""Tendon friction at the holes: the capstan law with sticking, and the path-dependent solve.

A cable runs through the holes of its vertebrae (its *route*: the proximal — actuated — hole
first, the terminating hole last). Each stretch between two consecutive holes is a *span* (a
piece of :class:`~vertebra.solver.cables.CableRouting`) with its own tension; at an interior
hole the cable turns by the angle ``Δθ`` between its incoming and outgoing spans (from the
frames' poses: it changes with the shape). With a friction coefficient ``μ`` the hole is

* sliding towards the base (``slip = +1``, the cable being pulled in): ``T_out = T_in e^(−μΔθ)``;
* sliding away from the base (``slip = −1``, the cable paid out): ``T_out = T_in e^(+μΔθ)``;
* stuck (``slip = 0``) while ``T_in e^(−μΔθ) ≤ T_out ≤ T_in e^(+μΔθ)``.

(point contact at the holes, no bending stiffness of the cable: docs/friction.md). The result
depends on the history of the commands, which a :class:`FrictionState` carries: every span's
tension, the unstretched length of every span of a stroke-driven tendon, and every hole's
slip and last slip direction.

One command is one increment from the state it is applied to, solved as a fixed point:

1. the *return map* (:func:`transmission`) at the current poses: from the committed state, the
   spans' tensions that the friction law allows (tension-driven cable: the command is the first
   span's tension and every stuck span keeps its tension, clipped into its hole's band — a
   sweep from the base; stroke-driven tendon: the spans are springs that share its compliance
   by rest length, the stroke takes material out of the first span, and the holes' statuses
   are found by an active-set iteration in which runs of spans joined by sliding holes exchange
   material and carry capstan-related tensions);
2. the frames' equilibrium for those span tensions (tension-driven spans: fixed tensions, the
   potential ``Σ T L``; a run of tendon spans: one spring on the capstan-weighted length
   ``Σ g L``) with the existing Newton solver — an energy minimum, so well posed;
3. repeated from the new poses until the tensions the return map gives there equal the tensions
   the equilibrium was found with (relative change ≤ :data:`FIXED_POINT`) and no hole changed
   its status. With ``μ = 0`` every factor is exactly 1: the first equilibrium is today's
   frictionless one and the return map reproduces its tensions bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import ConvergenceError, OptionError
from vertebra.core.lie import qmatrix
from vertebra.solver import newton, outputs
from vertebra.solver.cables import CablePieces
from vertebra.solver.potential import LoadCase, Tendons, evaluate

FIXED_POINT = 1e-12     # relative change of the span tensions at which the fixed point has converged
MAX_ROUNDS = 100        # return map / equilibrium rounds of an increment that is not split further
SPLIT_ROUNDS = 25       # rounds after which an increment is applied in two halves
UNSETTLED = 8           # rounds of changing hole statuses after which the holes that changed are held sliding
MAX_SPLITS = 4          # an increment is split into 2^MAX_SPLITS parts at most
SLIP = 1e-12            # relative excess of a hole's band (or backflow of a sliding hole) that changes its status

__all__ = ["FrictionState", "Routes", "Transmission", "equilibrium_sensitivities", "linearise", "routes", "sensitivities", "sequence_sensitivities", "solve",
           "solve_sequence", "transmission", "transmission_ratios", "turning_angles", "piecewise", "EDGE"]


@dataclass(frozen=True)
class Routes:
    """The spans (pieces) of every cable in route order, proximal first."""

    pieces: tuple             # per cable: (n_c,) piece indices
    previous: np.ndarray      # (m,) the piece before each in its route (−1: the first)
    first: np.ndarray         # (n_cables,) the first piece of every cable

    @property
    def interior(self) -> np.ndarray:
        """The pieces that start at an interior hole of their route."""
        return np.flatnonzero(self.previous >= 0)


_ROUTES: dict = {}


def routes(cables) -> Routes:
    """The route of every cable of a :class:`~vertebra.solver.cables.CableRouting` (its pieces
    are sorted by their first frame, so a cable's pieces come in route order); made once per
    routing (kept beside its read-only ``owner`` array)."""
    kept = _ROUTES.get(id(cables.owner))
    if kept is not None and kept[0] is cables.owner:
        return kept[1]
    if len(_ROUTES) > 64:
        _ROUTES.clear()
    _ROUTES[id(cables.owner)] = (cables.owner, made := _routes(cables))
    return made


def _routes(cables) -> Routes:
    pieces = tuple(np.flatnonzero(cables.owner == k) for k in range(cables.n_cables))
    previous = np.full(cables.owner.size, -1)
    for run in pieces:
        previous[run[1:]] = run[:-1]
    return Routes(pieces, previous, np.array([run[0] for run in pieces], int))


def turning_angles(routes: Routes, d: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(m,) the angle by which each cable turns at the proximal hole of each piece (0 at the
    first hole of a route) from the pieces' spans ``d`` (m, 3) and lengths (m,)."""
    u = d / length[:, None]
    angle = np.zeros(length.size)
    inner = routes.interior
    a, b = u[routes.previous[inner]], u[inner]
    angle[inner] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.add.reduce(a * b, 1))
    return angle


def geometry(trunk, state) -> tuple:
    """The pieces' lengths (m,) and turning angles (m,) at ``state`` (None: the rest state)."""
    state = trunk.rest_state if state is None else state
    _, d, length = trunk.cables.spans(state.positions, qmatrix(state.quaternions))
    return length, turning_angles(routes(trunk.cables), d, length)


@dataclass(frozen=True)
class FrictionState:
    """What a frictional solve leaves behind for the next command: the history."""

    actuation: np.ndarray     # the command it was reached under
    state: object             # the frames' State (None: the rest state)
    tension: np.ndarray       # (m,) every span's tension, N
    material: np.ndarray      # (m,) unstretched length of every span of a stroke-driven tendon (nan elsewhere), m
    slip: np.ndarray          # (m,) at each span's proximal hole: +1 sliding towards the base, −1 away, 0 stuck
    direction: np.ndarray     # (m,) the last slip direction there (0: never slid)

    @classmethod
    def rest(cls, trunk) -> "FrictionState":
        """The trunk at rest under zero commands: tension-driven cables slack, stroke-driven
        tendons at their pretension, spread over the spans by rest length."""
        actuators, cables = trunk.actuators, trunk.cables
        m = cables.owner.size
        tension = np.zeros(m)
        material = np.full(m, np.nan)
        for c in actuators.tendons.tolist():
            run = np.flatnonzero(cables.owner == c)
            share = _shares(trunk, c, run)
            k, pretension = actuators.cable_stiffness[c], actuators.pretension[c]
            material[run] = trunk.rest_piece_lengths[run] - share * pretension / k
            tension[run] = max(pretension, 0.0)
        zeros = np.zeros(m, np.int8)
        return cls(np.zeros(actuators.default.size), None, tension, material, zeros, zeros.copy())

    def stick(self, routes: Routes) -> list:
        """Per cable: one flag per interior hole of its route — is the cable stuck there?"""
        return [(self.slip[run[1:]] == 0).tolist() for run in routes.pieces]

    def incipient(self, trunk) -> np.ndarray:
        """(m,) the slip status each hole would take when the command goes on as it went (for
        :func:`linearise`): a sliding hole its status; a stuck hole of a tension-driven cable the
        direction it slid in last (it counts only where its tension sits on that edge of its band:
        a command that stopped, then goes on); a tendon's stuck hole 0 (its material would flow)."""
        tendon = trunk.actuators.stroke_driven[trunk.cables.owner]
        return np.where((self.slip != 0) | tendon, self.slip, self.direction).astype(np.int8)

    @classmethod
    def after(cls, history: "FrictionState", current: "Transmission", actuation: np.ndarray, state) -> "FrictionState":
        """The state a command ``actuation`` applied to ``history`` leaves at ``state`` when
        ``current`` is the return map there (a control tick commits its predicted state so: the
        next tick starts from it)."""
        direction = np.where(current.slip != 0, current.slip, history.direction).astype(np.int8)
        return cls(np.array(actuation, float), state, current.tension, current.material, current.slip, direction)


def _shares(trunk, cable: int, run: np.ndarray) -> np.ndarray:
    """The share of a tendon's compliance ``1/k`` that each of its spans holds: its rest length
    over the cable's."""
    return trunk.rest_piece_lengths[run] / trunk.rest_cable_lengths[cable]


@dataclass
class Transmission:
    """The return map's answer at one set of poses: the spans' tensions and statuses, the tendons'
    new unstretched lengths and the load it makes for the frames' equilibrium."""

    tension: np.ndarray       # (m,) every span's tension at these poses
    slip: np.ndarray          # (m,) int8
    material: np.ndarray      # (m,) tendons' unstretched span lengths (nan elsewhere)
    driven: np.ndarray | None     # (m,) tension of the tension-driven spans (None: all slack)
    tendons: Tendons | None       # the tendon units (None: today's per-cable tendons, or none)
    tendon_scaled: np.ndarray | None = None   # per unit: True where the spring is scaled with the load factor

    def load(self, trunk, actuation: np.ndarray, scale: float, previous: LoadCase | None = None) -> LoadCase:
        """The load case of the frames' equilibrium under ``actuation`` at load factor ``scale``."""
        base = LoadCase.of(trunk, actuation, scale, previous)
        driven = None if self.driven is None else scale * self.driven
        tendons = base.tendons
        if self.tendons is not None:
            t = self.tendons
            stiffness = np.where(self.tendon_scaled, scale * t.stiffness, t.stiffness)
            shift = np.where(self.tendon_scaled, t.shift, scale * t.shift)
            tendons = dataclasses.replace(t, stiffness=stiffness, shift=shift)
        return dataclasses.replace(base, piece_tension=driven, tendons=tendons, reference=None)


def transmission(trunk, history: FrictionState, actuation: np.ndarray, lengths: np.ndarray,
                 angles: np.ndarray, guess: np.ndarray | None = None, pinned: np.ndarray | None = None) -> Transmission:
    """The return map from the committed ``history`` under the command ``actuation`` at poses with
    span ``lengths`` and turning ``angles`` (module docstring); ``guess``: the holes' statuses
    the tendons' active-set iteration starts from (an earlier round's; None: every hole stuck);
    ``pinned``: (m,) holes of tendons held at the ``guess``'s sliding status (incipient slip)."""
    actuators, cables = trunk.actuators, trunk.cables
    route = routes(cables)
    mu = actuators.friction
    m = lengths.size
    tension = np.zeros(m)
    slip = np.zeros(m, np.int8)
    material = np.full(m, np.nan)
    driven = np.zeros(m)
    frictional = [c for c in actuators.tendons.tolist() if mu[c] > 0.0]
    for c, run in enumerate(route.pieces):
        if actuators.stroke_driven[c]:
            if mu[c] > 0.0:
                continue
            k = actuators.cable_stiffness[c]         # a frictionless tendon: one run, every factor 1
            compliance = _shares(trunk, c, run) / k
            trial = history.material[run].copy()
            trial[0] -= actuation[c] - history.actuation[c]
            status = np.ones(run.size, np.int8)
            status[0] = 0
            tau = (lengths[run].sum() - trial.sum()) / compliance.sum()
            tension[run], slip[run], material[run] = max(tau, 0.0), status, lengths[run] - compliance * tau
            continue
        T = float(actuation[c])
        old = history.tension[run]
        out = np.empty(run.size)
        status = np.zeros(run.size, np.int8)
        out[0] = T
        for j in range(1, run.size):
            turn = mu[c] * angles[run[j]]
            low, high = out[j - 1] * math.exp(-turn), out[j - 1] * math.exp(turn)
            status[j] = 1 if old[j] < low else -1 if old[j] > high else 0
            out[j] = min(max(old[j], low), high)
        tension[run], slip[run], driven[run] = out, status, out
    tendons = scaled = None
    if frictional:       # every frictional tendon's return map at once; one unit per run of spans joined by sliding holes
        spans = np.concatenate([route.pieces[c] for c in frictional])
        owner = cables.owner[spans]
        first = np.zeros(spans.size, bool)
        first[np.cumsum([0] + [route.pieces[c].size for c in frictional[:-1]])] = True
        compliance = trunk.rest_piece_lengths[spans] / trunk.rest_cable_lengths[owner] / actuators.cable_stiffness[owner]
        trial = history.material[spans].copy()
        trial[first] -= actuation[frictional] - history.actuation[frictional]
        status, g, tau, new, run = _tendon_spans(lengths[spans], angles[spans], mu[owner], trial, compliance, first,
                                                 None if guess is None else guess[spans],
                                                 None if pinned is None else pinned[spans])
        tension[spans], slip[spans], material[spans] = np.maximum(g * tau, 0.0), status, new
        count = int(run[-1]) + 1
        units = np.zeros(m, int)
        weights = np.zeros(m)
        units[spans], weights[spans] = run, g
        unit_cable = owner[status == 0]
        unit_k = 1.0 / np.bincount(run, compliance * g, count)
        unit_rest = np.bincount(run, trial, count) - np.bincount(run, (1.0 - g) * lengths[spans], count)
        unit_shift = np.zeros(count)
        scaled = np.ones(count, bool)
        others = [c for c in actuators.tendons.tolist() if mu[c] == 0.0]   # frictionless tendons among them: today's units
        for c in others:
            units[route.pieces[c]], weights[route.pieces[c]] = count, 1.0
            count += 1
        if others:
            k = actuators.cable_stiffness[others]
            unit_cable = np.concatenate([unit_cable, others])
            unit_k = np.concatenate([unit_k, k])
            unit_rest = np.concatenate([unit_rest, trunk.rest_cable_lengths[others]])
            unit_shift = np.concatenate([unit_shift, actuation[others] + actuators.pretension[others] / k])
            scaled = np.concatenate([scaled, np.zeros(len(others), bool)])
        tendon_piece = actuators.stroke_driven[cables.owner]
        units = np.where(tendon_piece, units, count)
        tendons = Tendons(np.asarray(unit_cable, int), unit_k, unit_rest, unit_shift, units,
                          np.where(tendon_piece, weights, 0.0))
    return Transmission(tension, slip, material, driven if np.any(driven) else None, tendons, scaled)


def _tendon_spans(L: np.ndarray, angle: np.ndarray, mu: np.ndarray, trial: np.ndarray, compliance: np.ndarray,
                  first: np.ndarray, start: np.ndarray | None = None, pinned: np.ndarray | None = None):
    """The return map of the stroke-driven tendons at span lengths ``L`` (all their spans, each
    tendon's in route order, ``first`` marking where each starts; ``mu`` per span): the holes'
    statuses, the capstan factors ``g`` within each run of spans joined by sliding holes, the
    spans' tension before the tendon's slack is cut off (``τ g``) and their new unstretched
    lengths. From the statuses ``start`` (None: every hole stuck, the elastic trial) each tendon
    frees the hole whose band is exceeded most, or sticks the sliding hole whose material flows
    against its slip, one hole per round, until none is — all tendons at once (arrays over their
    spans); ``pinned`` holes keep their start status."""
    n = L.size
    status = np.zeros(n, np.int8) if start is None else np.array(start, np.int8)
    status[first] = 0
    free = ~first if pinned is None else ~(first | pinned)
    turn = mu * angle
    factor = np.exp(turn)
    cable = np.cumsum(first) - 1
    heads = np.flatnonzero(first)
    longest = int(np.max(np.diff(np.append(heads, n)), initial=1))
    for _ in range(4 * longest + 4):
        g, tau, new, run = _runs(L, turn, trial, compliance, status, first)
        T = np.maximum(g * tau, 0.0)
        scale = np.maximum(np.maximum.reduceat(T, heads), 1e-300)[cable]
        previous = np.empty(n)
        previous[0], previous[1:] = 0.0, T[:-1]
        # a stuck hole's band [T_{j−1} e^(−μΔθ), T_{j−1} e^(+μΔθ)] exceeded: it slides (+1 below, −1 above)
        low, high = (previous / factor - T) / scale, (T - previous * factor) / scale
        stuck = free & (status == 0)
        excess = np.where(stuck, np.maximum(low, high), -np.inf)
        # a sliding hole through which the run's material flows against its slip sticks: the flow
        # through hole j is the material the spans from j to the run's end gave up
        given = trial - new
        total = np.bincount(run, given)
        size = np.bincount(run, np.abs(trial))
        ahead = np.cumsum(given) - given              # given up by the spans before j (whole array)
        ahead_abs = np.cumsum(np.abs(trial)) - np.abs(trial)
        begin = np.flatnonzero(status == 0)           # the runs' first spans (every run starts at a stuck hole)
        flow = total[run] - (ahead - ahead[begin][run])
        through = size[run] - (ahead_abs - ahead_abs[begin][run])
        sliding = free & (status != 0) & (previous + T > 0.0)
        backflow = np.where(sliding, -status * flow / np.maximum(through, 1e-300), -np.inf)
        # per tendon: the worst band first (one hole per round), else the worst backflow
        worst_band = _first_largest(excess, heads, cable)
        worst_flow = _first_largest(backflow, heads, cable)
        band = excess[worst_band] > SLIP
        flows = ~band & (backflow[worst_flow] > SLIP)
        if not (band.any() or flows.any()):
            return status, g, tau, new, run
        j = worst_band[band]
        status[j] = np.where(low[j] > high[j], 1, -1)
        status[worst_flow[flows]] = 0
    raise ConvergenceError("the stick/slip states of a tendon's holes did not settle (the return map cycles)")


def _first_largest(values: np.ndarray, heads: np.ndarray, cable: np.ndarray) -> np.ndarray:
    """Per segment (starting at ``heads``): the index of its largest value, the first of equals."""
    largest = np.maximum.reduceat(values, heads)
    hit = values == largest[cable]
    index = np.flatnonzero(hit)
    return index[np.searchsorted(cable[index], np.arange(heads.size))]


def _runs(L: np.ndarray, turn: np.ndarray, trial: np.ndarray, compliance: np.ndarray, status: np.ndarray,
          first: np.ndarray):
    """Capstan factors, run tensions (per span, before the slack cut-off), new unstretched lengths
    and each span's run for the holes' ``status`` (runs split at stuck holes, which every tendon's
    first span is; each run keeps its material)."""
    head = status == 0
    run = np.cumsum(head) - 1
    step = np.where(head, 0.0, -status * turn)                  # ln g_j − ln g_{j−1}
    total = np.cumsum(step)
    g = np.exp(total - total[np.flatnonzero(head)][run])
    weight = np.bincount(run, compliance * g)
    t = (np.bincount(run, L) - np.bincount(run, trial)) / weight
    tau = t[run]
    return g, tau, L - compliance * g * tau, run


class _Loads:
    """The load cases of one transmission (newton.solve asks for them by actuation and factor)."""

    def __init__(self, trunk, transmission: Transmission):
        self.trunk, self.transmission = trunk, transmission
        self.kept = {}

    def __call__(self, actuation: np.ndarray, scale: float = 1.0) -> LoadCase:
        key = (actuation.tobytes(), scale)
        if key not in self.kept:
            previous = next(iter(self.kept.values()), None)
            self.kept[key] = self.transmission.load(self.trunk, actuation, scale,
                                                    previous if previous is not None and previous.scale == scale else None)
        return self.kept[key]


def solve(trunk, actuation: np.ndarray, history: FrictionState | None, initial=None, *, tolerance: float,
          max_iterations: int, load_steps: int, raise_on_failure: bool = True):
    """The equilibrium under ``actuation`` applied to ``history`` (None: from rest — a single
    command is a monotone pull), from ``initial`` poses (None: the history's). Returns a
    :class:`~vertebra.solver.newton.StaticResult` whose ``friction`` is the new
    :class:`FrictionState`. An increment whose fixed point does not settle in
    :data:`SPLIT_ROUNDS` rounds (holes that stick at one shape and slide at the shape that
    follows) is applied in two halves, each as a command of its own, down to
    ``2^-MAX_SPLITS`` of it: the path between two commands is then the straight one."""
    if history is None:
        history = FrictionState.rest(trunk)
    options = dict(tolerance=tolerance, max_iterations=max_iterations, load_steps=load_steps)
    result = _split(trunk, actuation, history, initial, options, 0)
    if not result.converged and raise_on_failure:
        raise ConvergenceError(result.message or "the frictional solve did not converge", result)
    return result


def _split(trunk, actuation, history, initial, options, depth):
    result = _increment(trunk, actuation, history, initial, options, MAX_ROUNDS if depth == MAX_SPLITS else SPLIT_ROUNDS)
    if result.converged or depth == MAX_SPLITS:
        return result
    first = _split(trunk, 0.5 * (history.actuation + actuation), history, initial, options, depth + 1)
    if not first.converged:
        return first
    second = _split(trunk, actuation, first.friction, first.state, options, depth + 1)
    second.iterations += first.iterations + result.iterations
    second.load_steps += first.load_steps + result.load_steps
    second.residual_history = result.residual_history + first.residual_history + second.residual_history
    return second


def _increment(trunk, actuation, history, initial, options, rounds):
    """One increment: the fixed point of the return map and the frames' equilibrium (module
    docstring) in at most ``rounds`` rounds; ``result.friction`` is None unless it settled."""
    if history is None:
        history = FrictionState.rest(trunk)
    state = initial if initial is not None else history.state
    lengths, angles = geometry(trunk, state)
    current = transmission(trunk, history, actuation, lengths, angles)
    iterations, stages, history_of_residuals = 0, 0, []
    # the tensions' scale: the largest before or after the command (a release to slack measures
    # the rounding left against the tension it released), at least the tension of a strain of
    # 1e-3 of the stiffest tendon — FIXED_POINT of it is the rounding of a tendon's length
    floor = max(1e-3 * float(np.max(trunk.actuators.cable_stiffness * trunk.rest_cable_lengths, initial=0.0)), 1e-300)
    converged = False
    change = math.inf
    seen, pinned = [], None         # the statuses of the rounds so far; the holes held at incipient slip
    for _ in range(rounds):
        loads = _Loads(trunk, current)
        result = newton.solve(trunk, loads, actuation, state, raise_on_failure=False, **options)
        iterations += result.iterations
        stages += result.load_steps
        history_of_residuals.extend(result.residual_history)
        if not result.converged:
            break
        state = result.state
        balanced = _span_tensions(trunk, state, loads(actuation, 1.0))
        lengths, angles = geometry(trunk, state)
        following = transmission(trunk, history, actuation, lengths, angles, current.slip, pinned)
        scale = max(float(np.abs(balanced).max(initial=0.0)), float(history.tension.max(initial=0.0)), floor)
        change = float(np.abs(following.tension - balanced).max(initial=0.0)) / scale
        # converged: the tensions the return map gives at the new poses are those the poses are
        # in balance with, or the poses did not move in this round (the round maps them to
        # themselves; what is left is the rounding of the tendons' run lengths)
        if (change <= FIXED_POINT or result.iterations == 0) and np.array_equal(following.slip, current.slip):
            converged = True
            break
        seen.append(current.slip)
        cycle = next((k for k, slip in enumerate(seen[:-1]) if np.array_equal(slip, following.slip)), None)
        if cycle is None and len(seen) >= UNSETTLED and not np.array_equal(following.slip, current.slip):
            cycle = len(seen) - UNSETTLED // 2
        if cycle is not None:
            # a cycle (or statuses that keep changing): holes that stick at one round's shape and
            # slide at a later one's sit at incipient slip — hold them sliding (their sliding
            # status over those rounds) for this increment
            statuses = np.array(seen[cycle:] + [following.slip])
            flips = np.any(statuses != statuses[0], axis=0)
            sliding = np.where(np.any(statuses > 0, axis=0), 1, -1)
            pinned = flips if pinned is None else pinned | flips
            guess = np.where(flips, sliding, following.slip).astype(np.int8)
            following = transmission(trunk, history, actuation, lengths, angles, guess, pinned)
            seen = []
        current = following
    result.iterations, result.load_steps, result.residual_history = iterations, stages, history_of_residuals
    if result.converged and not converged:
        result.converged = False
        result.message = (f"the friction fixed point did not converge in {rounds} rounds of an increment split "
                          f"{MAX_SPLITS} times (the span tensions still change by {change:.3g} of the largest)")
    if converged:
        direction = np.where(following.slip != 0, following.slip, history.direction).astype(np.int8)
        result.friction = FrictionState(actuation.copy(), result.state, balanced, following.material,
                                        following.slip, direction)
    return result


def transmission_ratios(trunk, current: Transmission, angles: np.ndarray, incipient: np.ndarray | None = None) -> np.ndarray:
    """(m,) how much of a change of each cable's command reaches each span in the current
    sliding direction: a tension-driven cable's ``∂T_j/∂T₀`` (the capstan factors up to the first
    stuck hole, 0 beyond it; a slack cable as if pulled), a tendon's ``∂T_j/∂s`` over the run of
    spans that holds its first span (``K g_j`` while taut, 0 elsewhere). ``incipient``: (m,)
    statuses of holes at incipient slip (:func:`linearise`)."""
    return _ratios(trunk, current, angles, incipient)[0]


EDGE = 1e-9     # relative distance of a stuck hole's tension from its band's edge at which it is at incipient slip


def _ratios(trunk, current: Transmission, angles: np.ndarray, incipient: np.ndarray | None):
    """:func:`transmission_ratios` and, per cable, the slip direction it took for holes at
    incipient slip (0: none taken) — the direction the command must keep for the ratios to hold."""
    actuators, cables = trunk.actuators, trunk.cables
    mu = actuators.friction
    ratio = np.zeros(cables.owner.size)
    continued = np.zeros(cables.n_cables, np.int8)
    tendons = current.tendons
    for c, run in enumerate(routes(cables).pieces):
        if not actuators.stroke_driven[c]:
            factor = 1.0
            for j, piece in enumerate(run):
                if j:
                    status = current.slip[piece]
                    turn = mu[c] * angles[piece]
                    if status == 0 and incipient is not None and incipient[piece] and continued[c] in (0, incipient[piece]):
                        # stuck on the edge of its band towards its last slip: it slides on when
                        # the command goes on in that direction
                        before, after = current.tension[run[j - 1]], current.tension[piece]
                        edge = before * math.exp(-turn if incipient[piece] > 0 else turn)
                        if abs(after - edge) <= EDGE * max(before, after):
                            status = continued[c] = incipient[piece]
                    if status == 0 and (current.tension[run[j - 1]] > 0.0 or current.tension[piece] > 0.0):
                        break                                   # stuck: the spans beyond keep their tension
                    factor *= math.exp(-turn if status >= 0 else turn)
                ratio[piece] = factor
        elif tendons is not None and current.tension[run[0]] > 0.0:
            unit = tendons.units[run[0]]
            spans = run[tendons.units[run] == unit]
            ratio[spans] = tendons.stiffness[unit] * tendons.weights[spans]
            if incipient is not None and run.size > 1 and spans.size > 1:
                continued[c] = incipient[run[1]] if current.slip[run[1]] == incipient[run[1]] else 0
        elif current.tension[run[0]] > 0.0:                     # a frictionless tendon: k along the cable
            ratio[run] = actuators.cable_stiffness[c]
    return ratio, continued


def _forces(trunk, state, ratio: np.ndarray) -> np.ndarray:
    """(n_dof, n_cables) the generalised forces of each cable's spans per unit of its command
    when span ``j`` changes by ``ratio[j]`` of it (the sign of the linearisation's actuator forces)."""
    cables = trunk.cables
    n_cables, n_frames = cables.n_cables, trunk.frames.count
    pieces = cables.pieces(state.positions, qmatrix(state.quaternions))
    rows = np.repeat(cables.owner, 2) * n_frames + cables.ends
    forces = np.zeros((n_cables * n_frames, 6))
    np.add.at(forces, rows, (ratio[:, None] * pieces.unit).reshape(-1, 6))
    return -forces.reshape(n_cables, n_frames, 6)[:, 1:].reshape(n_cables, -1).T


def linearise(trunk, state, actuation: np.ndarray, history: FrictionState | None = None,
              incipient: np.ndarray | None = None):
    """The linearisation (:func:`~vertebra.solver.outputs.linearise`) at the equilibrium ``state``
    reached under ``actuation`` from ``history`` (None: from rest — a monotone pull): the tangent
    with every span's own tension, and as each cable's actuator force the forces of its spans per
    unit change of its command in the current sliding direction (:func:`transmission_ratios`) —
    the frictional transmission the inverse's QP sees. Stuck spans take no part in it.

    ``incipient``: (m,) slip statuses (e.g. ``history.slip``, the direction each hole slid in
    last) for holes that the return map finds stuck on the edge of their band — at the state a
    command left, every hole that slid is there: each such hole is taken as sliding on in that
    direction (a tendon's holes: the active set starts from them). That holds while the cable's
    command goes on in the direction returned for it (``continued``, (n_cables,): +1 pulled on,
    −1 paid out on, 0: no hole taken so); a command reversed sticks them (linearise again without
    them). Returns ``(lin, current, continued)``."""
    if history is None:
        history = FrictionState.rest(trunk)
    lengths, angles = geometry(trunk, state)
    current = transmission(trunk, history, actuation, lengths, angles, incipient)
    lin = outputs.linearise(trunk, state, actuation, _Loads(trunk, current))
    continued = np.zeros(trunk.cables.n_cables, np.int8)
    if trunk.cables.n_cables:
        ratio, continued = _ratios(trunk, current, angles, incipient)
        lin.actuator_forces[:, :trunk.cables.n_cables] = _forces(trunk, state, ratio)
        lin.force_scale = None      # the forces are no longer the Jacobian's rows scaled
    return lin, current, continued


def piecewise(trunk, state, history: FrictionState, start: Transmission, actuation: np.ndarray,
              answer: np.ndarray, incipient: np.ndarray | None, forces: np.ndarray, poses=None):
    """The return map at ``state``'s poses around a command ``answer``: at fixed poses each
    cable's span tensions are a piecewise-linear function of its own command alone (a hole slides
    or sticks as its band is reached: the kinks). Returns ``(reached, chord, slope)`` — the
    :class:`Transmission` at ``answer``, and as actuator forces (n_dof, n_cables) per unit of each
    cable's command the *chord* of the return map from ``actuation`` (where it gave ``start``) to
    ``answer`` and its *slope* there (:func:`transmission_ratios` of the statuses at ``answer``:
    the capstan factors up to the first stuck hole; a tendon's ``K g_j`` over the run holding its
    first span). The affine model
    ``F(λ) = chord·(answer − actuation) + slope·(λ − answer)`` is then the return map's exactly on
    that piece. Cables whose command does not change keep their column of ``forces`` (the
    tangent's)."""
    n_cables = trunk.cables.n_cables
    change = answer[:n_cables] - actuation[:n_cables]
    moved = np.flatnonzero(np.abs(change) > 1e-12 * np.maximum(np.abs(actuation[:n_cables]), 1.0))
    chord, slope = forces.copy(), forces.copy()
    lengths, angles = geometry(trunk, state) if poses is None else poses
    command = np.array(actuation, float)
    command[moved] = answer[moved]
    reached = transmission(trunk, history, command, lengths, angles, incipient)
    if moved.size:
        owner = trunk.cables.owner
        on = np.isin(owner, moved)
        per = np.where(on, change[owner], 1.0)
        chord[:, moved] = _forces(trunk, state, np.where(on, (reached.tension - start.tension) / per, 0.0))[:, moved]
        slope[:, moved] = _forces(trunk, state, _ratios(trunk, reached, angles, None)[0])[:, moved]
    return reached, chord, slope


def _span_tensions(trunk, state, load: LoadCase) -> np.ndarray:
    """The tension of every span in the equilibrium of ``load`` at ``state``."""
    m = trunk.cables.owner.size
    if not load.cables:
        return np.zeros(m)
    tension = evaluate(trunk, state, load).parts.piece_tension
    return np.zeros(m) if tension is None else np.array(tension, float)


def solve_sequence(model, actuations, history: FrictionState | None = None, initial=None, **options) -> list:
    """Solve the commands ``actuations`` in order, each from the last one's equilibrium and
    friction state (``history``: where the sequence starts; None: at rest). Returns the results."""
    results = []
    for actuation in actuations:
        result = model.solve(actuation, initial, history=history if history is not None else FrictionState.rest(model.trunk),
                             **options)
        results.append(result)
        history, initial = result.friction, None
    return results


def sensitivities(model, actuations, history: FrictionState | None = None, cables=None, step: float = 1e-4) -> dict:
    """Derivatives with respect to the cables' friction coefficients of the effector positions
    and the span tensions after each command of a sequence (``actuations`` applied in order to
    ``history``; None: from rest). A sequence's result depends on μ through its whole path (the
    holes that stick, the slip fronts), so these are central differences of the whole sequence
    with a step of ``step`` in μ (one-sided at μ = 0); :func:`sequence_sensitivities` gives them
    exactly where no hole's status changes with μ. ``cables``: names
    (default every cable). Returns ``{"names", "effector_positions": (steps, 3·n_effectors, p),
    "span_tensions": (steps, m, p)}``."""
    names = list(model.actuator_names[:model.n_cables])
    cables = names if cables is None else list(cables)
    unknown = [c for c in cables if c not in names]
    if unknown:
        raise OptionError(f"unknown cable(s) {', '.join(unknown)} (cables: {', '.join(names)})", field="cables")
    base = model.parameters
    actuations = [model.actuation(a) for a in actuations]

    def run(friction_values):
        model.set_parameters(friction=friction_values)
        results = model.solve_sequence(actuations, history)
        return (np.stack([model.effector_positions(r.state).reshape(-1) for r in results]),
                np.stack([r.friction.tension for r in results]))

    positions = np.zeros((len(actuations), 3 * len(model.effector_names), len(cables)))
    tensions = np.zeros((len(actuations), model.trunk.cables.owner.size, len(cables)))
    try:
        for j, name in enumerate(cables):
            k = names.index(name)
            mu = base.friction[k]
            low, high = base.friction.copy(), base.friction.copy()
            low[k], high[k] = max(mu - step, 0.0), mu + step
            (p_low, t_low), (p_high, t_high) = run(low), run(high)
            positions[..., j] = (p_high - p_low) / (high[k] - low[k])
            tensions[..., j] = (t_high - t_low) / (high[k] - low[k])
    finally:
        model.set_parameters(base)
    return {"names": [f"friction:{c}" for c in cables], "effector_positions": positions, "span_tensions": tensions}


def _scatter(trunk, rows: np.ndarray) -> np.ndarray:
    """(n_dof, k) from per-piece-end rows (k, 2m, 6) onto the free frames' DoFs."""
    cables = trunk.cables
    k, ends = rows.shape[0], rows.shape[1]
    gather = np.zeros((trunk.frames.count, ends))
    gather[cables.ends, np.arange(ends)] = 1.0          # (every piece end sits at one frame)
    return np.matmul(gather, rows)[:, 1:].reshape(k, -1).T


def _tendon_sensitivities(trunk, current: Transmission, c: int, run: np.ndarray, mu: float, angles: np.ndarray,
                          on_prev: np.ndarray, on_own: np.ndarray, unit_rows: np.ndarray, dT_dq: np.ndarray,
                          dT_dmu: np.ndarray, spring: np.ndarray, past_material: np.ndarray, dT_past: np.ndarray,
                          raw: dict, lengths: np.ndarray) -> None:
    """:func:`equilibrium_sensitivities` of a stroke-driven tendon's spans (into ``dT_dq``, rows on
    the pieces' ends, and ``dT_dmu``), the statuses and the history's materials held: a run of
    spans joined by sliding holes keeps its material ``M``, so ``T_j = g_j τ`` with
    ``τ = (Σ L_i − M)/W``, ``W = Σ c_i g_i`` and ``ln g_j`` the sum of ``−s_i μ Δθ_i`` over the run's
    holes up to ``j``. The linearisation's tangent already holds the run as one spring on
    ``Σ g_i L_i`` (stiffness ``1/W``): its rank-one part ``(1/W) Σ g L' ⊗ Σ g L'`` goes into
    ``spring`` (the tangent minus it, plus ``Σ_j L_j' ⊗ ∂T_j/∂q``, is the exact one).
    A slack run (``τ ≤ 0``) carries nothing and has no stiffness. Through the history (the
    derivatives ``past_material`` (m, p) of its materials) ``∂τ = −Σ ∂M/W`` (into ``dT_past``).
    ``raw[j]``: the rows, the direct derivatives (p,) of the unclipped ``g_j τ`` and ``c_j`` (the
    span's new material follows them, slack or not)."""
    tendons = current.tendons
    k = trunk.actuators.cable_stiffness[c]
    compliance = _shares(trunk, c, run) / k
    if tendons is None:                   # today's tendons: one unit per cable, g = 1
        units, g = np.zeros(run.size, int), np.ones(run.size)
    else:
        units, g = tendons.units[run], tendons.weights[run]
    slip = current.slip
    unit_ends = unit_rows[np.arange(unit_rows.shape[0]), 2 * np.arange(unit_rows.shape[0])], \
        unit_rows[np.arange(unit_rows.shape[0]), 2 * np.arange(unit_rows.shape[0]) + 1]
    # a span alone in its run (stuck at both ends): g = 1, T = τ = (L − M)/c, ∂T/∂q = L'/c — all
    # the tangent's spring already (nothing to update), nothing by μ directly
    counts = np.bincount(units - units.min())
    alone = counts[units - units.min()] == 1
    if alone.any():
        spans, cs = run[alone], compliance[alone]
        rows = np.stack([unit_ends[0][spans], unit_ends[1][spans]], 1) / cs[:, None, None]     # (k, 2, 6)
        past = -past_material[spans] / cs[:, None]
        for i, p in enumerate(spans.tolist()):
            ends = np.array([2 * p, 2 * p + 1])
            raw[p] = (ends, rows[i], 0.0, past[i], cs[i])
            if current.tension[p] > 0.0:
                dT_dq[p, ends] = spring[p, ends] = rows[i]
                dT_dmu[p], dT_past[p] = 0.0, past[i]
    for unit in np.unique(units[~alone]).tolist():
        where = np.flatnonzero(units == unit)
        spans = run[where]
        n = spans.size
        gs, cs = g[where], compliance[where]
        weighted = cs * gs
        W = float(np.sum(weighted))
        taut = current.tension[spans[0]] > 0.0
        # τ from the tension (taut) or from the new material ℓ = L − c g τ of the run's first span (slack)
        tau = (current.tension[spans[0]] / gs[0] if taut
               else (lengths[spans[0]] - current.material[spans[0]]) / weighted[0])
        # rows on the run's own piece ends (local: 2 per span), scattered into the pieces' at the end
        ends = np.stack([2 * spans, 2 * spans + 1], 1).reshape(-1)
        own_rows = np.zeros((n, 2 * n, 6))                                 # ∂L_i/∂q, local
        own_rows[np.arange(n), 2 * np.arange(n)] = unit_ends[0][spans]
        own_rows[np.arange(n), 2 * np.arange(n) + 1] = unit_ends[1][spans]
        step = np.zeros((n, 2 * n, 6))                                    # ∂ ln g_i − ∂ ln g_{i−1}
        a = np.zeros(n)
        for i in range(1, n):
            p, prev = spans[i], spans[i - 1]
            s = int(slip[p])
            step[i, 2 * i - 2:2 * i] = -s * mu * on_prev[prev].reshape(2, 6)
            step[i, 2 * i:2 * i + 2] -= s * mu * on_own[p].reshape(2, 6)
            a[i] = a[i - 1] - s * angles[p]
        dlng = np.cumsum(step, axis=0)                                     # ∂ ln g_i/∂q
        dtau_dmu = -tau / W * float(weighted @ a)
        dtau_past = -past_material[spans].sum(axis=0) / W                 # (p,)
        capstan = np.tensordot(gs, own_rows, axes=1)                      # Σ g_i L_i'
        dtau_dq = (own_rows.sum(axis=0) - tau * np.tensordot(weighted, dlng, axes=1)) / W
        T = gs * tau
        rows = T[:, None, None] * dlng + gs[:, None, None] * dtau_dq       # (n, 2n, 6)
        own, past = T * a + gs * dtau_dmu, gs[:, None] * dtau_past
        for i, p in enumerate(spans.tolist()):
            raw[p] = (ends, rows[i], own[i], past[i], cs[i])
            if taut:
                dT_dq[p, ends] = rows[i]
                dT_dmu[p], dT_past[p] = own[i], past[i]
                spring[p, ends] = gs[i] / W * capstan


def equilibrium_sensitivities(model, result, history: FrictionState, cables=None, history_derivatives=None) -> dict:
    """Exact derivatives with respect to the cables' friction coefficients of one frictional
    equilibrium ``result`` (a :meth:`~vertebra.solver.model.TrunkModel.solve` whose command was
    applied to ``history``), by the implicit function theorem, the history and the holes'
    statuses held (a hole on the edge of its band moves with it; one that is stuck keeps its
    tension). The equilibrium ``∇E(q) + Σ_j T_j(q, μ) ∂L_j/∂q = 0`` with the span tensions of
    the return map — along a tension-driven cable ``T_j = T_{j−1} e^(−s_j μ Δθ_j(q))`` at a hole
    sliding in direction ``s_j``, a stuck span's committed tension; along a stroke-driven tendon
    ``T_j = g_j τ`` over each run of spans joined by sliding holes, the run keeping its material
    (:func:`_tendon_sensitivities`) — gives
    ``dq/dμ = −(K + Σ_j ∂L_j/∂q ⊗ ∂T_j/∂q)⁻¹ Σ_j ∂T_j/∂μ ∂L_j/∂q``, with ``K`` the tangent at fixed
    span tensions (its factor; a tendon run's spring, which the linearisation's tangent holds,
    taken out of the update) and the rank-m update of the capstan factors' change with the
    shape solved by Sherman–Morrison–Woodbury. A tendon's holes keep the equilibrium's statuses
    (those the solve held at incipient slip too); a hole turned by less
    than 1e-9 rad has no angle derivative (a straight route: |Δθ| has a kink there). Returns
    ``{"names", "state": (n_dof, p), "effector_positions": (3·n_effectors, p), "span_tensions":
    (m, p), "material": (m, p)}`` (``material``: the tendons' span materials, 0 elsewhere).

    ``history_derivatives``: the derivatives of the history itself (``{"span_tensions",
    "material"}`` of the equilibrium it was left by, :func:`sequence_sensitivities`): a stuck
    span's committed tension and a run's material then move with μ too (forward mode along a
    sequence); None: the history held fixed."""
    trunk = model.trunk
    actuators, routing = trunk.actuators, trunk.cables
    names = list(model.actuator_names[:model.n_cables])
    chosen = names if cables is None else list(cables)
    unknown = [c for c in chosen if c not in names]
    if unknown:
        raise OptionError(f"unknown cable(s) {', '.join(unknown)} (cables: {', '.join(names)})", field="cables")
    state, actuation = result.state, result.friction.actuation
    lengths, angles = geometry(trunk, state)
    # (the tendons' holes held at the equilibrium's statuses: a hole the solve held at incipient slip stays so)
    current = transmission(trunk, history, actuation, lengths, angles, result.friction.slip,
                           actuators.stroke_driven[routing.owner])
    lin = outputs.linearise(trunk, state, actuation, _Loads(trunk, current))
    rotations = qmatrix(state.quaternions)
    offsets, d, length = routing.spans(state.positions, rotations)
    pieces = CablePieces.of_spans(offsets, d, length)
    m, n_dof = length.size, trunk.n_dof
    u = pieces.u
    ends = offsets.reshape(m, 2, 3)

    def c_times(w):           # C w = [−w; −s_a × w; w; s_b × w] per piece (m, 12)
        out = np.empty((m, 4, 3))
        out[:, 0], out[:, 2] = -w, w
        out[:, 1], out[:, 3] = -np.cross(ends[:, 0], w), np.cross(ends[:, 1], w)
        return out.reshape(m, 12)

    # ∂Δθ_j/∂q on the frames of piece j − 1 (via u_{j−1}) and of piece j (via u_j)
    route = routes(routing)
    mu = actuators.friction
    slip = current.slip
    inner = route.interior
    a, b = route.previous[inner], inner
    sin = np.sin(angles[b])
    ok = sin > 1e-9
    ua, ub = u[a], u[b]
    proj_a = (ub - ua * np.sum(ua * ub, 1)[:, None]) / length[a][:, None]       # Π_a u_b
    proj_b = (ua - ub * np.sum(ua * ub, 1)[:, None]) / length[b][:, None]       # Π_b u_a
    scale = np.where(ok, -1.0 / np.where(ok, sin, 1.0), 0.0)[:, None]
    full_a, full_b = np.zeros((m, 3)), np.zeros((m, 3))
    full_a[a], full_b[b] = scale * proj_a, scale * proj_b
    # row k of on_prev: the turn at the hole after piece k on piece k's frames; row j of on_own:
    # the turn at the hole before piece j on piece j's frames
    on_prev, on_own = c_times(full_a), c_times(full_b)
    # per span: ∂T_j/∂q as rows on piece ends (m spans × (2m piece ends, 6)), ∂T_j/∂μ of its cable
    dT_dq = np.zeros((m, 2 * m, 6))
    dT_dmu = np.zeros(m)
    p_count = len(chosen)
    past = history_derivatives or {}
    past_tension = np.asarray(past.get("span_tensions", np.zeros((m, p_count))), float)
    past_material = np.nan_to_num(np.asarray(past.get("material", np.zeros((m, p_count))), float))
    dT_past = np.zeros((m, p_count))        # ∂T_j/∂μ at fixed q through the history
    raw = {}                                # tendons' spans: the unclipped g τ's rows (their material follows it)
    spring = np.zeros((m, 2 * m, 6))    # the part of ∂T_j/∂q the tangent holds already (tendons' runs)
    unit_rows = np.zeros((m, 2 * m, 6))                                   # ∂L_j/∂q on piece ends
    unit_rows[np.arange(m), 2 * np.arange(m)] = pieces.unit.reshape(2 * m, 6)[0::2]
    unit_rows[np.arange(m), 2 * np.arange(m) + 1] = pieces.unit.reshape(2 * m, 6)[1::2]
    for c, run in enumerate(route.pieces):
        if actuators.stroke_driven[c]:
            _tendon_sensitivities(trunk, current, c, run, mu[c], angles, on_prev, on_own, unit_rows, dT_dq, dT_dmu,
                                  spring, past_material, dT_past, raw, length)
            continue
        for j in range(1, run.size):
            p, prev = run[j], run[j - 1]
            s = int(slip[p])
            if s == 0:
                dT_past[p] = past_tension[p]                  # stuck: its committed tension
                continue
            factor = math.exp(-s * mu[c] * angles[p])
            dT_past[p] = factor * dT_past[prev]
            T = current.tension[p]
            dT_dq[p] = factor * dT_dq[prev]
            dT_dq[p, 2 * prev:2 * prev + 2] -= T * s * mu[c] * on_prev[prev].reshape(2, 6)
            dT_dq[p, 2 * p:2 * p + 2] -= T * s * mu[c] * on_own[p].reshape(2, 6)
            dT_dmu[p] = factor * dT_dmu[prev] - T * s * angles[p]
    A = _scatter(trunk, unit_rows)                                         # (n_dof, m) ∂L_j/∂q
    B = _scatter(trunk, dT_dq)                                             # (n_dof, m) ∂T_j/∂q
    update = B - _scatter(trunk, spring) if actuators.tendons.size else B  # what the tangent lacks of it
    K_inv_A = lin.solve(np.asfortranarray(A))
    capacitance = np.eye(m) + update.T @ K_inv_A

    def solve(rhs):           # (K + A Bᵀ)⁻¹ rhs (Sherman–Morrison–Woodbury)
        x = lin.solve(np.asfortranarray(rhs))
        return x - K_inv_A @ np.linalg.solve(capacitance, update.T @ x)

    owner = routing.owner
    columns = []
    for name in chosen:
        k = names.index(name)
        columns.append(np.where(owner == k, dT_dmu, 0.0))
    dT_mu = np.array(columns).T.reshape(m, p_count) + dT_past            # (m, p) at fixed q
    dq = -solve(A @ dT_mu)                                                 # (n_dof, p)
    tensions = dT_mu + B.T @ dq
    # a tendon span's new material ℓ_j = L_j − c_j g_j τ: dℓ_j = L_j'·dq − c_j d(g_j τ)
    material = np.zeros((m, p_count))
    if raw:
        spans = np.array(sorted(raw))
        own = np.array([raw[j][2] for j in spans])
        direct = np.stack([raw[j][3] for j in spans]) + np.array(
            [[own[i] if owner[j] == names.index(name) else 0.0 for name in chosen] for i, j in enumerate(spans)])
        compliance = np.array([raw[j][4] for j in spans])
        moved = B[:, spans].T @ dq                                         # (k, p) the taut spans' rows
        slack = [i for i, j in enumerate(spans) if not current.tension[j] > 0.0]
        if slack:               # (a slack run's rows are not in B: its tension is cut off)
            rows = np.zeros((len(slack), 2 * m, 6))
            for r, i in enumerate(slack):
                rows[r, raw[spans[i]][0]] = raw[spans[i]][1]
            moved[slack] = _scatter(trunk, rows).T @ dq
        material[spans] = (A[:, spans].T @ dq) - compliance[:, None] * (direct + moved)
    return {"names": [f"friction:{c}" for c in chosen], "state": dq,
            "effector_positions": lin.effector_jacobian @ dq, "span_tensions": tensions, "material": material}


def sequence_sensitivities(model, results, history: FrictionState | None = None, cables=None) -> dict:
    """Exact derivatives with respect to the cables' friction coefficients of the equilibria of a
    sequence (``results``: each a :meth:`~vertebra.solver.model.TrunkModel.solve` of its command
    applied to the friction state the one before left, the first to ``history``; None: rest), in
    forward mode along it: each equilibrium's derivative (:func:`equilibrium_sensitivities`)
    with the derivatives of the history it was applied to — the committed span tensions and the
    tendons' materials the one before left — the holes' statuses held throughout. Returns
    ``{"names", "state": [(n_dof, p)] per step, "effector_positions": (steps, 3·n_effectors, p),
    "span_tensions": (steps, m, p)}`` — the exact counterpart of :func:`sensitivities` where no
    status changes under a small change of μ."""
    history = FrictionState.rest(model.trunk) if history is None else history
    past, out = None, []
    for result in results:
        step = equilibrium_sensitivities(model, result, history, cables, past)
        out.append(step)
        history, past = result.friction, step
    return {"names": out[0]["names"] if out else [], "state": [step["state"] for step in out],
            "effector_positions": np.stack([step["effector_positions"] for step in out]),
            "span_tensions": np.stack([step["span_tensions"] for step in out])}
