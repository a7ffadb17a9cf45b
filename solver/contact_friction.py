"""Coulomb friction at obstacle contacts (docs/contact.md, "Friction").

An obstacle with ``friction = μ > 0`` resists the sliding of what touches it. Quasi-static
Coulomb friction is path dependent, so a solve is an *increment* from a committed state (the
history): every contact with such an obstacle holds the material point of its body that touched
the obstacle at the increment's start (its *anchor*: the point on the obstacle beneath it, and
two tangent directions ``t₁, t₂`` there). Within the increment the point's *slip* is
``s(q) = Tᵀ(P(q) − A)`` — ``P`` the material point moved with its frame (a chord's point at its
parameter), ``A`` the anchor — and the contact

* **sticks**: ``s = 0`` and the tangential force ``f_t`` (two components along ``t₁, t₂``) lies in
  the cone ``|f_t| ≤ μ f_n``; or
* **slips**: ``f_t = −μ f_n d`` with ``s = γ d``, ``γ ≥ 0``, ``|d| = 1`` — the force on the cone's
  edge, opposite the slip (maximum dissipation);

and the normal force stays complementary to the gap as without friction. In the Newton solve
(:mod:`~vertebra.solver.newton`) the two slip rows join the contact's gap row in constraint space:
the sequential-QP step's complementarity problem (:mod:`~vertebra.solver.contact`) becomes, on
the candidate contacts' rows ``G = ∂[g; s]/∂q`` and the Delassus operator ``W = G K⁻¹ Gᵀ``,

    ``w = [g; s] + G K⁻¹ r + W λ``,   normal rows complementary, tangential rows stick or slip

(:func:`coulomb`: semismooth Newton on the Alart–Curnier equations on a working set of the
contacts that can press, an active set over open / stick / slip with the slip directions solved
for ``w_t ∥ d`` where it does not converge), and the step is ``p = K⁻¹(r + Gᵀλ)``. At the converged state ``w = [g; s]``: the
increment's equilibrium, with the friction law above holding exactly.

History. :class:`ContactFriction` is the committed state with each pressed frictional contact's
status, tangential force and slip direction (``result.friction``); the next increment anchors
every contact at the contact point of that state (so a contact rolls from increment to increment,
and within one only pivots about its anchored point). A solve from rest without a history steps
its load in the solve's load stages and commits after each (the contacts made along the load
path, each anchored where it was at the start of the stage in which it closed); ``model.solve(
command, history=...)`` applies one increment to a committed state, ``model.solve_sequence``
chains them. With ``μ = 0`` on every obstacle none of this runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.lie import qmatrix
from vertebra.solver import contact, newton
from vertebra.solver.contact import BALL, CHORD, RIM, TANGENTIAL, ContactSet, Step

OBSTACLE_KINDS = (RIM, BALL, CHORD)   # the contacts that friction acts at (a body against an obstacle)
STATUS_CHANGES = 60                   # active-set changes per frictional contact before the step is refused
SWEEPS = 25                           # projected Gauss–Seidel sweeps at most
SWEEP_TOLERANCE = 1e-10               # their forces' change per sweep, of the largest, that ends them
DIRECTION_ITERATIONS = 30             # Newton iterations on the slip directions of one active set
DIRECTION_TOLERANCE = 1e-14           # |w_t × d| relative to the rows' scale: the slip along its direction
NEWTON_ITERATIONS = 40                # semismooth Newton iterations on the Alart–Curnier equations at most
HALVINGS = 12                         # … and halvings of one's step (then it has stalled: a local minimum of ½|F|²)
NEWTON_TOLERANCE = 1e-14              # their residual, of the forces' scale, that ends them


def frictional(trunk) -> bool:
    """Does the trunk touch an obstacle with friction (then its solves run this module)?"""
    model = trunk.contact
    return model is not None and any(getattr(o, "friction", 0.0) > 0.0 for o in model.obstacles)


def coefficients(model, key: np.ndarray) -> np.ndarray:
    """μ of each contact ``key`` (m, 3): its obstacle's, 0 for contacts between discs."""
    mu = np.array([float(getattr(o, "friction", 0.0)) for o in model.obstacles] + [0.0])
    on_obstacle = np.isin(key[:, 0], OBSTACLE_KINDS)
    return np.where(on_obstacle, mu[np.where(on_obstacle, key[:, 2], -1)], 0.0)


def tangential_keys(key: np.ndarray) -> np.ndarray:
    """The two tangential rows' keys (2k, 3) of obstacle contacts ``key`` (k, 3), in pairs."""
    out = np.repeat(key, 2, 0)
    out[:, 0] = TANGENTIAL + 2 * out[:, 0] + np.tile([0, 1], key.shape[0])
    return out


def normal_keys(key: np.ndarray) -> np.ndarray:
    """The contacts (k, 3) that tangential rows ``key`` (2k, 3, in pairs) belong to."""
    out = key[::2].copy()
    out[:, 0] = (out[:, 0] - TANGENTIAL) // 2
    return out


def _basis(normal: np.ndarray) -> np.ndarray:
    """Two unit tangents (k, 2, 3) orthogonal to each unit ``normal`` (k, 3) and to each other."""
    axis = np.eye(3)[np.argmin(np.abs(normal), 1)]
    t1 = axis - np.add.reduce(axis * normal, 1)[:, None] * normal
    t1 /= np.sqrt(np.add.reduce(t1 * t1, 1))[:, None]
    t2 = contact._cross(normal, t1)
    return np.stack([t1, t2], 1)


