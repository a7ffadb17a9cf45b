"""The globalisation steps of the forward solve beyond the shifted Newton step: a direction of
negative curvature of an indefinite tangent (to leave saddles and maxima) and the backtracking
line search on the energy (or, with loads that have no potential, an energy-like merit; with
contacts, the Lagrangian at the step's contact forces). The stage they act on is
:mod:`vertebra.solver.newton`'s.
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.core.lie import qconj, qlog, qmul
from vertebra.solver import contact
from vertebra.solver.potential import Evaluation, evaluate, nonpotential_forces, potential
from vertebra.solver.state import retract, strain_change

NEUTRAL = 1e-9        # curvature above −NEUTRAL·D is neutral (a symmetry of the loads), not unstable
ARMIJO = 1e-4
ROUNDING = 1e-12       # energy changes below this fraction of the energy are rounding
SEARCH_FLOOR = 1e-3    # smallest step fraction of the line search
DISC_DEPTH = 0.5       # a trial may take discs this far into each other, of the depth that cannot be followed


def negative_curvature(factor, shift: float, scale: np.ndarray, n: int):
    """A direction ``v`` of most negative curvature of the tangent ``H`` in the D-metric
    (``vᵀDv = 1``) and its curvature ``vᵀHv``, by inverse iteration with the factor of the
    positive definite ``H + μD``; None when the curvature is not negative."""
    v = np.random.default_rng(n).standard_normal(n)      # a deterministic start
    curvature = 0.0
    for _ in range(8):
        w = factor.solve(scale * v)
        norm = math.sqrt(float(w @ (scale * w)))
        if not (norm > 0.0 and math.isfinite(norm)):
            return None
        curvature = float(w @ (scale * v)) / (norm * norm) - shift     # wᵀHw / wᵀDw
        v = w / norm
    return (v, curvature) if curvature < -NEUTRAL else None


def projected_curvature(factor, shift: float, scale: np.ndarray, matrix, held: np.ndarray):
    """A direction ``v`` of negative curvature of the tangent ``matrix`` (``H``: the Lagrangian's)
    on the directions the pressed contacts leave free — the null space of their gaps' rows
    ``held`` (k, n): ``held v = 0`` — in the D-metric (``vᵀDv = 1``), and its curvature ``vᵀHv``;
    None when it is not negative. ``factor`` is that of the tangent the step used (``H`` plus
    springs along the pressed contacts, plus ``shift``·D, positive definite): the springs make
    its most negative direction (:func:`negative_curvature`) nearly free of the contacts, and its
    D-orthogonal projection onto the null space of ``held`` makes it exactly so."""
    found = negative_curvature(factor, shift, scale, scale.size)
    if found is None:
        return None
    v = found[0]
    if held.shape[0]:
        scaled = held / scale
        v = v - scaled.T @ np.linalg.lstsq(scaled @ held.T, held @ v, rcond=1e-13)[0]
    norm = math.sqrt(float(v @ (scale * v)))
    if not (norm > 0.0 and math.isfinite(norm)):
        return None
    v = v / norm
    curvature = matrix.quadratic(v)
    return (v, curvature) if curvature < -NEUTRAL else None


def gap_limit(v: np.ndarray, gaps: np.ndarray, rows: np.ndarray) -> float:
    """The largest multiple ``α`` of the step ``v`` that closes no open candidate contact on its
    linearisation: ``g_i + α G_i v ≥ 0`` for every contact (gaps ``gaps``, rows ``G`` = ``rows``)
    that ``v`` closes (``G_i v < 0``); a contact already closed (``g_i ≤ 0``) that ``v`` closes
    further allows none. ``inf`` when ``v`` closes none."""
    closing = rows @ v
    mask = closing < 0.0
    if not mask.any():
        return math.inf
    return float(np.min(np.maximum(gaps[mask], 0.0) / -closing[mask]))


def bend(stage, ev, r: np.ndarray, factor, shift: float, scale: np.ndarray, matrix=None, state=None):
    """The step along the tangent's direction of most negative curvature (:func:`negative_curvature`),
    turned downhill and stretched to the strain-space caps: (dq, strain change, r·dq, dqᵀH dq,
    predicted decrease), or None when the curvature is not negative. With contacts
    (``stage.constraints``) the direction is that of the Lagrangian's tangent ``matrix`` on the
    directions the contacts that hold the trunk leave free (``Constraints.held``: the pressed
    ones, with friction the stuck ones' slip rows too; :func:`projected_curvature`), and its length is
    also capped where it would close another candidate contact (:func:`gap_limit`: it cannot step
    through a disc or into an obstacle); of its two senses the one that predicts the larger
    decrease of the Lagrangian is taken (``r·v`` is the Lagrangian's: ``v`` moves no pressed
    contact; ``state``: the iterate)."""
    constraints = stage.constraints
    if constraints is None:
        found = negative_curvature(factor, shift, scale, r.size)
        if found is None:
            return None
        v, curvature = found
        if float(r @ v) < 0.0:
            v = -v
        change = strain_change(v, ev.links)
        limit = stage.step_limit(v, change, ev)
    else:
        holding, candidates = constraints.held(state), constraints.at(state)
        rows = (holding.jacobian(constraints.n_frames) if holding is not None
                else np.zeros((0, r.size)))
        found = projected_curvature(factor, shift, scale, matrix, rows)
        if found is None:
            return None
        v, curvature = found
        held = set(map(tuple, constraints.keys.tolist()))
        free = np.array([tuple(k) not in held for k in candidates.key.tolist()], bool)
        rows = candidates.jacobian(constraints.n_frames)[free]
        best = None
        for sense in (1.0, -1.0):
            w = sense * v
            change = strain_change(w, ev.links)
            limit = min(stage.step_limit(w, change, ev), gap_limit(w, candidates.gap[free], rows))
            gain = limit * float(r @ w) - 0.5 * limit * limit * curvature
            if best is None or gain > best[0]:
                best = gain, w, change, limit
        _, v, change, limit = best
        if not limit > 0.0:
            return None
    dq, change, curvature = limit * v, limit * change, curvature * limit * limit
    rp = float(r @ dq)
    return dq, change, rp, curvature, rp - 0.5 * curvature


def turned(state, trial) -> np.ndarray:
    """The rotation vectors (world axes) that take the free frames of ``state`` to those of
    ``trial``, flattened: the work of dead moments ``M`` from one to the other along the
    geodesics is ``M · turned`` exactly. The merit needs this, not ``α M·Δφ``: the retraction
    (in strain space) turns the frames differently from ``exp(αΔφ)`` at second order, and near
    an equilibrium, where the potential's gradient balances ``M``, that second-order term would
    put the merit's curvature off ``pᵀHp`` and the step-quality ratio off 1 for good."""
    return qlog(qmul(trial.quaternions[1:], qconj(state.quaternions[1:]))).reshape(-1)


def moved(state, trial) -> np.ndarray:
    """The displacements and rotation vectors (world axes, :func:`turned`) that take the free
    frames of ``state`` to those of ``trial``, ``[Δx; Δφ]`` per frame, flattened: the work of loads
    without a potential from one to the other is ``f · moved`` for constant ``f`` (dead moments:
    exact along the geodesics) and ``½ (f₀ + f₁) · moved`` to second order for loads that turn
    with their frames (follower loads)."""
    return np.concatenate([trial.positions[1:] - state.positions[1:],
                           turned(state, trial).reshape(-1, 3)], 1).reshape(-1)


def _completed(trunk, trial, load, judged) -> Evaluation:
    """The evaluation of a trial whose potential :func:`potential` gave (``judged``: what it
    computed reused; a state given by its poses was evaluated in full already)."""
    return judged if isinstance(judged, Evaluation) else evaluate(trunk, trial, load, judged)


def line_search(stage, state, ev, residual: float, dq, change, alpha: float, rp: float,
                 curvature: float, nonpotential):
    """Backtracking from ``alpha`` along ``dq``: the first fraction that lowers the energy (the
    merit: the energy less the work along the step, :func:`moved`, of the ``nonpotential`` forces
    at the iterate — dead moments, follower loads) by an Armijo share of the quadratic model's
    prediction ``α r·p − ½α² pᵀHp`` — or, where the prediction is below the energy's rounding,
    that does not raise the residual. Returns (state, evaluation, α, decrease, prediction, quality) with quality the
    ratio of actual to predicted decrease of the first (full) trial (1 below rounding, 0 when
    it was cut back), or None."""
    trunk, load = stage.trunk, stage.load
    noise = ROUNDING * abs(ev.energy)
    quality = None
    deepest = None
    if stage.constraints is not None and trunk.contact.pair.size:
        # discs may be pushed into each other by at most half the depth that cannot be followed,
        # or no deeper than they are (the linearised disc gaps hold only for short steps)
        deepest = max(DISC_DEPTH, contact.interpenetration(trunk.contact, stage.constraints.at(state))[0])
    outrun = None
    if stage.constraints is not None:
        outrun = _outrun_check(stage, state)
    while alpha >= SEARCH_FLOOR:
        step, strains = (dq, change) if alpha == 1.0 else (alpha * dq, alpha * change)
        trial = retract(state, step, ev.links, strains)
        if deepest is not None and contact.interpenetration(trunk.contact, stage.constraints.at(trial))[0] > deepest:
            if quality is None:
                quality = 0.0
            alpha *= 0.5
            continue
        judged = potential(trunk, trial, load)       # the energy first: a refused trial needs no gradient
        predicted = alpha * rp - 0.5 * alpha * alpha * curvature
        decrease = ev.energy - judged.energy
        if nonpotential is not None:       # the work of the loads without a potential along the step
            at_trial = nonpotential_forces(trunk, trial, load) if trunk.loads.has_follower else nonpotential
            decrease += 0.5 * float((nonpotential + at_trial) @ moved(state, trial))
        if stage.constraints is not None:        # the Lagrangian E − λᵀg at the step's contact forces
            decrease += stage.constraints.work(trial)
        ev_trial = None
        if predicted <= noise:       # the energy cannot judge this step: the residual does
            ev_trial = _completed(trunk, trial, load, judged)
            good = stage.norm(ev_trial, trial) <= residual
            if not good and stage.constraints is not None:
                good = _settled(stage, ev_trial, trial, residual)
            ratio = 1.0
        else:
            good = decrease >= ARMIJO * predicted - noise
            ratio = decrease / predicted
        if good and outrun is not None and predicted > noise and outrun(trial):
            good = False        # (judged after the merit: the trials it refuses need no contacts evaluated)
        if quality is None:
            quality = ratio if good else 0.0
        if good:
            if ev_trial is None:
                ev_trial = _completed(trunk, trial, load, judged)     # the gradient of the accepted trial
            return trial, ev_trial, alpha, decrease, predicted, quality
        alpha *= 0.5
    return None


def _outrun_check(stage, state):
    """A test of trials: does one take an obstacle contact that the step's problem left open (no
    force) into its obstacle, deeper than it is and than the converged states' tolerance? Its
    linearised gap kept it open: the step has outrun the linearisation (a rim's nearest point
    turning over a large rotation), and the next step would push it out again (a disc in a wedge
    between two obstacles pressed on each in turn)."""
    constraints = stage.constraints
    model = stage.trunk.contact
    now = constraints.at(state)
    obstacle = np.isin(now.key[:, 0], (contact.RIM, contact.BALL, contact.CHORD))
    if not obstacle.any():
        return None
    pressed = {tuple(k) for k in constraints.keys.tolist()}
    tolerance = contact.GAP_TOLERANCE * model.length
    floor = {tuple(k): min(g, 0.0) - tolerance for k, g, o in zip(now.key.tolist(), now.gap.tolist(), obstacle) if o
             and tuple(k) not in pressed}

    def outrun(trial) -> bool:
        found = constraints.at(trial)
        for k, g in zip(found.key.tolist(), found.gap.tolist()):
            if g < -tolerance and tuple(k) in floor and g < floor[tuple(k)]:
                return True
        return False

    return outrun


def _settled(stage, ev_trial, trial, residual: float) -> bool:
    """With contacts, a trial below the energy's rounding judged on its residual at the pressed
    contacts' forces that balance it best (``Constraints.reestimate``, kept when it passes; the
    step's forces are restored when not): where contacts are redundant — discs lying face to
    face, pressed at the pucks' gap and at face points — the step's forces are one of many that
    close the gaps, and the pucks' gap turns with the faces' tilt, so at the trial they can be
    off balance by far more than the step's size explains while others balance it to rounding."""
    constraints = stage.constraints
    if not constraints.multipliers.size:
        return False
    kept = constraints.keys, constraints.multipliers, constraints.reference
    constraints.reestimate(ev_trial.gradient, trial, stage.weights)
    if stage.norm(ev_trial, trial) <= residual:
        return True
    constraints.keys, constraints.multipliers, constraints.reference = kept
    return False


def residual_step(stage, state, ev, residual: float, factor, r: np.ndarray):
    """Loads without a potential: the full, undamped Newton step (LU of the unshifted, consistent
    tangent) when it is within the step caps and at least halves the scaled residual — Newton
    inside its region of convergence, where the energy-like merit can no longer judge it: beyond
    the load at which the tangent's symmetric part turns indefinite the equilibrium sought is no
    minimum of that merit, and dead moments do work round a closed loop of rotations, so the
    merit can keep falling while the frames circle. Returns (state, evaluation, α, decrease,
    prediction, quality) as :func:`line_search` does (in residual units), or None. ``factor``: the
    unshifted tangent's LU factor (None: singular)."""
    if factor is None:
        return None
    dq = factor.solve(r)
    if not np.all(np.isfinite(dq)):
        return None
    change = strain_change(dq, ev.links)
    if stage.step_limit(dq, change, ev) < 1.0:
        return None
    trial = retract(state, dq, ev.links, change)
    ev_trial = evaluate(stage.trunk, trial, stage.load)
    after = stage.norm(ev_trial, trial)
    if not after <= 0.5 * residual:
        return None
    return trial, ev_trial, 1.0, residual - after, residual, 1.0


def smallest_singular_value(matrix, scale: np.ndarray, iterations: int = 30) -> tuple | None:
    """The smallest singular value ``σ`` of the tangent ``H`` (``matrix``) in the metric of
    ``scale`` (``S H S``, ``S = diag(scale)^{-1/2}``: every DoF in its own units) and its left
    singular vector ``u`` (``uᵀ S H S ≈ σ vᵀ``, ``|u| = 1``: the direction in which ``S H S``
    is nearly singular from the left), by inverse iteration on ``(S H S)⁻ᵀ (S H S)⁻¹`` with the
    unshifted banded LU factor: (σ, u); σ = 0 (u None) when the tangent is singular; None when its
    factor has no transposed solve (a dense term beside the band). σ falls to 0 where an
    equilibrium path reaches a limit point or a bifurcation: what continuation reports when it
    cannot go on."""
    factor, _ = matrix.factor(0.0, symmetric=False)
    if factor is None:
        return 0.0, None
    if not hasattr(factor, "pivots"):
        return None
    root = np.sqrt(scale)
    u = np.random.default_rng(scale.size).standard_normal(scale.size)     # a deterministic start
    u /= np.linalg.norm(u)
    growth = 0.0
    for _ in range(iterations):
        y = root * factor.solve(root * u)                     # (S H S)⁻¹ u
        z = root * factor.solve(root * y, transposed=True)    # (S H S)⁻ᵀ (S H S)⁻¹ u
        growth = float(np.linalg.norm(z))
        if not (growth > 0.0 and math.isfinite(growth)):
            return 0.0, None
        u = z / growth
    return 1.0 / math.sqrt(growth), u
