"""Complex-step reference of the link and cable potentials: an implementation independent of the
runtime kernels (:mod:`vertebra.core.lie`, :mod:`vertebra.solver.links`,
:class:`vertebra.solver.cables.CablePieces`), written with complex-analytic operations only (no
``abs``, ``conj`` or ``arctan2`` on the data) and element-by-element formulas instead of the
runtime's tables.

:func:`pair_tangent` obtains the exact tangent of a pair element by the complex-step derivative
of its gradient (Squire & Trapp 1998; Martins et al. 2003): no subtractive cancellation, a
consistent tangent to machine precision. The SE(3) logarithm follows Barfoot, *State Estimation
for Robotics* (2017), eqs. 7.86 and 7.95, with Taylor series in θ² near zero angle (even
functions, so the derivative stays right at θ = 0).

Benchmarks import it by putting the ``tests`` folder on ``sys.path``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass

import numpy as np

COMPLEX_STEP = 1e-30
CHUNK = 1024          # elements per complex-step batch (keeps the complex temporaries in cache)
_SERIES_POWERS = 5
# Taylor coefficients in θ² of c2, a1, a2, a3 (columns), powers θ⁰…θ⁸ (rows)
_SE3_SERIES = np.array([
    [1 / 12, 1 / 6, 1 / 24, 1 / 120],
    [1 / 720, -1 / 120, -1 / 720, -1 / 2520],
    [1 / 30240, 1 / 5040, 1 / 40320, 1 / 120960],
    [1 / 1209600, -1 / 362880, -1 / 3628800, -1 / 9979200],
    [1 / 47900160, 1 / 39916800, 1 / 479001600, 1 / 1245404160],
])
_SE3_SERIES_THRESHOLD = 1e-2    # θ² below which the series (next term < 1e-19 relative) is used
_LOG_SERIES_THRESHOLD = 1e-4    # s² = sin²(θ/2) below which qlog uses its series


# ----------------------------------------------------------------------------- algebra
def dot(a, b):
    """Bilinear dot product over the last axis (no conjugation)."""
    return (a * b).sum(-1)


def cross(a, b):
    """Cross product of ``(..., 3)`` arrays (no conjugation)."""
    a1, a2, a3 = a[..., 0], a[..., 1], a[..., 2]
    b1, b2, b3 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1], -1)


def hat(v):
    """Skew-symmetric matrices ``(..., 3, 3)``."""
    zero = np.zeros_like(v[..., 0])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                     np.stack([-y, x, zero], -1)], -2)


def matvec(A, v):
    return (A @ v[..., None])[..., 0]


def qmul(p, q):
    """Hamilton product ``p ⊗ q``."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    return np.concatenate([pw * qw - dot(pv, qv)[..., None], pw * qv + qw * pv + cross(pv, qv)], -1)


def qconj(q):
    return np.concatenate([q[..., :1], -q[..., 1:]], -1)


def qmatrix(q):
    """Rotation matrices of unit quaternions: ``R = (w² − v·v) I + 2 v vᵀ + 2 w v̂``."""
    w, v = q[..., 0, None, None], q[..., 1:]
    return ((w * w - dot(v, v)[..., None, None]) * np.eye(3) + 2.0 * v[..., :, None] * v[..., None, :]
            + 2.0 * w * hat(v))


def qrotate(q, v):
    return matvec(qmatrix(q), v)


def qexp(phi):
    """Unit quaternion of a rotation vector (real input)."""
    theta2 = dot(phi, phi)
    small = theta2 < _LOG_SERIES_THRESHOLD
    theta = np.sqrt(np.where(small, 1.0, theta2))
    half_sinc = np.where(small, 0.5 - theta2 / 48.0 + theta2 ** 2 / 3840.0, np.sin(0.5 * theta) / theta)
    cos_half = np.where(small, 1.0 - theta2 / 8.0 + theta2 ** 2 / 384.0, np.cos(0.5 * theta))
    return np.concatenate([cos_half[..., None], half_sinc[..., None] * phi], -1)


