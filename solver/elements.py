"""Force elements of the trunk: compliance links, cable pieces, gravity.

Each pair element returns the gradient of its potential with respect to the 12
DoFs of its two frames ``[dx_a, dφ_a, dx_b, dφ_b]`` (world translation and world
rotation vector of each frame, rotation about the frame's own origin). The functions
use complex-analytic operations only, so :func:`pair_tangent` obtains the exact
tangent by the complex-step derivative of the gradient (Squire & Trapp 1998; Martins
et al. 2003): no subtractive cancellation, machine-precision consistent tangent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.rotations import cross, dot, hat, matvec, qconj, qlog, qmatrix, qmul, qrotate, se3_coefficients

COMPLEX_STEP = 1e-30
_UNIT_Q = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass
class LinkGeometry:
    """Relative pose of a link's frames: ``R_a``, ``p = R_aᵀ(x_b − x_a)``, ``φ = log(R_aᵀR_b)``,
    ``ρ = J⁻¹(φ) p`` and the SE(3) series coefficients (c2, a1, a2, a3)."""

    Ra: np.ndarray
    p: np.ndarray
    phi: np.ndarray
    rho: np.ndarray
    coef: np.ndarray

    @classmethod
    def of(cls, qa, xa, qb, xb) -> "LinkGeometry":
        Ra = qmatrix(qa)
        p = matvec(np.swapaxes(Ra, -1, -2), xb - xa)
        phi = qlog(qmul(qconj(qa), qb))
        coef = se3_coefficients(dot(phi, phi))
        c2 = coef[..., :1]
        phi_p = cross(phi, p)
        rho = p - 0.5 * phi_p + c2 * cross(phi, phi_p)
        return cls(Ra, p, phi, rho, coef)

    def twist(self) -> np.ndarray:
        """``ξ = log(T_a⁻¹ T_b) = [ρ; φ]``."""
        return np.concatenate([self.rho, self.phi], -1)

    def transport(self, w: np.ndarray) -> np.ndarray:
        """``y = J_l⁻ᵀ(ξ) w``: a strain-space wrench as the dual of left twists in ``a``.

        With ``J_l⁻¹ = [[J⁻¹, −J⁻¹QJ⁻¹], [0, J⁻¹]]`` (Barfoot eq. 7.95):
        ``y_f = J⁻ᵀ w_f``, ``y_m = J⁻ᵀ (w_m − Qᵀ y_f)``; ``Qᵀu`` is written with cross
        products only (no 3×3 matrices), which is what keeps the hot path cheap.
        """
        phi, rho = self.phi, self.rho
        if w.ndim > phi.ndim:                       # several wrenches per link (…, k, 6)
            phi, rho = phi[..., None, :], rho[..., None, :]
            coef = self.coef[..., None, :]
        else:
            coef = self.coef
        c2, a1, a2, a3 = (coef[..., k:k + 1] for k in range(4))

        def inverse_jacobian_transpose(u):        # J⁻ᵀ u = u + ½ φ×u + c2 φ×(φ×u)
            fu = cross(phi, u)
            return u + 0.5 * fu + c2 * cross(phi, fu)

        yf = inverse_jacobian_transpose(w[..., :3])
        A = cross(phi, yf)
        B = cross(rho, yf)
        C = cross(phi, A)
        D = cross(rho, A)
        fB, fD, rC = cross(phi, B), cross(phi, D), cross(rho, C)
        QTu = (-0.5 * B + a1 * (D + fB - fD) + a2 * (3.0 * fD - rC - cross(phi, fB))
               + a3 * (cross(phi, fD) + cross(phi, rC)))
        ym = inverse_jacobian_transpose(w[..., 3:] - QTu)
        return np.concatenate([yf, ym], -1)

    def strain_change(self, zeta: np.ndarray) -> np.ndarray:
        """``J_l⁻¹(ξ) ζ``: the change of the twist under a left twist ``ζ`` in ``a``'s frame,
        ``[J⁻¹(ζ_ρ − Q J⁻¹ζ_φ); J⁻¹ζ_φ]`` with ``Qu`` in cross products (Barfoot eq. 7.86)."""
        phi, rho = self.phi, self.rho
        c2, a1, a2, a3 = (self.coef[..., k:k + 1] for k in range(4))

        def inverse_jacobian(v):                   # J⁻¹ v = v − ½ φ×v + c2 φ×(φ×v)
            fv = cross(phi, v)
            return v - 0.5 * fv + c2 * cross(phi, fv)

        u = inverse_jacobian(zeta[..., 3:])
        A = cross(phi, u)
        B = cross(rho, u)
        D = cross(rho, A)
        E = cross(phi, B)
        F = cross(phi, D)
        H = cross(rho, cross(phi, A))
        Qu = (0.5 * B + a1 * (E + D + F) + a2 * (cross(phi, E) + H - 3.0 * F)
              + a3 * (cross(phi, H) + cross(phi, F)))
        return np.concatenate([inverse_jacobian(zeta[..., :3] - Qu), u], -1)

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
    return geometry.generalised_force(geometry.transport(w)), 0.5 * dot(e, w)


def cable_gradient(qa, xa, qb, xb, hole_a, hole_b, tension):
    """Gradient and energy ``τ |P_b − P_a|`` of one cable piece between two holes."""
    sa = qrotate(qa, hole_a)
    sb = qrotate(qb, hole_b)
    d = (xb + sb) - (xa + sa)
    length = np.sqrt(dot(d, d))
    u = d / length[..., None]
    t = tension[..., None]
    grad = np.concatenate([-t * u, -t * cross(sa, u), t * u, t * cross(sb, u)], -1)
    return grad, tension * length


def pair_tangent(gradient, qa, xa, qb, xb, *args):
    """Gradient ``(n, 12)``, energy ``(n,)`` and exact tangent ``(n, 12, 12)`` of an objective
    pair element (its potential is invariant under rigid motions of both frames).

    The columns for frame ``b`` are complex-step derivatives, ``Im g(q + i h e_k) / h``, along
    the chart Newton updates in (x + dx, exp(dφ) R): exact to rounding, no cancellation. The
    columns for frame ``a`` then follow from objectivity, at no cost: a common translation
    leaves ``g`` unchanged, so ``H_xa = −H_xb``; a common rotation ψ about the world origin
    (``dx = ψ × x``, ``dφ = ψ``) rotates every 3-block of ``g``, so
    ``H_φa = −ĝ + H_xb (x_b − x_a)^ − H_φb``.
    """
    n = qb.shape[0]
    h = COMPLEX_STEP
    qbc = np.broadcast_to(qb, (6, n, 4)).astype(complex)
    xbc = np.broadcast_to(xb, (6, n, 3)).astype(complex)
    xbc[:3] += 1j * h * np.eye(3)[:, None, :]
    qbc[3:] += 0.5j * h * qmul(_UNIT_Q[:, None, :], qb[None])
    g, energy = gradient(qa, xa, qbc, xbc, *args)
    gradient_real = g[0].real
    tangent = np.empty((n, 12, 12))
    H_b = np.moveaxis(g.imag, 0, -1) / h                     # (n, 12, 6): columns dx_b, dφ_b
    tangent[:, :, 6:] = H_b
    tangent[:, :, :3] = -H_b[:, :, :3]
    rotation = -hat(gradient_real.reshape(n, 4, 3)).reshape(n, 12, 3)
    tangent[:, :, 3:6] = rotation + H_b[:, :, :3] @ hat(xb - xa) - H_b[:, :, 3:]
    return gradient_real, energy[0].real, tangent
