"""Quaternions and SE(3) logarithms, accurate near zero and usable with complex numbers.

Every function here is written with complex-analytic operations only (no ``abs``,
``conj`` or ``arctan2`` on the data), so that the complex-step reference of the link
potential (:mod:`solver.elements`, which the tests compare the model's closed-form kernel
in :mod:`solver.links` with) is exact to machine precision. Branches are chosen on real
parts; near-zero angles use Taylor series in θ² (even functions), which keeps the
derivative correct at θ = 0.

Functions are written to issue as few numpy calls as possible (index tables and small
constant matrices instead of element-by-element formulas), because for trunks of tens of
frames the cost is the number of numpy calls, not the arithmetic.

Conventions: quaternions ``[w, x, y, z]``, unit norm; rotation vectors in radians;
twists ``ξ = [ρ; φ]`` (translation first) with ``T = exp(ξ^)``, as in Barfoot,
*State Estimation for Robotics* (2017), §7.1.
"""

from __future__ import annotations

import numpy as np

_HAT_TABLE = np.zeros((3, 9))        # hat(v).ravel() = v @ _HAT_TABLE
_HAT_TABLE[[2, 1, 2, 0, 1, 0], [1, 2, 3, 5, 6, 7]] = [-1.0, 1.0, 1.0, -1.0, -1.0, 1.0]
_C1, _C2 = np.array([1, 2, 0]), np.array([2, 0, 1])
_QL_INDEX = np.array([0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0])
_QL_SIGN = np.array([1.0, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1])
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _rotation_matrix_table():
    """M (16×9) with R(q).ravel() = (q ⊗ q).ravel() @ M for unit q (homogeneous form)."""
    M = np.zeros((4, 4, 3, 3))
    w, x, y, z = range(4)
    def put(i, j, r, c, v):
        M[i, j, r, c] += v
    for (i, v) in ((w, 1), (x, 1), (y, -1), (z, -1)):
        put(i, i, 0, 0, v)
    for (i, v) in ((w, 1), (x, -1), (y, 1), (z, -1)):
        put(i, i, 1, 1, v)
    for (i, v) in ((w, 1), (x, -1), (y, -1), (z, 1)):
        put(i, i, 2, 2, v)
    for (a, b, r, c, v) in ((x, y, 0, 1, 2), (w, z, 0, 1, -2), (x, z, 0, 2, 2), (w, y, 0, 2, 2),
                            (x, y, 1, 0, 2), (w, z, 1, 0, 2), (y, z, 1, 2, 2), (w, x, 1, 2, -2),
                            (x, z, 2, 0, 2), (w, y, 2, 0, -2), (y, z, 2, 1, 2), (w, x, 2, 1, 2)):
        put(a, b, r, c, v)
    return M.reshape(16, 9)


_R_TABLE = _rotation_matrix_table()
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


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of vectors ``(..., 3) -> (..., 3, 3)`` (one small matrix product)."""
    return (v.reshape(-1, 3) @ _HAT_TABLE).reshape(v.shape[:-1] + (3, 3))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of ``(..., 3)`` arrays (complex-safe, no conjugation)."""
    return a[..., _C1] * b[..., _C2] - a[..., _C2] * b[..., _C1]


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Bilinear dot product over the last axis (no conjugation)."""
    return (a * b).sum(-1)


def matvec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (A @ v[..., None])[..., 0]


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` quaternions."""
    left = (p[..., _QL_INDEX] * _QL_SIGN).reshape(p.shape[:-1] + (4, 4))
    return matvec(left, q)


def qconj(q: np.ndarray) -> np.ndarray:
    """Quaternion conjugate (the inverse of a unit quaternion)."""
    return q * _CONJ


def qmatrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    outer = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    return (outer @ _R_TABLE).reshape(q.shape[:-1] + (3, 3))


def qrotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` by unit quaternions ``q`` (broadcasting)."""
    return matvec(qmatrix(q), v)


def qexp(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion of a rotation vector (real input)."""
    theta2 = dot(phi, phi)
    small = theta2 < _LOG_SERIES_THRESHOLD
    theta = np.sqrt(np.where(small, 1.0, theta2))
    half_sinc = np.where(small, 0.5 - theta2 / 48.0 + theta2 ** 2 / 3840.0, np.sin(0.5 * theta) / theta)
    cos_half = np.where(small, 1.0 - theta2 / 8.0 + theta2 ** 2 / 384.0, np.cos(0.5 * theta))
    return np.concatenate([cos_half[..., None], half_sinc[..., None] * phi], -1)


def qlog(q: np.ndarray) -> np.ndarray:
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


def se3_log(q: np.ndarray, p: np.ndarray):
    """Twist ``ξ = [ρ; φ]`` of the transform (rotation ``q``, translation ``p``) and the
    inverse left Jacobian ``J_l⁻¹(ξ)`` (6×6): ``log(exp(ζ^) T) = ξ + J_l⁻¹ ζ + O(ζ²)``."""
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


def se3_exp(xi: np.ndarray):
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