def qlog(q):
    """Rotation vector of a unit quaternion, angle in [0, π] (complex-analytic)."""
    q = q * np.where(np.real(q[..., :1]) < 0.0, -1.0, 1.0)
    w, v = q[..., 0], q[..., 1:]
    s2 = dot(v, v)
    small = np.real(s2) < _LOG_SERIES_THRESHOLD
    r2 = s2 / (w * w)
    # 2·atan(s/w)/s as a series in s²/w² (here w > 0.99995, next term < 1e-20)
    series = (2.0 / w) * (1.0 + r2 * (-1 / 3 + r2 * (1 / 5 + r2 * (-1 / 7 + r2 / 9))))
    s = np.sqrt(np.where(small, 1.0, s2))
    # atan2(s, w) for w ≥ 0, s > 0 with complex-analytic pieces
    angle = np.where(np.real(w) >= np.real(s), np.arctan(s / w), 0.5 * np.pi - np.arctan(w / s))
    return np.where(small, series, 2.0 * angle / s)[..., None] * v


def se3_coefficients(theta2):
    """c2 of J⁻¹ = I − ½φ^ + c2 φ^² and a1, a2, a3 of Barfoot's Q (eq. 7.86), ``(..., 4)``."""
    small = np.real(theta2) < _SE3_SERIES_THRESHOLD
    t2 = np.where(small, 1.0, theta2)
    t = np.sqrt(t2)
    s, c = np.sin(t), np.cos(t)
    exact = np.stack([(1.0 - 0.5 * t * s / (1.0 - c)) / t2, (t - s) / (t2 * t),
                      (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2), (2.0 * t - 3.0 * s + t * c) / (2.0 * t2 * t2 * t)], -1)
    powers = theta2[..., None] ** np.arange(_SERIES_POWERS)
    return np.where(small[..., None], powers @ _SE3_SERIES, exact)


def se3_log(q, p):
    """Twist ``ξ = [ρ; φ]`` of the transform (rotation ``q``, translation ``p``) and the
    inverse left Jacobian ``J_l⁻¹(ξ)`` (Barfoot eq. 7.95)."""
    phi = qlog(q)
    P = hat(phi)
    P2 = P @ P
    coef = se3_coefficients(dot(phi, phi))[..., None, None, :]
    Jinv = np.eye(3) - 0.5 * P + coef[..., 0] * P2
    rho = matvec(Jinv, p)
    Rh = hat(rho)
    X, Y = P @ Rh, Rh @ P
    Z = X @ P
    Q = (0.5 * Rh + coef[..., 1] * (X + Y + Z) + coef[..., 2] * (P @ X + Y @ P - 3.0 * Z)
         + coef[..., 3] * (Z @ P + P @ Z))
    Jl_inv = np.zeros(phi.shape[:-1] + (6, 6), dtype=np.result_type(q, p))
    Jl_inv[..., :3, :3] = Jinv
    Jl_inv[..., 3:, 3:] = Jinv
    Jl_inv[..., :3, 3:] = -Jinv @ Q @ Jinv
    return np.concatenate([rho, phi], -1), Jl_inv


def se3_exp(xi):
    """Rotation quaternion and translation of ``exp(ξ^)`` (real input)."""
    rho, phi = xi[..., :3], xi[..., 3:]
    theta2 = dot(phi, phi)
    small = theta2 < _LOG_SERIES_THRESHOLD
    t2 = np.where(small, 1.0, theta2)
    t = np.sqrt(t2)
    b = np.where(small, 0.5 - theta2 / 24 + theta2 ** 2 / 720, (1 - np.cos(t)) / t2)
    c = np.where(small, 1 / 6 - theta2 / 120 + theta2 ** 2 / 5040, (t - np.sin(t)) / (t2 * t))
    P = hat(phi)
    V = np.eye(3) + b[..., None, None] * P + c[..., None, None] * (P @ P)
    return qexp(phi), matvec(V, rho)


# ----------------------------------------------------------------------------- elements
@dataclass
class LinkGeometry:
    """Relative pose of a link's frames: ``R_a``, ``p = R_aᵀ(x_b − x_a)``, ``φ = log(R_aᵀR_b)``,
    ``ρ = J⁻¹(φ) p``, the skew matrices ``Φ = φ^``, ``Ρ = ρ^``, ``J⁻¹(φ)`` and the SE(3)
    series coefficients (c2, a1, a2, a3)."""

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
        Jinv = np.eye(3) - 0.5 * Phi + coef[..., 0, None, None] * (Phi @ Phi)
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

    def transport(self, w):
        """``y = J_l⁻ᵀ(ξ) w``: ``y_f = J⁻ᵀ w_f``, ``y_m = J⁻ᵀ (w_m − Qᵀ y_f)`` with ``Qᵀu``
        expanded term by term (``(φ^ρ^)ᵀu = ρ×(φ×u)`` and so on)."""
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

    def generalised_force(self, y):
        """Generalised force on ``[a, b]`` of a wrench ``y`` (dual of left twists in a):
        ``g_a = −[R_a y_f; R_a y_m]``, ``g_b = [R_a y_f; R_a (y_m − p × y_f)]``."""
        Ra, p = self.Ra, self.p
        if y.ndim > p.ndim:
            Ra, p = Ra[..., None, :, :], p[..., None, :]
        yf, ym = y[..., :3], y[..., 3:]
        world = Ra @ np.stack([yf, ym, ym - cross(p, yf)], -1)     # columns: force, moment at a, at b
        force, moment_a, moment_b = world[..., 0], world[..., 1], world[..., 2]
        return np.concatenate([-force, -moment_a, force, moment_b], -1)