@dataclass(frozen=True, eq=False)
class Anchors:
    """Where the contacts ``key`` hold on: per contact the frames of its body, its material
    point (``local``: in frame a's axes for a disc rim or a frame's ball; for a chord ``(t, 0, 0)``
    with ``offset`` the world vector from its axis point to the surface), the anchor ``point`` on
    the obstacle and the tangents ``basis`` (k, 2, 3) there."""

    key: np.ndarray
    frames: np.ndarray
    local: np.ndarray
    offset: np.ndarray
    point: np.ndarray
    basis: np.ndarray

    @classmethod
    def at(cls, model, state, key: np.ndarray) -> "Anchors":
        """The anchors of contacts ``key`` made at ``state``: each body's contact point there and
        the obstacle's point nearest it."""
        found = contact.evaluate(model, state, key)
        x, R = state.positions, qmatrix(state.quaternions)
        frames = found.frames.copy()
        local = np.zeros((key.shape[0], 3))
        offset = np.zeros((key.shape[0], 3))
        point = np.zeros((key.shape[0], 3))
        basis = np.zeros((key.shape[0], 2, 3))
        chord = key[:, 0] == CHORD
        rigid = ~chord
        a = frames[:, 0]
        local[rigid] = np.einsum("kji,kj->ki", R[a[rigid]], found.point[rigid] - x[a[rigid]])
        if chord.any():
            t = np.add.reduce(found.rows[chord, 1, :3] * found.normal[chord], -1)
            local[chord, 0] = t
            axis = (1.0 - t)[:, None] * x[a[chord]] + t[:, None] * x[frames[chord, 1]]
            offset[chord] = found.point[chord] - axis
        for j in np.unique(key[:, 2]):
            chosen = key[:, 2] == j
            _, normal, surface = model.obstacles[j].closest(found.point[chosen])
            point[chosen] = surface
            basis[chosen] = _basis(np.asarray(normal, float).reshape(-1, 3))
        return cls(key, frames, local, offset, point, basis)

    def take(self, index: np.ndarray) -> "Anchors":
        return Anchors(self.key[index], self.frames[index], self.local[index], self.offset[index], self.point[index],
                       self.basis[index])

    def rows(self, state) -> ContactSet:
        """The slip rows at ``state``: for each contact two rows (``t₁``, ``t₂``) with the slip
        ``s = tᵀ(P − A)`` as their gap, the material point ``P``, ``t`` as their direction and
        ``∂s/∂q`` (the point carried by its frame: ``[t, (P − x_a) × t]``; a chord's point
        ``(1 − t) x_a + t x_b``)."""
        x, R = state.positions, qmatrix(state.quaternions)
        k = self.key.shape[0]
        a, b = self.frames[:, 0], self.frames[:, 1]
        chord = self.key[:, 0] == CHORD
        P = np.empty((k, 3))
        rigid = ~chord
        P[rigid] = x[a[rigid]] + np.einsum("kij,kj->ki", R[a[rigid]], self.local[rigid])
        t = self.local[:, 0]
        if chord.any():
            P[chord] = ((1.0 - t[chord])[:, None] * x[a[chord]] + t[chord][:, None] * x[b[chord]]
                        + self.offset[chord])
        direction = self.basis.reshape(2 * k, 3)                      # t₁, t₂ of each contact in turn
        P2 = np.repeat(P, 2, 0)
        slip = np.add.reduce(direction * (P2 - np.repeat(self.point, 2, 0)), 1)
        rows = np.zeros((2 * k, 2, 6))
        chord2 = np.repeat(chord, 2)
        lever = P2 - x[np.repeat(a, 2)]
        rows[~chord2, 0, :3] = direction[~chord2]
        rows[~chord2, 0, 3:] = contact._cross(lever[~chord2], direction[~chord2])
        t2 = np.repeat(t, 2)
        rows[chord2, 0, :3] = (1.0 - t2[chord2])[:, None] * direction[chord2]
        rows[chord2, 1, :3] = t2[chord2][:, None] * direction[chord2]
        frames = np.repeat(self.frames, 2, 0)
        origin = np.where((frames >= 0)[:, :, None], x[np.maximum(frames, 0)], 0.0)
        origin[chord2, 0] = P2[chord2]        # (a chord's rows do not turn with its frames: no lever arm)
        return ContactSet(tangential_keys(self.key), slip, P2, direction, frames, rows, origin, np.zeros((2 * k, 2, 3)))


# ---------------------------------------------------------------------------------------------
# the frictional problem in constraint space


@dataclass
class Friction:
    """The statuses of a frictional complementarity problem: per contact (normal rows) whether it
    is pressed; per frictional contact whether it slips and its slip direction (2, in its tangents)."""

    closed: np.ndarray
    slip: np.ndarray
    direction: np.ndarray


