"""Force elements of the trunk: cable pieces (used by the model) and the complex-step
reference of the link and cable potentials (used by the tests).

Each pair element returns the gradient of its potential with respect to the 12
DoFs of its two frames ``[dx_a, dφ_a, dx_b, dφ_b]`` (world translation and world
rotation vector of each frame, rotation about the frame's own origin).

:class:`CablePieces` is the model's closed-form cable kernel. :func:`link_gradient`,
:func:`cable_gradient` and :func:`pair_tangent` are an independent implementation written
with complex-analytic operations only, so that :func:`pair_tangent` obtains the exact
tangent by the complex-step derivative of the gradient (Squire & Trapp 1998; Martins
et al. 2003): no subtractive cancellation, machine-precision consistent tangent. The
model's closed-form link kernel (:mod:`solver.links`) is tested against it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass

import numpy as np

from vertebra.solver.rotations import _HAT_TABLE, cross, dot, hat, matvec, qconj, qlog, qmatrix, qmul, qrotate, se3_coefficients

COMPLEX_STEP = 1e-30
CHUNK = 1024          # elements per complex-step batch
_UNIT_Q = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass
class LinkGeometry:
    """Relative pose of a link's frames: ``R_a``, ``p = R_aᵀ(x_b − x_a)``, ``φ = log(R_aᵀR_b)``,
    ``ρ = J⁻¹(φ) p``, the skew matrices ``Φ = φ^``, ``Ρ = ρ^``, ``J⁻¹(φ)`` and the SE(3)
    series coefficients (c2, a1, a2, a3).

    Cross products with φ and ρ are applied as products with the precomputed ``Φ`` and ``Ρ``:
    for the small batches of a trunk that is ~3× cheaper in numpy than element-wise crosses.
    """

    Ra: np.ndarray
    p: np.ndarray
    phi: np.ndarray
    rho: np.ndarray
    coef: np.ndarray
    Phi: np.ndarray
    Rho: np.ndarray
    Jinv: np.ndarray

    @classmethod
    def of(cls, qa, xa, qb, xb) -> "LinkGeometry":
        Ra = qmatrix(qa)
        p = matvec(np.swapaxes(Ra, -1, -2), xb - xa)
        phi = qlog(qmul(qconj(qa), qb))
        coef = se3_coefficients(dot(phi, phi))
        Phi = hat(phi)
        Jinv = np.eye(3) - 0.5 * Phi + coef[..., 0, None, None] * (Phi @ Phi)   # J⁻¹ = I − ½Φ + c2 Φ²
        rho = matvec(Jinv, p)
        return cls(Ra, p, phi, rho, coef, Phi, hat(rho), Jinv)

    def unperturbed(self) -> "LinkGeometry":
        """From a geometry computed on complex-step copies (leading axis = direction), the real
        geometry of the unperturbed state: direction 0's real part (exact: the perturbation
        enters at O(h²) = 1e-60). Fields that depend on frame ``a`` only were never copied."""
        batch = self.p.ndim - 1
        core = {"Ra": 2, "p": 1, "phi": 1, "rho": 1, "coef": 1, "Phi": 2, "Rho": 2, "Jinv": 2}
        return LinkGeometry(**{name: np.real(value[0] if value.ndim - core[name] == batch else value)
                               for name, value in ((n, getattr(self, n)) for n in core)})

    def twist(self) -> np.ndarray:
        """``ξ = log(T_a⁻¹ T_b) = [ρ; φ]``."""
        return np.concatenate([self.rho, self.phi], -1)

    def _expanded(self, v):
        """Broadcast the per-link matrices over an extra axis when ``v`` holds several vectors."""
        Phi, Rho, Jinv, coef = self.Phi, self.Rho, self.Jinv, self.coef
        if v.ndim > self.phi.ndim:
            Phi, Rho, Jinv, coef = Phi[..., None, :, :], Rho[..., None, :, :], Jinv[..., None, :, :], coef[..., None, :]
        return Phi, Rho, Jinv, tuple(coef[..., k:k + 1] for k in range(4))

    def transport(self, w: np.ndarray) -> np.ndarray:
        """``y = J_l⁻ᵀ(ξ) w``: a strain-space wrench as the dual of left twists in ``a``.

        With ``J_l⁻¹ = [[J⁻¹, −J⁻¹QJ⁻¹], [0, J⁻¹]]`` (Barfoot eq. 7.95):
        ``y_f = J⁻ᵀ w_f``, ``y_m = J⁻ᵀ (w_m − Qᵀ y_f)``, with ``Qᵀu`` expanded term by term
        (``(φ^ρ^)ᵀu = ρ×(φ×u)`` and so on) so that no 3×3 matrix product is needed.
        """
        Phi, Rho, Jinv, (_, a1, a2, a3) = self._expanded(w)
        JinvT = np.swapaxes(Jinv, -1, -2)
        yf = matvec(JinvT, w[..., :3])
        A = matvec(Phi, yf)
        B = matvec(Rho, yf)
        C = matvec(Phi, A)
        D = matvec(Rho, A)
        fB, fD, rC = matvec(Phi, B), matvec(Phi, D), matvec(Rho, C)
        QTu = (-0.5 * B + a1 * (D + fB - fD) + a2 * (3.0 * fD - rC - matvec(Phi, fB))
               + a3 * (matvec(Phi, fD) + matvec(Phi, rC)))
        ym = matvec(JinvT, w[..., 3:] - QTu)
        return np.concatenate([yf, ym], -1)

    def strain_change(self, zeta: np.ndarray) -> np.ndarray:
        """``J_l⁻¹(ξ) ζ``: the change of the twist under a left twist ``ζ`` in ``a``'s frame,
        ``[J⁻¹(ζ_ρ − Q J⁻¹ζ_φ); J⁻¹ζ_φ]`` with ``Qu`` expanded term by term (Barfoot eq. 7.86)."""
        Phi, Rho, Jinv, (_, a1, a2, a3) = self._expanded(zeta)
        u = matvec(Jinv, zeta[..., 3:])
        A = matvec(Phi, u)
        B = matvec(Rho, u)
        D = matvec(Rho, A)
        E = matvec(Phi, B)
        F = matvec(Phi, D)
        H = matvec(Rho, matvec(Phi, A))
        Qu = (0.5 * B + a1 * (E + D + F) + a2 * (matvec(Phi, E) + H - 3.0 * F)
              + a3 * (matvec(Phi, H) + matvec(Phi, F)))
        return np.concatenate([matvec(Jinv, zeta[..., :3] - Qu), u], -1)

    def generalised_force(self, y: np.ndarray) -> np.ndarray:
        """Generalised force on ``[a, b]`` of a wrench ``y`` (dual of left twists in a) — the
        transport of paper eqs. 5–7: ``g_a = −[R_a y_f; R_a y_m]``, ``g_b = [R_a y_f; R_a (y_m − p × y_f)]``."""
        Ra, p = self.Ra, self.p
        if y.ndim > p.ndim:
            Ra, p = Ra[..., None, :, :], p[..., None, :]
        yf, ym = y[..., :3], y[..., 3:]
        world = Ra @ np.stack([yf, ym, ym - cross(p, yf)], -1)     # columns: force, moment at a, at b
        force, moment_a, moment_b = world[..., 0], world[..., 1], world[..., 2]
        return np.concatenate([-force, -moment_a, force, moment_b], -1)


def link_gradient(qa, xa, qb, xb, stiffness, xi_rest):
    """Gradient (…, 12) and energy of the constant-strain link ``½ eᵀ K e`` with
    ``e = log(T_a⁻¹ T_b) − ξ_rest`` (FIELD-NOTES; paper eq. 4 with a co-rotated strain).

    Perturbations enter as left twists in ``a``'s frame: ``ζ_a = −[R_aᵀ dx_a; R_aᵀ dφ_a]``,
    ``ζ_b = [R_aᵀ dx_b + p × R_aᵀ dφ_b; R_aᵀ dφ_b]``, and ``de = J_l⁻¹ ζ``.
    """
    geometry = LinkGeometry.of(qa, xa, qb, xb)
    e = geometry.twist() - xi_rest
    w = matvec(stiffness, e)
    return geometry.generalised_force(geometry.transport(w)), 0.5 * dot(e, w), geometry


def _cable_piece(qa, xa, qb, xb, hole_a, hole_b, tension):
    """Hole offsets ``s = R r``, unit direction ``u``, length and gradient of ``τ |P_b − P_a|``."""
    sa = qrotate(qa, hole_a)
    sb = qrotate(qb, hole_b)
    d = (xb + sb) - (xa + sa)
    length = np.sqrt(dot(d, d))
    u = d / length[..., None]
    t = tension[..., None]
    gradient = np.concatenate([-t * u, -t * cross(sa, u), t * u, t * cross(sb, u)], -1)
    return sa, sb, u, length, gradient


def cable_gradient(qa, xa, qb, xb, hole_a, hole_b, tension):
    """Gradient and energy ``τ |P_b − P_a|`` of one cable piece between two holes."""
    *_, length, gradient = _cable_piece(qa, xa, qb, xb, hole_a, hole_b, tension)
    return gradient, tension * length


_C_CONST = np.zeros((12, 3))
_C_CONST[:3], _C_CONST[6:9] = -np.eye(3), np.eye(3)
_C_TABLE = np.zeros((6, 12, 3))
_C_TABLE[:3, 3:6] = -_HAT_TABLE.reshape(3, 3, 3)        # −ŝ_a
_C_TABLE[3:, 9:] = _HAT_TABLE.reshape(3, 3, 3)          # ŝ_b
_C_TABLE = _C_TABLE.reshape(6, 36)
_DIFFERENCE = np.concatenate([-np.eye(3), np.eye(3)])   # [P_a; P_b] → P_b − P_a
_EYE3 = np.eye(3)


@dataclass
class CablePieces:
    """Kinematics of cable pieces between holes ``r_a``, ``r_b`` of two frames (real input).

    With ``s = R r``, ``d = P_b − P_a``, ``u = d/|d|`` and ``C = [−I; −ŝ_a; I; ŝ_b]`` (12×3), the
    change of ``d`` under frame increments is ``Cᵀ dq``, so the gradient of the length is
    ``C u`` and the tangent of ``τ|d|`` is ``τ (C Π Cᵀ − (û ŝ_a on dφ_a) + (û ŝ_b on dφ_b))``,
    ``Π = (I − uuᵀ)/|d|``: one evaluation serves the forces, the tangent, the actuator Jacobian
    (unit tension) and the cable lengths."""

    C: np.ndarray          # (m, 12, 3)
    u: np.ndarray          # (m, 3)
    length: np.ndarray     # (m,)
    unit: np.ndarray       # (m, 12) gradient of the length

    @classmethod
    def of(cls, Ra, xa, Rb, xb, hole_a, hole_b) -> "CablePieces":
        m = xa.shape[0]
        return cls.of_pairs(np.stack([Ra, Rb], 1).reshape(2 * m, 3, 3), np.stack([xa, xb], 1).reshape(2 * m, 3),
                            np.stack([hole_a, hole_b], 1).reshape(2 * m, 3, 1))

    @classmethod
    def of_pairs(cls, R, x, holes) -> "CablePieces":
        """From the rotations (2m, 3, 3), positions (2m, 3) and hole offsets (2m, 3, 1) of the two
        ends of every piece, interleaved (a₀, b₀, a₁, b₁, …)."""
        m = x.shape[0] // 2
        offsets = (R @ holes).reshape(m, 6)                   # [s_a, s_b]
        d = (x.reshape(m, 6) + offsets) @ _DIFFERENCE         # P_b − P_a
        length = np.sqrt((d[:, None, :] @ d[:, :, None])[:, 0, 0])
        u = d / length[:, None]
        C = (offsets @ _C_TABLE).reshape(m, 12, 3) + _C_CONST
        return cls(C, u, length, (C @ u[:, :, None])[:, :, 0])

    def tangent(self, tension: np.ndarray) -> np.ndarray:
        """Tangent (m, 12, 12) of ``τ |d|`` per piece."""
        u, C = self.u, self.C
        t = (tension / self.length)[:, None, None]
        H = (C @ (t * _EYE3 - t * (u[:, :, None] * u[:, None, :]))) @ C.mT
        U = (u @ _HAT_TABLE).reshape(-1, 3, 3) * tension[:, None, None]
        H[:, 3:6, 3:6] += U @ C[:, 3:6]                      # −τ û ŝ_a
        H[:, 9:, 9:] += U @ C[:, 9:]                         # +τ û ŝ_b
        return H


def cable_tangent(qa, xa, qb, xb, hole_a, hole_b, tension):
    """Gradient, energy and exact tangent of cable pieces in closed form (:class:`CablePieces`;
    the tests compare it with the complex step of :func:`cable_gradient`)."""
    pieces = CablePieces.of(qmatrix(qa), xa, qmatrix(qb), xb, hole_a, hole_b)
    return tension[:, None] * pieces.unit, tension * pieces.length, pieces.tangent(tension)


def pair_tangent(gradient, qa, xa, qb, xb, *args):
    """Gradient ``(n, 12)``, energy ``(n,)`` and exact tangent ``(n, 12, 12)`` of an objective
    pair element (its potential is invariant under rigid motions of both frames); when the
    element's gradient function also returns its geometry, the real geometry comes fourth.

    The columns for frame ``b`` are complex-step derivatives, ``Im g(q + i h e_k) / h``, along
    the chart Newton updates in (x + dx, exp(dφ) R): exact to rounding, no cancellation. The
    columns for frame ``a`` then follow from objectivity, at no cost: a common translation
    leaves ``g`` unchanged, so ``H_xa = −H_xb``; a common rotation ψ about the world origin
    (``dx = ψ × x``, ``dφ = ψ``) rotates every 3-block of ``g``, so
    ``H_φa = −ĝ + H_xb (x_b − x_a)^ − H_φb``.
    """
    n = qb.shape[0]
    if n > CHUNK:   # keep the complex temporaries in cache: measured ~linear again (bench_solver)
        parts = [pair_tangent(gradient, *(a[i:i + CHUNK] for a in (qa, xa, qb, xb, *args)))
                 for i in range(0, n, CHUNK)]
        return tuple(_concatenate([part[k] for part in parts]) for k in range(len(parts[0])))
    h = COMPLEX_STEP
    qbc = np.broadcast_to(qb, (6, n, 4)).astype(complex)
    xbc = np.broadcast_to(xb, (6, n, 3)).astype(complex)
    xbc[:3] += 1j * h * np.eye(3)[:, None, :]
    qbc[3:] += 0.5j * h * qmul(_UNIT_Q[:, None, :], qb[None])
    g, energy, *extra = gradient(qa, xa, qbc, xbc, *args)
    gradient_real = g[0].real
    tangent = np.empty((n, 12, 12))
    H_b = np.moveaxis(g.imag, 0, -1) / h                     # (n, 12, 6): columns dx_b, dφ_b
    tangent[:, :, 6:] = H_b
    tangent[:, :, :3] = -H_b[:, :, :3]
    rotation = -hat(gradient_real.reshape(n, 4, 3)).reshape(n, 12, 3)
    tangent[:, :, 3:6] = rotation + H_b[:, :, :3] @ hat(xb - xa) - H_b[:, :, 3:]
    if extra:   # the element's geometry at the unperturbed state: the real part of direction 0
        return gradient_real, energy[0].real, tangent, extra[0].unperturbed()
    return gradient_real, energy[0].real, tangent


def _concatenate(items):
    """Join per-chunk outputs along the element axis (arrays, or dataclasses of arrays)."""
    first = items[0]
    if is_dataclass(first):
        return type(first)(**{f.name: np.concatenate([getattr(item, f.name) for item in items])
                              for f in fields(first)})
    return np.concatenate([np.atleast_1d(item) for item in items])