def link_gradient(qa, xa, qb, xb, stiffness, xi_rest):
    """Gradient (…, 12) and energy of the quadratic link ``½ eᵀ K e`` with
    ``e = log(T_a⁻¹ T_b) − ξ_rest``; perturbations enter as left twists in ``a``'s frame:
    ``ζ_a = −[R_aᵀ dx_a; R_aᵀ dφ_a]``, ``ζ_b = [R_aᵀ dx_b + p × R_aᵀ dφ_b; R_aᵀ dφ_b]``."""
    geometry = LinkGeometry.of(qa, xa, qb, xb)
    e = geometry.twist() - xi_rest
    w = matvec(stiffness, e)
    return geometry.generalised_force(geometry.transport(w)), 0.5 * dot(e, w), geometry


def polynomial_link_gradient(qa, xa, qb, xb, exponents, coefficients, scales, stiffness, xi_rest, shift):
    """Gradient (…, 12) and energy of a link that stores a polynomial energy of its strain
    ``s = log(T_a⁻¹ T_b) − ξ_rest``: ``ψ = ½ (s − shift)ᵀ K (s − shift) + Σ_α c_α (s / scales)^α``
    (a fitted energy at fixed pressures: ``shift = S p``, the pressure factors multiplied into
    the coefficients). ``exponents`` (m, 6), ``coefficients`` (m,), ``scales`` (6,); term by term,
    complex-analytic."""
    geometry = LinkGeometry.of(qa, xa, qb, xb)
    s = geometry.twist() - xi_rest
    u = s / scales
    w = matvec(stiffness, s - shift)
    energy = 0.5 * dot(s - shift, w)
    for alpha, c in zip(exponents, coefficients):
        energy = energy + c * np.prod(u ** alpha, axis=-1)
        for j in np.flatnonzero(alpha):
            lowered = alpha.copy()
            lowered[j] -= 1
            w = w + (c * alpha[j] / scales[j]) * np.prod(u ** lowered, axis=-1)[..., None] * np.eye(6)[j]
    return geometry.generalised_force(geometry.transport(w)), energy, geometry


def cable_gradient(qa, xa, qb, xb, hole_a, hole_b, tension):
    """Gradient and energy ``τ |P_b − P_a|`` of cable pieces between holes ``r`` of two frames."""
    sa = qrotate(qa, hole_a)
    sb = qrotate(qb, hole_b)
    d = (xb + sb) - (xa + sa)
    length = np.sqrt(dot(d, d))
    u = d / length[..., None]
    t = tension[..., None]
    return np.concatenate([-t * u, -t * cross(sa, u), t * u, t * cross(sb, u)], -1), tension * length


_UNIT_Q = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def pair_tangent(gradient, qa, xa, qb, xb, *args):
    """Gradient ``(n, 12)``, energy ``(n,)`` and exact tangent ``(n, 12, 12)`` of an objective
    pair element (its potential is invariant under rigid motions of both frames); when the
    element's gradient function also returns its geometry, the real geometry comes fourth.

    The columns for frame ``b`` are complex-step derivatives, ``Im g(q + i h e_k) / h``, along
    the chart Newton updates in (x + dx, exp(dφ) R). The columns for frame ``a`` follow from
    objectivity: a common translation leaves ``g`` unchanged, so ``H_xa = −H_xb``; a common
    rotation ψ about the world origin (``dx = ψ × x``, ``dφ = ψ``) rotates every 3-block of
    ``g``, so ``H_φa = −ĝ + H_xb (x_b − x_a)^ − H_φb``.
    """
    n = qb.shape[0]
    if n > CHUNK:
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