def _set_equations(W, b, m, fr, mu, status: Friction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linear equations of the statuses on the forces they leave free: an open contact has no
    force (and no tangential one), a pressed one closes its gap, a sticking one its slip, a
    slipping one has ``f_t = −μ f_n d``. Returns (the rows ``U`` of those forces — the pressed
    contacts' normal rows and their slip rows —, ``A``, ``rhs``) with ``A λ_U = rhs`` and
    ``λ = 0`` off ``U``: a system the size of the pressed contacts, not of the candidates."""
    t = m + 2 * np.arange(fr.size)
    pressed = status.closed[fr]
    slips = pressed & status.slip
    held = np.zeros(b.size, bool)                  # the rows whose equation is w = 0
    held[:m] = status.closed
    held[t[pressed & ~slips]] = held[t[pressed & ~slips] + 1] = True
    tied = np.zeros(b.size, bool)                  # the slip rows tied to their normal force
    tied[t[slips]] = tied[t[slips] + 1] = True
    U = np.flatnonzero(held | tied)
    position = np.full(b.size, -1)
    position[U] = np.arange(U.size)
    A = W[np.ix_(U, U)]
    rhs = -b[U]
    rows = position[np.concatenate([t[slips], t[slips] + 1])]
    A[rows] = 0.0
    rhs[rows] = 0.0
    A[rows, rows] = 1.0
    slipping = np.flatnonzero(slips)
    for k in range(2):
        A[position[t[slipping] + k], position[fr[slipping]]] = mu[slipping] * status.direction[slipping, k]
    return U, A, rhs


def _solve_set(W, b, m, fr, mu, status: Friction) -> np.ndarray:
    """λ for the statuses (:func:`_set_equations`)."""
    U, A, rhs = _set_equations(W, b, m, fr, mu, status)
    lam = np.zeros(b.size)
    if U.size:
        try:
            lam[U] = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            lam[U] = np.linalg.lstsq(A, rhs, rcond=1e-13)[0]
    return lam


def _directions(W, b, m, fr, mu, status: Friction, scale: float) -> np.ndarray:
    """Solve the slipping contacts' directions so that each one's slip ``w_t`` lies along its
    ``d = (cos θ, sin θ)`` (``h = w_t × d = 0``; Newton on the angles), keeping
    ``status.direction``; returns λ. The Jacobian is exact: with ``A(θ)λ_U = rhs`` the statuses'
    equations (:func:`_set_equations`), ``∂λ/∂θ_s = −A⁻¹ (∂A/∂θ_s) λ``, whose only entries are the
    slipping contact's two rows, ``μ λ_n ∂d/∂θ_s`` — one factorisation of ``A`` a Newton iteration."""
    from scipy.linalg import lu_factor, lu_solve

    sliding = np.flatnonzero(status.slip & status.closed[fr])
    if not sliding.size:
        return _solve_set(W, b, m, fr, mu, status)
    rows = m + 2 * sliding
    normal = fr[sliding]
    index = np.arange(sliding.size)
    angle = np.arctan2(status.direction[sliding, 1], status.direction[sliding, 0])
    lam = np.zeros(b.size)
    for iteration in range(DIRECTION_ITERATIONS + 1):
        status.direction[sliding] = np.stack([np.cos(angle), np.sin(angle)], 1)
        U, A, rhs = _set_equations(W, b, m, fr, mu, status)
        factor = lu_factor(A, check_finite=False)
        if not np.all(np.isfinite(factor[0])) or not np.all(np.diag(factor[0])):
            lam[U] = np.linalg.lstsq(A, rhs, rcond=1e-13)[0]
            break
        lam[U] = lu_solve(factor, rhs, check_finite=False)
        position = np.full(b.size, -1)
        position[U] = np.arange(U.size)
        slip_rows = np.concatenate([rows, rows + 1])
        w = b[slip_rows] + W[np.ix_(slip_rows, U)] @ lam[U]
        w0, w1 = w[:sliding.size], w[sliding.size:]
        cos, sin = np.cos(angle), np.sin(angle)
        h = w0 * sin - w1 * cos
        if iteration == DIRECTION_ITERATIONS or float(np.abs(h).max()) <= DIRECTION_TOLERANCE * scale:
            break
        E = np.zeros((U.size, sliding.size))
        E[position[rows], index] = -mu[sliding] * lam[normal] * sin
        E[position[rows + 1], index] = mu[sliding] * lam[normal] * cos
        dw = W[np.ix_(slip_rows, U)] @ -lu_solve(factor, E, check_finite=False)       # ∂w/∂θ
        J = dw[:sliding.size] * sin[:, None] - dw[sliding.size:] * cos[:, None]
        J[index, index] += w0 * cos + w1 * sin
        try:
            change = np.linalg.solve(J, -h)
        except np.linalg.LinAlgError:
            change = np.linalg.lstsq(J, -h, rcond=1e-13)[0]
        angle = angle + np.clip(change, -0.5, 0.5)
    return lam


def _alart_curnier(W: np.ndarray, b: np.ndarray, m: int, fr: np.ndarray, mu: np.ndarray,
                   lam: np.ndarray) -> tuple[np.ndarray, bool]:
    """The frictional complementarity problem on ``w = b + Wλ`` (:func:`coulomb`) as the
    Alart–Curnier equations ``F(λ) = 0`` solved by semismooth Newton from ``lam``:

        normal rows      ``F_n = min(λ_n, ρ_n w_n)``                      (complementarity)
        slip rows        ``F_t = λ_t − P_r(λ_t − ρ_t w_t)``               (Coulomb's law)

    ``P_r`` the projection onto the disc of radius ``r = μ max(λ_n − ρ_n w_n, 0)`` in the
    tangent plane (``μ λ_n`` at a solution; from the augmented normal force, so that a contact
    that starts to press has a cone at once),
    ``ρ`` the inverse diagonal of ``W`` (per contact for its two slip rows). ``F`` is piecewise
    smooth; each iteration solves with one element of its generalised Jacobian — the branch of
    every ``min`` and projection at ``λ``, so every status changes at once — and halves the step
    until ``½|F|²`` falls (Armijo). Returns (λ, converged to :data:`NEWTON_TOLERANCE`)."""
    n, k = b.size, fr.size
    diagonal = np.abs(np.diag(W))
    rho_n = 1.0 / np.maximum(diagonal[:m], 1e-300)
    t = m + 2 * np.arange(k)
    rho_t = 2.0 / np.maximum(diagonal[t] + diagonal[t + 1], 1e-300)
    rows_t = np.stack([t, t + 1], 1)
    rho = np.concatenate([rho_n, np.repeat(rho_t, 2)])
    force_scale = max(float(np.abs(rho * b).max(initial=0.0)), 1e-300)

    def equations(lam):
        w = b + W @ lam
        F = np.empty(n)
        F[:m] = np.minimum(lam[:m], rho_n * w[:m])
        lam_t = lam[rows_t]
        xi = lam_t - rho_t[:, None] * w[rows_t]
        radius = mu * np.maximum(lam[fr] - rho_n[fr] * w[fr], 0.0)
        norm = np.sqrt(np.add.reduce(xi * xi, 1))
        slips = norm > radius
        shrink = np.where(slips, radius / np.maximum(norm, 1e-300), 1.0)
        F[m:] = (lam_t - shrink[:, None] * xi).reshape(-1)
        return F, xi, norm, slips, shrink, w

    F, xi, norm, slips, shrink, w = equations(lam)
    merit = float(F @ F)
    for _ in range(NEWTON_ITERATIONS):
        if float(np.abs(F).max(initial=0.0)) <= NEWTON_TOLERANCE * max(force_scale, float(np.abs(lam).max(initial=0.0))):
            return lam, True
        J = np.zeros((n, n))
        pressing = lam[:m] > rho_n * w[:m]
        J[:m] = np.where(pressing[:, None], rho_n[:, None] * W[:m], 0.0)
        J[np.flatnonzero(~pressing), np.flatnonzero(~pressing)] = 1.0
        # the slip rows: dF_t = dλ_t − s M (dλ_t − ρ_t W_t dλ) − ξ̂ μ (dλ_n − ρ_n W_n dλ) (slipping;
        # s = r/|ξ|, M = I − ξ̂ξ̂ᵀ), ρ_t W_t dλ (sticking: s = 1, M = I, r fixed)
        unit = xi / np.maximum(norm, 1e-300)[:, None]
        M = np.eye(2) - np.where(slips[:, None, None], unit[:, :, None] * unit[:, None, :], 0.0)
        sM = shrink[:, None, None] * M                                         # (k, 2, 2)
        J[m:] = (np.einsum("kij,kjn->kin", sM * rho_t[:, None, None], W[rows_t])).reshape(2 * k, n)
        block = np.eye(2) - sM
        J[rows_t[:, :, None], rows_t[:, None, :]] += block
        pushing = np.flatnonzero(slips & pressing[fr])
        if pushing.size:
            # −μ ξ̂ (e_n − ρ_n W_n): the cone's radius follows the augmented normal force
            J[rows_t[pushing]] += (mu[pushing, None, None] * unit[pushing][:, :, None]
                                   * (rho_n[fr[pushing], None] * W[fr[pushing]])[:, None, :])
            J[rows_t[pushing], fr[pushing, None]] -= mu[pushing, None] * unit[pushing]
        try:
            delta = np.linalg.solve(J, -F)
        except np.linalg.LinAlgError:
            delta = np.linalg.lstsq(J, -F, rcond=1e-13)[0]
        if not np.all(np.isfinite(delta)):
            return lam, False
        alpha = 1.0
        for _ in range(HALVINGS):
            trial = lam + alpha * delta
            found = equations(trial)
            new = float(found[0] @ found[0])
            if new <= (1.0 - 1e-4 * alpha) * merit:
                break
            alpha *= 0.5
        else:
            return lam, False
        lam, merit = trial, new
        F, xi, norm, slips, shrink, w = found
    return lam, bool(float(np.abs(F).max(initial=0.0))
                     <= NEWTON_TOLERANCE * max(force_scale, float(np.abs(lam).max(initial=0.0))))


def _statuses(W: np.ndarray, b: np.ndarray, m: int, fr: np.ndarray, mu: np.ndarray, lam: np.ndarray) -> Friction:
    """The statuses of a solution ``lam`` of the Alart–Curnier equations (:func:`_alart_curnier`):
    a contact is pressed where its ``min`` takes ``ρ_n w_n`` with ``λ_n > 0``, a pressed frictional
    one slips where ``λ_t − ρ_t w_t`` lies outside its cone's disc (beyond its rounding), along ``d = −(λ_t − ρ_t w_t)``
    normalised (``w_t = γ d``, ``λ_t = −μ λ_n d``)."""
    w = b + W @ lam
    diagonal = np.abs(np.diag(W))
    closed = (lam[:m] > 0.0) & (lam[:m] > w[:m] / np.maximum(diagonal[:m], 1e-300))
    t = m + 2 * np.arange(fr.size)
    rho_t = 2.0 / np.maximum(diagonal[t] + diagonal[t + 1], 1e-300)
    xi = np.stack([lam[t] - rho_t * w[t], lam[t + 1] - rho_t * w[t + 1]], 1)
    norm = np.sqrt(np.add.reduce(xi * xi, 1))
    radius = mu * np.maximum(lam[fr], 0.0)
    slip = closed[fr] & (norm - radius > 1e-12 * radius)    # (on the cone's edge, not moving: stuck)
    direction = np.tile([1.0, 0.0], (fr.size, 1))
    direction[slip] = -xi[slip] / norm[slip, None]
    return Friction(closed, slip, direction)


def coulomb(W: np.ndarray, b: np.ndarray, m: int, fr: np.ndarray, mu: np.ndarray,
            start: Friction | None = None, guess: np.ndarray | None = None) -> tuple[np.ndarray, Friction] | None:
    """The frictional complementarity problem on ``w = b + Wλ`` (:func:`_active_set` states it),
    on a working set of contacts: those whose linearised gap is negative or that ``start`` presses
    (with their slip rows), solved by :func:`_solve_working`; a contact outside it whose gap the
    answer closes beyond the rounding joins it and the problem is solved again. Its answer, with
    no force on the others, is the whole problem's answer (their gaps open, no force, no friction);
    the candidates far from touching cost one product with ``W`` instead of rows in every solve.
    ``guess``: forces (n,) to start Newton from besides the statuses' (the frictionless answer's)."""
    scale = float(np.abs(b).max(initial=0.0)) + 1e-300
    start = start if start is not None else Friction(b[:m] < 0.0, np.zeros(fr.size, bool),
                                                     np.tile([1.0, 0.0], (fr.size, 1)))
    working = start.closed | (b[:m] < 0.0)
    owner = np.full(m, -1)
    owner[fr] = np.arange(fr.size)
    for _ in range(m + 1):
        normal = np.flatnonzero(working)
        inside = working[fr]
        c = np.flatnonzero(inside)
        t = m + 2 * c
        rows = np.concatenate([normal, np.stack([t, t + 1], 1).reshape(-1)])
        position = np.full(m, -1)
        position[normal] = np.arange(normal.size)
        sub_start = Friction(start.closed[normal], start.slip[c], start.direction[c])
        found = _solve_working(W[np.ix_(rows, rows)], b[rows], normal.size, position[fr[c]], mu[c], sub_start,
                               None if guess is None else guess[rows])
        if found is None:
            return None
        sub_lam, sub_status = found
        lam = np.zeros(b.size)
        lam[rows] = sub_lam
        w = b[:m] + W[:m, rows] @ sub_lam
        closing = ~working & (w < -1e-13 * scale)
        if not closing.any():
            closed = np.zeros(m, bool)
            closed[normal] = sub_status.closed
            slip = np.zeros(fr.size, bool)
            slip[c] = sub_status.slip
            direction = np.tile([1.0, 0.0], (fr.size, 1))
            direction[c] = sub_status.direction
            return lam, Friction(closed, slip, direction)
        working |= closing
    return None


def _solve_working(W: np.ndarray, b: np.ndarray, m: int, fr: np.ndarray, mu: np.ndarray,
                   start: Friction, guess: np.ndarray | None = None) -> tuple[np.ndarray, Friction] | None:
    """The frictional complementarity problem of :func:`coulomb` on its working set: the
    Alart–Curnier equations by semismooth Newton (:func:`_alart_curnier`), from the forces of the
    statuses ``start`` (the last step's: along a solve mostly the answer's) and, where that does
    not converge, from ``guess`` (the frictionless answer's forces), then from no force. Where neither converges (nearly redundant contacts — both rims
    of a disc on a sphere — leave Newton at a local minimum of its merit), the active set from
    ``start``; where its statuses run in a cycle, from the statuses of projected Gauss–Seidel
    sweeps (:func:`_sweeps`) — and where that cycles too, the sweeps' answer itself when they
    converged to :data:`SWEEP_TOLERANCE`."""
    starts = [np.zeros(b.size)]
    if guess is not None and np.any(guess):
        starts.insert(0, guess)
    if start.closed.any():
        guess = _solve_set(W, b, m, fr, mu, start)
        if np.all(np.isfinite(guess)):
            starts.insert(0, guess)
    for guess in starts:
        lam, converged = _alart_curnier(W, b, m, fr, mu, guess)
        if converged:
            return lam, _statuses(W, b, m, fr, mu, lam)
    found = _active_set(W, b, m, fr, mu, start)
    if found is not None:
        return found
    lam, status, converged = _sweeps(W, b, m, fr, mu)
    found = _active_set(W, b, m, fr, mu, status)
    if found is not None:
        return found
    return (lam, status) if converged else None


def _local(A: np.ndarray, q: np.ndarray, mu: float, guess: np.ndarray | None = None) -> tuple[np.ndarray, bool, np.ndarray]:
    """One frictional contact's problem ``w = q + Aλ`` (rows: gap, two slips): open, stuck or
    slipping — the slip direction from ``guess`` (the last sweep's) by the fixed point
    ``d ← w_t/|w_t|``, else by its angle: 64 samples, then regula falsi on ``w_t × d``.
    Returns (λ, slips, direction)."""
    none = np.array([1.0, 0.0])
    if q[0] >= 0.0:
        return np.zeros(3), False, none
    try:
        lam = np.linalg.solve(A, -q)
    except np.linalg.LinAlgError:
        lam = np.linalg.lstsq(A, -q, rcond=1e-13)[0]
    if lam[0] > 0.0 and math.hypot(lam[1], lam[2]) <= mu * lam[0]:
        return lam, False, none

    def at(theta):
        d = np.stack([np.cos(theta), np.sin(theta)], -1)
        f_n = -q[0] / (A[0, 0] - mu * (d @ A[0, 1:]))
        lam_t = -mu * f_n[..., None] * d
        w_t = q[1:] + A[1:, 0] * f_n[..., None] + lam_t @ A[1:, 1:].T
        return f_n, lam_t, w_t, d

    if guess is not None:
        angle = math.atan2(guess[1], guess[0])
        for _ in range(8):
            f_n, lam_t, w_t, d = at(np.array([angle]))
            norm = math.hypot(*w_t[0])
            if not (f_n[0] > 0.0 and norm > 0.0):
                break
            if abs(w_t[0, 0] * d[0, 1] - w_t[0, 1] * d[0, 0]) <= DIRECTION_TOLERANCE * norm and w_t[0] @ d[0] > 0.0:
                return np.array([f_n[0], lam_t[0, 0], lam_t[0, 1]]), True, d[0]
            angle = math.atan2(w_t[0, 1], w_t[0, 0])
    theta = 2.0 * math.pi * np.arange(64) / 64
    f_n, _, w_t, d = at(theta)
    cross = w_t[:, 0] * d[:, 1] - w_t[:, 1] * d[:, 0]
    along = np.add.reduce(w_t * d, 1)
    good = (f_n > 0.0) & (along >= 0.0)
    best = None
    following = np.roll(cross, -1)
    for k in np.flatnonzero(good & (np.sign(cross) != np.sign(following))).tolist():
        # regula falsi (Illinois) on the bracket's cross product, to the rounding of the angle
        low, high, f_low, f_high = theta[k], theta[k] + 2.0 * math.pi / 64, cross[k], following[k]
        side = 0
        for _ in range(60):
            middle = (low * f_high - high * f_low) / (f_high - f_low) if f_high != f_low else 0.5 * (low + high)
            value = at(np.array([middle]))
            c = value[2][0, 0] * value[3][0, 1] - value[2][0, 1] * value[3][0, 0]
            if c == 0.0 or high - low <= 1e-15:
                break
            if np.sign(c) == np.sign(f_low):
                low, f_low = middle, c
                f_high = 0.5 * f_high if side == -1 else f_high
                side = -1
            else:
                high, f_high = middle, c
                f_low = 0.5 * f_low if side == 1 else f_low
                side = 1
        value = at(np.array([middle]))
        if value[0][0] > 0.0 and float(value[2][0] @ value[3][0]) >= 0.0:
            best = value
            break
    if best is None:
        k = int(np.argmin(np.where(good, np.abs(cross), np.inf))) if good.any() else 0
        best = at(theta[k:k + 1])
    f_n, lam_t, _, d = best
    return np.array([f_n[0], lam_t[0, 0], lam_t[0, 1]]), True, d[0]


def _sweeps(W, b, m, fr, mu) -> tuple[np.ndarray, Friction, bool]:
    """Projected (block) Gauss–Seidel on the contacts: each in turn solves its own problem
    (:func:`_local`; a frictionless one its gap) with the others' forces held, until the forces
    change by less than :data:`SWEEP_TOLERANCE` of their largest. Returns (λ, the statuses, converged)."""
    n = b.size
    lam = np.zeros(n)
    blocks = []
    owner = {int(i): c for c, i in enumerate(fr.tolist())}
    for i in range(m):
        c = owner.get(i)
        blocks.append(np.array([i] if c is None else [i, m + 2 * c, m + 2 * c + 1]))
    status = Friction(np.zeros(m, bool), np.zeros(fr.size, bool), np.tile([1.0, 0.0], (fr.size, 1)))
    diagonal = [W[np.ix_(rows, rows)] for rows in blocks]
    coupling = [W[rows] for rows in blocks]
    converged = False
    for _ in range(SWEEPS):
        change = 0.0
        for i, rows in enumerate(blocks):
            q = b[rows] + coupling[i] @ lam - diagonal[i] @ lam[rows]
            if rows.size == 1:
                new = np.array([max(0.0, -q[0] / W[i, i])])
            else:
                c = owner[i]
                new, slips, direction = _local(diagonal[i], q, mu[c], status.direction[c] if status.slip[c] else None)
                status.slip[c], status.direction[c] = slips, direction
            status.closed[i] = new[0] > 0.0
            change = max(change, float(np.abs(new - lam[rows]).max()))
            lam[rows] = new
        if change <= SWEEP_TOLERANCE * max(float(np.abs(lam).max()), 1e-300):
            converged = True
            break
    return lam, status, converged


def _active_set(W: np.ndarray, b: np.ndarray, m: int, fr: np.ndarray, mu: np.ndarray,
                start: Friction | None = None, changes: int | None = None) -> tuple[np.ndarray, Friction] | None:
    """The frictional complementarity problem on ``w = b + Wλ``: rows ``0…m−1`` the contacts'
    gaps (``w ≥ 0, λ ≥ 0, wᵀλ = 0``), then two slip rows for each frictional contact ``fr`` (its
    index among the first ``m``) with its ``μ``: a pressed contact sticks (``w_t = 0``,
    ``|λ_t| ≤ μ λ_n``) or slips (``λ_t = −μ λ_n d``, ``w_t = γ d``, ``γ ≥ 0``), an open one has
    no tangential force. An active set from ``start`` (or every contact whose linearised gap is
    negative pressed and stuck): each round solves the set's linear equations (the slipping
    contacts' directions by Newton, :func:`_directions`) and changes the status that is violated
    most — a pressed contact pulling opens, an open one penetrating closes (stuck), a stuck one
    beyond its cone slips (opposite its tangential force), a slipping one moving against its
    direction sticks. Returns (λ, the statuses), or None when no set is found."""
    n = b.size
    scale = float(np.abs(b).max(initial=0.0)) + 1e-300
    diagonal = float(np.abs(np.diag(W)).max(initial=0.0)) if n else 0.0
    force_scale = scale / max(diagonal, 1e-300)
    status = (start if start is not None else
              Friction(b[:m] < 0.0, np.zeros(fr.size, bool), np.tile([1.0, 0.0], (fr.size, 1))))
    status = Friction(status.closed.copy(), status.slip.copy(), status.direction.copy())
    visited = set()
    for _ in range(changes if changes is not None else STATUS_CHANGES * (m + fr.size) + 10):
        seen = (status.closed.tobytes(), status.slip.tobytes())
        if seen in visited:
            return None                  # the statuses run in a cycle
        visited.add(seen)
        lam = _directions(W, b, m, fr, mu, status, scale)
        w = b + W @ lam
        # the violations' scores (0: none), normal rows then frictional contacts: the first largest changes
        closed = status.closed
        pulls = closed & (lam[:m] < -1e-13 * force_scale)
        penetrates = ~closed & (w[:m] < -1e-13 * scale)
        normal_score = np.where(pulls, -lam[:m] / force_scale, np.where(penetrates, -w[:m] / scale, 0.0))
        t = m + 2 * np.arange(fr.size)
        f_t, w_t = np.stack([lam[t], lam[t + 1]], 1), np.stack([w[t], w[t + 1]], 1)
        lam_n = lam[fr]
        excess = np.sqrt(np.add.reduce(f_t * f_t, 1)) - mu * np.maximum(lam_n, 0.0)
        outside = ~status.slip & (excess > 1e-12 * np.maximum(mu * np.abs(lam_n), 1e-13 * force_scale))
        along = np.add.reduce(w_t * status.direction, 1)
        back = status.slip & (along < -1e-13 * scale)
        friction_score = np.where(closed[fr] & outside, excess / force_scale,
                                  np.where(closed[fr] & back, -along / scale, 0.0))
        scores = np.concatenate([normal_score, friction_score])
        change = None
        if scores.size and float(scores.max()) > 0.0:
            j = int(np.argmax(scores))
            if j < m:
                change = ("open" if pulls[j] else "close", j)
            else:
                change = ("slip" if not status.slip[j - m] else "stick", j - m)
        if change is None:
            return lam, status
        what, index = change
        if what == "open":
            status.closed[index] = False
        elif what == "close":
            status.closed[index] = True
            status.slip[np.flatnonzero(fr == index)] = False
        elif what == "slip":
            f_t = lam[m + 2 * index:m + 2 * index + 2]
            status.slip[index] = True
            status.direction[index] = -f_t / max(float(np.hypot(*f_t)), 1e-300)
        else:
            status.slip[index] = False
    return None


# ---------------------------------------------------------------------------------------------
# the contact side of a Newton stage, with friction


class FrictionalConstraints(contact.Constraints):
    """:class:`~vertebra.solver.contact.Constraints` with Coulomb friction at the contacts with
    frictional obstacles: the multipliers hold, after the pressed contacts' normal forces, the
    tangential forces of the frictional ones among them (two each, along their anchors' tangents)."""

    def __init__(self, trunk, session: "Session"):
        super().__init__(trunk)
        self.session = session
        self.status: dict = {}        # contact key → (slips, direction (2,)) of the last step
        self.centre = None            # Σ k Gᵀc of the springs on frictional rows in the tangent factored now
        self.across = None            # (contacts, their slip directions) sprung across the slip now

    def lagrangian(self, matrix, state):
        self.centre = None            # (a new iteration's tangent: no springs until stiffened)
        return super().lagrangian(matrix, state)

    def stiffened(self, matrix, state, stiffness: float = contact.STABILITY_SPRING, step: Step | None = None):
        """:meth:`Constraints.stiffened`, with the springs on the frictional contacts' rows (their
        gaps and the stuck ones' slips) centred on the linearised row ``c + Gp`` instead of the
        step ``Gp``: a spring about ``Gp`` would carry ``−k c`` of the contact's force — beside the
        multiplier, so outside the friction law, which bounds the tangential force by ``μ`` times
        the multiplier (docs/contact.md, Friction). Centred, a row held closed carries
        no spring force and the multiplier is the whole force. The step's right-hand side takes
        ``−Σ k Gᵀc`` (:attr:`centre`)."""
        stiffened = super().stiffened(matrix, state, stiffness, step)
        self.centre = None
        if self.springs is not None:
            G, spring, key = self.springs
            held = self.held(state, step)
            value = {tuple(k): c for k, c in zip(held.key.tolist(), held.gap.tolist())}
            owner = key.copy()
            tangential = key[:, 0] >= TANGENTIAL
            owner[tangential, 0] = (key[tangential, 0] - TANGENTIAL) // 2
            frictional = coefficients(self.model, owner) > 0.0
            if frictional.any():
                c = np.array([value[tuple(k)] for k in key[frictional].tolist()])
                self.centre = G[frictional].T @ (spring[frictional] * c)
        self.across = None
        across = self._across(state, step) if self.springs is not None else None
        if across is not None:
            G, spring, c, owners = across
            self.across = (owners, {k: self.status[k][1].copy() for k in owners})
            centre = G.T @ (spring * c)
            self.centre = centre if self.centre is None else self.centre + centre
            U, d = stiffened.low_rank if stiffened.low_rank is not None else (np.zeros((G.shape[1], 0)), np.zeros(0))
            stiffened = type(stiffened)(stiffened.assembler, stiffened.terms, (np.hstack([U, G.T]), np.concatenate([d, spring])))
        return stiffened

    def _across(self, state, step: Step | None):
        """The slipping contacts' friction across their slip: ``f_t = −μ f_n s/|s|`` turns with the
        slip ``s``, a stiffness ``μ f_n/|s|`` across the slip direction ``d`` (the tangent of
        Coulomb's law on the cone's edge, symmetric and positive: the friction force follows the
        slip sideways). The Lagrangian's tangent leaves it out — the step's problem solves the
        direction instead — so a trunk pressed and slipping over a convex obstacle can be
        indefinite on the free directions where with it it is not, and the shift would damp every
        step. Returns the rows across (``d_⊥ᵀ ∂s/∂q``), their stiffnesses, their values
        ``d_⊥ᵀ s`` (the springs are centred there: at the step's answer, whose slip lies along
        ``d``, they carry no force) and the contacts; None when none slips."""
        if step is None:
            if not self.multipliers.size:
                return None
            found, lam = self.pressed(state), self.multipliers
        else:
            keep = self._kept(step)
            found, lam = step.contacts.take(np.flatnonzero(keep)), step.multipliers[keep]
        slipping = self._slipping(found.key)
        if not slipping.any():
            return None
        force = {tuple(k): f for k, f in zip(found.key.tolist(), lam.tolist()) if k[0] < TANGENTIAL}
        rows, springs, values, owners = [], [], [], []
        G = found.jacobian(self.n_frames)
        for j in np.flatnonzero(slipping)[::2].tolist():
            owner = tuple(normal_keys(found.key[j:j + 2])[0].tolist())
            s = found.gap[j:j + 2]
            size = float(np.hypot(*s))
            f_n = force.get(owner, 0.0)
            if not (size > 0.0 and f_n > 0.0):
                continue
            d = self.status[owner][1]
            across = np.array([-d[1], d[0]])
            row = across[0] * G[j] + across[1] * G[j + 1]
            squared = float(row @ row)
            if squared == 0.0:
                continue
            mu = float(coefficients(self.model, np.array([owner]))[0])
            rows.append(row)
            springs.append(mu * f_n / size)
            values.append(float(across @ s))
            owners.append(owner)
        if not rows:
            return None
        return np.array(rows), np.array(springs), np.array(values), owners

    def released(self, step: Step) -> bool:
        """:meth:`Constraints.released`, or a contact sprung across its slip that the step leaves
        sticking or open or slipping another way (the springs across the old direction would
        carry force at the step's answer)."""
        if super().released(step):
            return True
        if getattr(self, "across", None) is None:
            return False
        owners, directions = self.across
        for k in owners:
            slips, d = self.status.get(k, (False, None))
            if not slips or not np.array_equal(d, directions[k]):
                return True
        return False

    # the rows of a set of contacts: normal ones (contact.evaluate) and, for the frictional, slip rows
    def _rows(self, state, normal: ContactSet) -> tuple[ContactSet, np.ndarray]:
        mu = coefficients(self.model, normal.key)
        fr = np.flatnonzero(mu > 0.0)
        slip = self.session.anchors(normal.key[fr]).rows(state)
        return _joined(normal, slip), fr

    def pressed(self, state) -> ContactSet:
        if self._pressed[0] is not state or self._pressed[1] is not self.keys:
            normal = self.keys[self.keys[:, 0] < TANGENTIAL]
            found = self.contacts(state, normal)
            rows, _ = self._rows(state, found)
            self._pressed = (state, self.keys, rows)
        return self._pressed[2]

    def step(self, factor, r: np.ndarray, state) -> Step | None:
        """The sequential-QP step with friction (module docstring). Only the frictional contacts
        that can press carry slip rows — those pressed at the last step or by the frictionless
        problem, and any the frictional answer presses (then solved again): an open contact has
        no tangential force."""
        normal = self.at(state)
        p = factor.solve(r if self.centre is None else r - self.centre)
        if not normal.count:
            return Step(p, np.zeros(0), normal, r)
        m = normal.count
        mu_all = coefficients(self.model, normal.key)
        G_n = normal.jacobian(self.n_frames)
        Z_n = factor.solve(np.asfortranarray(G_n.T))
        W_n = G_n @ Z_n
        b_n = normal.gap + G_n @ p
        floor = contact.REGULARISATION * max(float(np.abs(np.diag(W_n)).max()), 1e-300)
        frictionless = contact.complementarity(W_n + floor * np.eye(m), b_n)
        pressed = {tuple(k) for k in self.keys[self.keys[:, 0] < TANGENTIAL].tolist()}
        relevant = (mu_all > 0.0) & ((b_n < 0.0) | np.array([tuple(k) in pressed for k in normal.key.tolist()], bool)
                                     | (frictionless > 0.0 if frictionless is not None else True))
        for _ in range(m + 1):
            fr = np.flatnonzero(relevant)
            slip = self.session.anchors(normal.key[fr]).rows(state)
            contacts = _joined(normal, slip)
            G_t = slip.jacobian(self.n_frames) if fr.size else np.zeros((0, G_n.shape[1]))
            Z = np.hstack([Z_n, factor.solve(np.asfortranarray(G_t.T))]) if fr.size else Z_n
            G = np.vstack([G_n, G_t])
            W = G @ Z
            b = np.concatenate([b_n, slip.gap + G_t @ p])
            regularised = W.copy()
            regularised[np.diag_indices_from(W)] += floor
            mu = mu_all[fr]
            guess = None
            if frictionless is not None:
                guess = np.zeros(b.size)
                guess[:m] = frictionless
            found = coulomb(regularised, b, m, fr, mu, self._start(normal.key, fr, b[:m], frictionless), guess)
            if found is None:
                return None
            lam, status = found
            missing = status.closed & (mu_all > 0.0) & ~relevant
            if not missing.any():
                break
            relevant |= missing
        refined = Friction(status.closed, status.slip, status.direction.copy())
        exact = _directions(W, b, m, fr, mu, refined, float(np.abs(b).max()) + 1e-300)
        if np.all(exact[:m][status.closed] > 0.0):
            # the pressed contacts' gaps and the stuck ones' slips closed exactly, the slipping ones'
            # slips along the directions solved with them: those directions are the statuses' (the
            # forces are −μ f_n d along them, and the converged state's slip is checked against them)
            lam, status = exact, refined
        lam[:m] = np.where(status.closed, np.maximum(lam[:m], 0.0), 0.0)
        for c, i in enumerate(fr.tolist()):
            if not status.closed[i]:
                lam[m + 2 * c:m + 2 * c + 2] = 0.0
            self.status[tuple(normal.key[i].tolist())] = (bool(status.slip[c]), status.direction[c].copy())
        return Step(p + Z @ lam, lam, contacts, r + G.T @ lam)

    def _start(self, key: np.ndarray, fr: np.ndarray, b: np.ndarray, frictionless: np.ndarray | None) -> Friction:
        """The statuses the last step left for these contacts (new ones: pressed where the
        frictionless problem presses them — else where their linearised gap is negative —, stuck):
        where many linearised gaps are negative and few contacts press (a soft trunk whose one
        contact lifts its whole length), the frictionless answer is near the frictional one, every
        negative gap pressed is far from it."""
        pressed = {tuple(k) for k in self.keys[self.keys[:, 0] < TANGENTIAL].tolist()}
        closed = (np.array([tuple(k) in pressed for k in key.tolist()], bool)
                  | (b < 0.0 if frictionless is None else frictionless > 0.0))
        slip = np.zeros(fr.size, bool)
        direction = np.tile([1.0, 0.0], (fr.size, 1))
        for c, i in enumerate(fr.tolist()):
            last = self.status.get(tuple(key[i].tolist()))
            if last is not None:
                slip[c], direction[c] = last[0], last[1]
        return Friction(closed, slip, direction)

    def accept(self, step: Step) -> None:
        keep = self._kept(step)
        self.keys = step.contacts.key[keep]
        self.multipliers = step.multipliers[keep]
        self.reference = step.contacts.gap[keep]

    @staticmethod
    def _kept(step: Step) -> np.ndarray:
        """The rows of ``step`` that carry forces: the pressed contacts and the slip rows of those."""
        key = step.contacts.key
        normal = key[:, 0] < TANGENTIAL
        keep = normal & (step.multipliers > 0.0)
        pressed = {tuple(k) for k in key[keep].tolist()}
        if (~normal).any():
            owner = np.repeat(normal_keys(key[~normal]), 2, 0)
            keep[~normal] = [tuple(k) in pressed for k in owner.tolist()]
        return keep

    def _slipping(self, keys: np.ndarray) -> np.ndarray:
        """Per tangential row of ``keys``: does its contact slip (the last step's status)?"""
        tangential = keys[:, 0] >= TANGENTIAL
        out = np.zeros(keys.shape[0], bool)
        if tangential.any():
            owner = np.repeat(normal_keys(keys[tangential]), 2, 0)
            out[tangential] = [self.status.get(tuple(k), (False, None))[0] for k in owner.tolist()]
        return out

    def held(self, state, step: Step | None = None) -> ContactSet | None:
        """The pressed contacts and the slip rows of the stuck ones (a slipping contact leaves its
        tangential directions free)."""
        if step is None:
            if not self.multipliers.size:
                return None
            found = self.pressed(state)
        else:
            keep = self._kept(step)
            if not (keep & (step.contacts.key[:, 0] < TANGENTIAL)).any():
                return None
            found = step.contacts.select(step.contacts.key[keep])
        return found.select(found.key[~self._slipping(found.key)])

    def reestimate(self, gradient: np.ndarray, state, weights: np.ndarray) -> None:
        """The forces that balance ``∇E`` best (:meth:`Constraints.reestimate`), the normal ones
        ``≥ 0``, a stuck contact's tangential ones free and a slipping one's ``−μ f_n d``."""
        if not self.multipliers.size:
            return
        from scipy.optimize import lsq_linear

        found = self.pressed(state)
        G = found.jacobian(self.n_frames).reshape(found.count, -1, 6)
        A = (G * weights).reshape(found.count, -1)
        normal = np.flatnonzero(found.key[:, 0] < TANGENTIAL)
        index = {tuple(k): i for i, k in enumerate(found.key[normal].tolist())}
        slipping = self._slipping(found.key)
        columns = A.copy()
        tied = np.flatnonzero(slipping)
        mu = coefficients(self.model, found.key[normal])
        for j in tied[::2].tolist():
            owner = tuple(normal_keys(found.key[j:j + 2])[0].tolist())
            i = normal[index[owner]]
            d = self.status[owner][1]
            columns[i] = columns[i] - mu[index[owner]] * (d[0] * A[j] + d[1] * A[j + 1])
        free = np.flatnonzero(~slipping)
        lower = np.where(found.key[free, 0] < TANGENTIAL, 0.0, -np.inf)
        b = (gradient[1:] * weights).reshape(-1)
        solution = lsq_linear(columns[free].T, b, bounds=(lower, np.full(free.size, np.inf)), method="bvls",
                              lsmr_tol="auto").x
        lam = np.zeros(found.count)
        lam[free] = solution
        for j in tied[::2].tolist():
            owner = tuple(normal_keys(found.key[j:j + 2])[0].tolist())
            f_n = lam[normal[index[owner]]]
            lam[j:j + 2] = -mu[index[owner]] * f_n * self.status[owner][1]
        step = Step(np.zeros(0), lam, found, np.zeros(0))
        keep = self._kept(step)
        self.keys, self.multipliers = self.keys[keep], lam[keep]
        if self.reference is not None:
            self.reference = self.reference[keep]

    def feasible(self, state) -> bool:
        """No penetration, every pressed contact closed, every stuck one's slip zero and every
        slipping one's slip along its direction (to the pressed gaps' tolerance)."""
        tolerance = contact.GAP_TOLERANCE * self.model.length
        candidates = self.at(state)
        if candidates.count and float(candidates.gap.min()) < -tolerance:
            return False
        if not self.multipliers.size:
            return True
        found = self.pressed(state)
        limit = contact.ACTIVE_GAP * self.model.length
        slipping = self._slipping(found.key)
        if float(np.abs(found.gap[~slipping]).max()) > limit:
            return False
        for j in np.flatnonzero(slipping)[::2].tolist():
            owner = tuple(normal_keys(found.key[j:j + 2])[0].tolist())
            d = self.status[owner][1]
            s = found.gap[j:j + 2]
            if abs(s[0] * d[1] - s[1] * d[0]) > limit or float(s @ d) < -limit:
                return False
        return True

    def report(self, state) -> tuple:
        """Every candidate contact with its force and, at frictional obstacles, its tangential force
        (world) and whether it sticks, slips or is open."""
        normal = self.keys[:, 0] < TANGENTIAL
        found = self.pressed(state) if self.multipliers.size else None
        friction = {}
        if found is not None:
            for j in np.flatnonzero(~normal)[::2].tolist():
                owner = tuple(normal_keys(self.keys[j:j + 2])[0].tolist())
                force = self.multipliers[j] * found.normal[j] + self.multipliers[j + 1] * found.normal[j + 1]
                friction[owner] = (tuple(force.tolist()), "slip" if self.status.get(owner, (False,))[0] else "stick")

        def tangential(keys):
            mu = coefficients(self.model, keys)
            return [{} if mu[i] == 0.0 else dict(zip(("friction", "sliding"),
                                                     friction.get(tuple(k), ((0.0, 0.0, 0.0), "open"))))
                    for i, k in enumerate(keys.tolist())]

        return contact.report(self.model, state, self.keys[normal], self.multipliers[normal], tangential,
                              found=self.at(state))


def _joined(a: ContactSet, b: ContactSet) -> ContactSet:
    return ContactSet(*(np.concatenate([x, y]) for x, y in zip(
        (a.key, a.gap, a.point, a.normal, a.frames, a.rows, a.origin, a.slide),
        (b.key, b.gap, b.point, b.normal, b.frames, b.rows, b.origin, b.slide))))


# ---------------------------------------------------------------------------------------------
# the history between increments


@dataclass(frozen=True, eq=False)
class ContactFriction:
    """The friction state a solve leaves (``result.friction``) and the next increment starts from:
    the committed ``state`` and, per frictional contact pressed there (``key`` (k, 3)), whether it
    slipped in the increment that ended there (``slipped``), its slip direction (world; zero when
    it stuck) and its tangential force (world, on the body)."""

    state: object
    key: np.ndarray
    slipped: np.ndarray
    direction: np.ndarray
    force: np.ndarray


def at_state(state) -> ContactFriction:
    """A friction state at ``state`` with nothing known of how it was reached (the next increment
    anchors its contacts there)."""
    return ContactFriction(state, np.zeros((0, 3), int), np.zeros(0, bool), np.zeros((0, 3)), np.zeros((0, 3)))


class Session:
    """The friction state along one forward solve: the increment's start (anchors are taken
    there), committed after every load stage that converges."""

    def __init__(self, trunk, start, history: ContactFriction | None):
        self.trunk, self.model = trunk, trunk.contact
        self.history = history            # given: the solve is one increment from it (no restart from rest)
        self.start = start
        self._anchors: dict = {}
        self._committed = None             # a state committed, the start of the next stage
        self.last = history

    def anchors(self, key: np.ndarray) -> Anchors:
        """The anchors of contacts ``key`` at the increment's start (kept for the increment)."""
        missing = [k for k in map(tuple, key.tolist()) if k not in self._anchors]
        if missing:
            found = Anchors.at(self.model, self.start, np.array(missing, int).reshape(-1, 3))
            for i, k in enumerate(missing):
                self._anchors[k] = found.take(np.array([i]))
        if not key.shape[0]:
            return Anchors(np.zeros((0, 3), int), np.zeros((0, 2), int), np.zeros((0, 3)), np.zeros((0, 3)),
                           np.zeros((0, 3)), np.zeros((0, 2, 3)))
        parts = [self._anchors[k] for k in map(tuple, key.tolist())]
        return Anchors(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                         ("key", "frames", "local", "offset", "point", "basis")))

    def constraints(self, trunk) -> FrictionalConstraints:
        """The contact side of a new load stage (an increment from the last committed state)."""
        if self._committed is not None:
            self.start, self._anchors, self._committed = self._committed, {}, None
        return FrictionalConstraints(trunk, self)

    def commit(self, constraints: FrictionalConstraints, state) -> None:
        """A load stage converged at ``state``: the next stage's increment starts there (the
        anchors of this one stay until then: the result reports with them)."""
        self.last = self.state_of(constraints, state)
        self._committed = state

    def restart(self, state) -> None:
        """The solve starts again from ``state`` (a warm start without history that failed)."""
        self.start, self._anchors, self.last, self._committed = state, {}, None, None

    def state_of(self, constraints: FrictionalConstraints | None, state) -> ContactFriction:
        """The friction state at ``state`` reached with ``constraints``' forces."""
        if constraints is None or not constraints.multipliers.size:
            return at_state(state)
        keys, lam = constraints.keys, constraints.multipliers
        found = constraints.pressed(state)
        rows = np.flatnonzero(keys[:, 0] >= TANGENTIAL)[::2]
        owners = normal_keys(keys[np.repeat(rows, 2) + np.tile([0, 1], rows.size)]) if rows.size else np.zeros((0, 3), int)
        slipped = np.array([constraints.status.get(tuple(k), (False,))[0] for k in owners.tolist()], bool)
        force = np.array([lam[j] * found.normal[j] + lam[j + 1] * found.normal[j + 1] for j in rows.tolist()]).reshape(-1, 3)
        direction = np.array([constraints.status[tuple(k)][1] @ found.normal[j:j + 2] if s else np.zeros(3)
                              for k, s, j in zip(owners.tolist(), slipped, rows.tolist())]).reshape(-1, 3)
        return ContactFriction(state, owners, slipped, direction, force)


def solve(trunk, loads, actuation: np.ndarray, initial, history: ContactFriction | None, **options):
    """The forward solve with friction at obstacle contacts: ``actuation`` applied to ``history``
    (one increment from its state, Newton started from ``initial`` when given, else from that
    state; None: from rest, or from ``initial`` taken as the start, the load stepped in the solve's
    load stages, each committed). ``result.friction`` is the state after it."""
    if history is not None:
        start = history.state
        initial = initial if initial is not None else history.state
    else:
        start = initial if initial is not None else trunk.rest_state
    session = Session(trunk, start, history)
    return newton.solve(trunk, loads, actuation, initial, friction=session, **options)
