"""Rotations and rigid transforms, real-valued: quaternions, SO(3)/SE(3) exponential and logarithm.

Conventions: quaternions ``[w, x, y, z]``, unit norm; rotation vectors in radians; twists
``ξ = [ρ; φ]`` (translation first) with ``T = exp(ξ^)``, as in Barfoot, *State Estimation for
Robotics* (2017), §7.1; ``ad(ξ) = [[φ^, ρ^], [0, φ^]]``.

Every function of the rotation angle θ is a power series in ``t = θ²`` taken from one table, so
small angles need no special branch and a batch of links costs one matrix product:

* the **logarithm side** (:func:`coefficients`): the adjoint ``A = ad(ξ)`` satisfies
  ``A⁵ + 2θ²A³ + θ⁴A = 0``, so any analytic function of ``A`` is a polynomial of degree four
  in ``A`` with coefficients in θ². The inverse left Jacobian (the map from a perturbation
  ``ζ`` to ``dξ``, ``log(exp(ζ^)T) = ξ + J_l⁻¹ζ + O(ζ²)``) is

      J_l⁻¹(ξ) = I − ½A + c₂(θ²) A² + c₄(θ²) A⁴

  with ``c₂ = Σ (2−k) a_k θ^{2k−2}``, ``c₄ = Σ (1−k) a_k θ^{2k−4}`` and
  ``a_k = |B_2k|/(2k)! = 2ζ(2k)/(2π)^{2k}`` — the coefficients of ``1 − (θ/2)cot(θ/2)``
  (Hermite interpolation of ``(x/2)coth(x/2)`` on the spectrum {0, ±iθ, ±iθ}). The series
  converge for θ < 2π; at the largest angle a link can take (π) 40 terms leave < 1e-24, and
  fewer are summed when every angle of the batch is smaller. The table's other columns are the
  SO(3) ``J⁻¹ = I − ½Φ + cΦ²`` and the coefficients the link tangent needs
  (:func:`vertebra.solver.links.link_tangent`).
* the **exponential side** (:data:`EXP_TABLE`): ``cos(θ/2)``, ``sin(θ/2)/θ`` (the quaternion)
  and ``(1 − cos θ)/θ²``, ``(θ − sin θ)/θ³`` (the translation ``V ρ``), alternating series used
  up to θ = 4 rad and closed forms beyond.

Two forms of the same functions, batched over leading axes: the runtime's (quaternions ``q``
and translations, :func:`qexp`, :func:`qlog`, :func:`se3_exp`, :func:`se3_log` and the kernels
they are made of) and the matrix form the designer works in (rotation matrices ``R``:
:func:`so3_exp`, :func:`so3_expm1`, :func:`so3_log`, :func:`se3_exp_matrix`,
:func:`se3_log_matrix`, :func:`qfrom_matrix`), the latter written with the former's series. Also
:func:`hat`, :func:`ad` and the inverse left Jacobian of a twist
(:func:`se3_left_jacobian_inverse`).

Functions issue as few numpy calls as possible (index tables and small constant matrices
instead of element-by-element formulas): for trunks of tens of frames the cost is the number
of numpy calls, not the arithmetic.
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.core.errors import ConvergenceError
from scipy.special import zeta

# ----------------------------------------------------------------------------- tables
HAT_TABLE = np.zeros((3, 9))        # hat(v).ravel() = v @ HAT_TABLE
HAT_TABLE[[2, 1, 2, 0, 1, 0], [1, 2, 3, 5, 6, 7]] = [-1.0, 1.0, 1.0, -1.0, -1.0, 1.0]
_QL_INDEX = np.array([0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0])
_QL_SIGN = np.array([1.0, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1])
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _rotation_matrix_table() -> np.ndarray:
    """(16, 9): ``R(q).ravel() = (q ⊗ q).ravel() @ T`` for unit q (homogeneous form)."""
    M = np.zeros((4, 4, 3, 3))
    w, x, y, z = range(4)
    for i, v in ((w, 1), (x, 1), (y, -1), (z, -1)):
        M[i, i, 0, 0] += v
    for i, v in ((w, 1), (x, -1), (y, 1), (z, -1)):
        M[i, i, 1, 1] += v
    for i, v in ((w, 1), (x, -1), (y, -1), (z, 1)):
        M[i, i, 2, 2] += v
    for a, b, r, c, v in ((x, y, 0, 1, 2), (w, z, 0, 1, -2), (x, z, 0, 2, 2), (w, y, 0, 2, 2),
                          (x, y, 1, 0, 2), (w, z, 1, 0, 2), (y, z, 1, 2, 2), (w, x, 1, 2, -2),
                          (x, z, 2, 0, 2), (w, y, 2, 0, -2), (y, z, 2, 1, 2), (w, x, 2, 1, 2)):
        M[a, b, r, c] += v
    return M.reshape(16, 9)


R_TABLE = _rotation_matrix_table()


def _quaternion_table() -> np.ndarray:
    """(10, 16): ``([1, R.ravel()] @ T).reshape(4, 4)`` has rows ``4 q_i q`` (i = w, x, y, z) for
    the unit quaternion q of a rotation matrix R; row i is accurate when ``q_i`` is the largest."""
    T = np.zeros((10, 4, 4))
    entry = 1 + np.arange(9).reshape(3, 3)                                 # row of R[i, j] in T
    T[0] = np.eye(4)                                                       # 4q_i² = 1 ± R₀₀ ± R₁₁ ± R₂₂
    for i, signs in enumerate(((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))):
        T[entry.diagonal(), i, i] = signs
    # 4wx = R₂₁ − R₁₂, 4wy = R₀₂ − R₂₀, 4wz = R₁₀ − R₀₁; 4xy = R₀₁ + R₁₀, 4xz = R₀₂ + R₂₀, 4yz = R₁₂ + R₂₁
    for (a, b), (i, j), sign in (((0, 1), (2, 1), -1.0), ((0, 2), (0, 2), -1.0), ((0, 3), (1, 0), -1.0),
                                 ((1, 2), (0, 1), 1.0), ((1, 3), (0, 2), 1.0), ((2, 3), (1, 2), 1.0)):
        T[entry[i, j], a, b] = T[entry[i, j], b, a] = 1.0
        T[entry[j, i], a, b] = T[entry[j, i], b, a] = sign
    return T.reshape(10, 16)


Q_TABLE = _quaternion_table()
L_TABLE = np.zeros((4, 16))          # L(q).ravel() = q @ L_TABLE, with p ⊗ q = L(p) q
L_TABLE[_QL_INDEX, np.arange(16)] = _QL_SIGN


def block_table(blocks: dict) -> np.ndarray:
    """(6, 36) table T with ``M(v).ravel() = v @ T`` for a 6×6 matrix of hats of v's halves;
    ``blocks`` maps (row block, column block) to the half of v (0: first, 1: second)."""
    table = np.zeros((6, 6, 6))
    for (r, c), half in blocks.items():
        table[3 * half:3 * half + 3, 3 * r:3 * r + 3, 3 * c:3 * c + 3] = HAT_TABLE.reshape(3, 3, 3)
    return table.reshape(6, 36)


AD_TABLE = block_table({(0, 0): 1, (0, 1): 0, (1, 1): 1})      # ad([ρ; φ]) = [[φ^, ρ^], [0, φ^]]
_EYE6 = np.eye(6)

# ----------------------------------------------------------------------------- series in θ²
TERMS = 40
_k = np.arange(1, TERMS + 3, dtype=float)
_A = 2.0 * zeta(2.0 * _k) / (2.0 * np.pi) ** (2.0 * _k)        # a_1 … a_42


def _series_table() -> np.ndarray:
    """(TERMS, 31): ``coefficients(θ²) = [t⁰ … t^(N−1)] @ table``, t = θ². Columns: SO(3) ``c``
    (J⁻¹ = I − ½Φ + cΦ²); the weights of [I, A, A², A³, A⁴] in J_l⁻¹ (1, −½, c₂, 0, c₄); and the
    5×5 matrix (row-major) taking ``[z₀ … z₄]``, ``z_k = A^k S w``, to ``S v`` for the vectors ``v``
    the link tangent needs (functions of ``u_k = (Aᵀ)^k w = (−1)^k S z_k``; ``S`` swaps a twist's
    halves, ``Aᵀ = −SAS``)."""
    a = dict(zip(range(1, TERMS + 3), _A))
    j = np.arange(TERMS)
    const = lambda value: np.where(j == 0, value, 0.0)                  # noqa: E731
    c_so3 = np.array([a[i + 1] for i in j])
    c2 = np.array([(1 - i) * a[i + 1] for i in j])                         # Σ (2−k) a_k t^(k−1)
    c4 = np.array([-(i + 1) * a[i + 2] for i in j])                        # Σ (1−k) a_k t^(k−2)
    dc2 = np.array([-i * (i + 1) * a[i + 2] for i in j])                   # d/dt of c₂
    dc4 = np.array([-(i + 2) * (i + 1) * a[i + 3] for i in j])             # d/dt of c₄
    zero = np.zeros(TERMS)
    # the tangent's vectors from u_k = (−1)^k S z_k (z_k = A^k S w, S swapping a twist's halves):
    # the weight of u_k times (−1)^k, which gives S v
    columns = [c_so3, const(1.0), const(-0.5), c2, zero, c4,
               const(-0.5), -c2, zero, -c4, zero,          # v₃ = −½w + c₂u₁ + c₄u₃
               c2, zero, c4, zero, zero,                   # v₂ = c₂w + c₄u₂
               zero, -c4, zero, zero, zero,                # v₁ = c₄u₁
               c4, zero, zero, zero, zero,                 # v₀ = c₄w
               zero, zero, 2.0 * dc2, zero, 2.0 * dc4]     # ∂(c₂, c₄)/∂φ direction: 2(c₂′u₂ + c₄′u₄)
    return np.stack(columns, 1)


def _exp_table() -> np.ndarray:
    """(TERMS, 5) series in t = θ² of cos(θ/2), sin(θ/2)/θ, 1, (1 − cos θ)/θ² and (θ − sin θ)/θ³
    (the last three weigh ρ, Φρ, Φ²ρ in ``V ρ``): alternating, used for t ≤ 16 (θ ≤ 4 rad),
    where 16 terms leave < 1e-18."""
    k = np.arange(TERMS)
    fact = np.array([float(math.factorial(i)) for i in range(2 * TERMS + 4)])
    sign = (-1.0) ** k
    table = np.stack([sign / (4.0 ** k * fact[2 * k]), sign / (2.0 * 4.0 ** k * fact[2 * k + 1]),
                      np.where(k == 0, 1.0, 0.0), sign / fact[2 * k + 2], sign / fact[2 * k + 3]], 1)
    table[16:] = 0.0
    return table


SERIES = _series_table()
EXP_TABLE = _exp_table()
EXP_SERIES_LIMIT = 16.0      # θ² up to which EXP_TABLE is summed (θ = 4 rad)


def terms(largest: float) -> int:
    """Series terms needed for θ² ≤ ``largest``: the k-th is below ``(θ²/4π²)^k`` relative.
    A non-finite ``largest`` (a state or step that is not finite) raises :class:`ConvergenceError`."""
    if not math.isfinite(largest):
        raise ConvergenceError("non-finite link rotations reached the Lie-group series (the state or the "
                               "step that produced it is not finite)")
    ratio = largest / (4.0 * np.pi * np.pi)
    return TERMS if ratio >= 0.25 else min(TERMS, 4 + int(-41.5 / math.log(max(ratio, 1e-300))))


def powers(t: np.ndarray, count: int) -> np.ndarray:
    """``[t⁰, t¹, …]`` (n, count) by running products: unlike ``t ** k`` (libm ``pow``), tiny
    and zero ``t`` cost nothing extra (``pow`` takes ~10× longer when results underflow)."""
    table = np.empty((t.shape[0], count))
    table[:, 0] = 1.0
    table[:, 1:] = t[:, None]
    return np.multiply.accumulate(table, axis=1, out=table)


def coefficients(theta2: np.ndarray) -> np.ndarray:
    """``(n, 31)`` logarithm-side coefficients of a batch of angles (see :func:`_series_table`)."""
    count = terms(float(theta2.max()) if theta2.size else 0.0)
    return powers(theta2, count) @ SERIES[:count]


def exp_coefficients(theta2: np.ndarray) -> np.ndarray:
    """``(n, 5)`` exponential-side coefficients (:data:`EXP_TABLE`'s columns) of a batch of angles:
    the series up to θ² = 16, the closed forms beyond."""
    if not theta2.size or float(theta2.max()) <= EXP_SERIES_LIMIT:
        return powers(theta2, 16) @ EXP_TABLE[:16]
    t2 = np.maximum(theta2, EXP_SERIES_LIMIT)
    theta = np.sqrt(t2)
    closed = np.stack([np.cos(0.5 * theta), np.sin(0.5 * theta) / theta, np.ones_like(theta),
                       (1.0 - np.cos(theta)) / t2, (theta - np.sin(theta)) / (t2 * theta)], 1)
    return np.where(theta2[:, None] <= EXP_SERIES_LIMIT, powers(theta2, 16) @ EXP_TABLE[:16], closed)


# ----------------------------------------------------------------------------- quaternions
def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of vectors ``(..., 3) -> (..., 3, 3)`` (one small matrix product)."""
    return v.reshape(-1, 3).dot(HAT_TABLE).reshape(v.shape[:-1] + (3, 3))


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` quaternions."""
    left = (p[..., _QL_INDEX] * _QL_SIGN).reshape(p.shape[:-1] + (4, 4))
    return (left @ q[..., None])[..., 0]


def qconj(q: np.ndarray) -> np.ndarray:
    """Quaternion conjugate (the inverse of a unit quaternion)."""
    return q * _CONJ


def qmatrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    outer = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    return (outer @ R_TABLE).reshape(q.shape[:-1] + (3, 3))


def qfrom_matrix(R) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` with ``w ≥ 0`` of rotation matrices ``(..., 3, 3)`` (the
    inverse of :func:`qmatrix`): of the four rows ``4 q_i q`` (:data:`Q_TABLE`), the one of the
    largest ``4 q_i²``, normalised (Shepperd's method: no cancellation at any angle)."""
    R = np.asarray(R, dtype=float)
    flat = np.empty((R.size // 9, 10))
    flat[:, 0] = 1.0
    flat[:, 1:] = R.reshape(-1, 9)
    rows = (flat @ Q_TABLE).reshape(-1, 4, 4)
    n = rows.shape[0]
    pivot = rows[:, [0, 1, 2, 3], [0, 1, 2, 3]].argmax(1)
    q = rows[np.arange(n), pivot]
    q *= np.copysign(1.0 / np.sqrt((q * q).sum(1)), q[:, 0])[:, None]
    return q.reshape(R.shape[:-2] + (4,))


def pose_matrix(position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """Homogeneous transforms ``(..., 4, 4)`` of poses (positions ``(..., 3)``, unit quaternions
    ``(..., 4)`` [w, x, y, z]): ``[[R, p], [0, 1]]`` maps a point in the frame to the world."""
    position, quaternion = np.asarray(position, dtype=float), np.asarray(quaternion, dtype=float)
    shape = np.broadcast_shapes(position.shape[:-1], quaternion.shape[:-1])
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = qmatrix(quaternion)
    out[..., :3, 3] = position
    out[..., 3, 3] = 1.0
    return out


def qrotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` by unit quaternions ``q`` (broadcasting)."""
    return (qmatrix(q) @ v[..., None])[..., 0]


def qexp(phi: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors ``(..., 3)``."""
    flat = phi.reshape(-1, 3)
    c = exp_coefficients((flat * flat).sum(1))
    return np.concatenate([c[:, :1], c[:, 1:2] * flat], 1).reshape(phi.shape[:-1] + (4,))


def qlog(q: np.ndarray) -> np.ndarray:
    """Rotation vectors of unit quaternions ``(..., 4)``, angle in [0, π] (q and −q: the same
    rotation)."""
    w, v = q[..., 0], q[..., 1:]
    s = np.sqrt((v * v).sum(-1))
    angle = 2.0 * np.arctan2(s, np.abs(w))
    return (np.copysign(angle, w) / np.maximum(s, 1e-300))[..., None] * v


# ----------------------------------------------------------------------------- SO(3), matrix form
def so3_exp(phi) -> np.ndarray:
    """Rotation matrices ``exp(φ^)`` ``(..., 3, 3)`` of rotation vectors ``(..., 3)``."""
    return qmatrix(qexp(np.asarray(phi, dtype=float)))


def so3_expm1(phi) -> np.ndarray:
    """``exp(φ^) − I`` ``(..., 3, 3)`` without the cancellation of ``so3_exp(φ) − I`` at small
    angles: ``2w v^ + 2 v^v^`` of the quaternion ``[w, v] = qexp(φ)``."""
    q = qexp(np.asarray(phi, dtype=float))
    V = hat(q[..., 1:])
    return 2.0 * (q[..., 0, None, None] * V + V @ V)


def so3_log(R) -> np.ndarray:
    """Rotation vectors ``(..., 3)``, angle in [0, π], of rotation matrices ``(..., 3, 3)``."""
    return qlog(qfrom_matrix(R))


# ----------------------------------------------------------------------------- SE(3)
def ad(xi) -> np.ndarray:
    """``ad(ξ) = [[φ^, ρ^], [0, φ^]]`` ``(..., 6, 6)`` of twists ``ξ = [ρ; φ]`` ``(..., 6)``."""
    xi = np.asarray(xi, dtype=float)
    return (xi.reshape(-1, 6) @ AD_TABLE).reshape(xi.shape[:-1] + (6, 6))


def log_translation(phi: np.ndarray, p: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """``ρ = J⁻¹(φ) p`` (n, 3) with ``J⁻¹ = I − ½Φ + cΦ²`` and ``c = coef[:, 0]``."""
    Phi = (phi @ HAT_TABLE).reshape(-1, 3, 3)
    return p + (Phi @ (coef[:, :1, None] * (Phi @ p[:, :, None]) - 0.5 * p[:, :, None]))[:, :, 0]


def ad_powers(xi: np.ndarray) -> np.ndarray:
    """``(n, 5, 36)``: ``I, A, A², A³, A⁴`` (row-major) with ``A = ad(ξ)``, powers written in place."""
    n = xi.shape[0]
    flat = np.empty((n, 5, 36))
    flat[:, 0] = _EYE6.ravel()
    np.matmul(xi, AD_TABLE, out=flat[:, 1])
    Apow = flat.reshape(n, 5, 6, 6)
    np.matmul(Apow[:, 1], Apow[:, 1], out=Apow[:, 2])
    np.matmul(Apow[:, 2:3], Apow[:, 1:3], out=Apow[:, 3:5])        # A³ = A²A, A⁴ = A²A²
    return flat


def left_jacobian_inverse(coef: np.ndarray, flat_powers: np.ndarray) -> np.ndarray:
    """``J_l⁻¹ = Σ_k coef[:, 1 + k] A^k`` (n, 6, 6) from :func:`ad_powers`."""
    return (coef[:, None, 1:6] @ flat_powers).reshape(-1, 6, 6)


def se3_log(q: np.ndarray, p: np.ndarray):
    """Twist ``ξ = [ρ; φ]`` of the transforms (rotations ``q`` (..., 4), translations ``p``
    (..., 3)) and the inverse left Jacobians ``J_l⁻¹(ξ)`` (..., 6, 6)."""
    shape = q.shape[:-1]
    phi = qlog(q.reshape(-1, 4))
    coef = coefficients((phi * phi).sum(1))
    xi = np.concatenate([log_translation(phi, p.reshape(-1, 3), coef), phi], 1)
    Jl_inv = left_jacobian_inverse(coef, ad_powers(xi))
    return xi.reshape(shape + (6,)), Jl_inv.reshape(shape + (6, 6))


def exp_translation(expc: np.ndarray, phi: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """``V(φ) ρ`` (n, 3) from the exponential coefficients ``expc`` (n, 5)."""
    Phi = phi.dot(HAT_TABLE).reshape(-1, 3, 3)
    T = np.empty((phi.shape[0], 3, 3))                 # rows ρ, Φρ, Φ²ρ: V ρ = [1, b, c] · T
    T[:, 0] = rho
    np.matmul(Phi, rho[:, :, None], out=T[:, 1, :, None])
    np.matmul(Phi, T[:, 1, :, None], out=T[:, 2, :, None])
    return (expc[:, None, 2:] @ T)[:, 0]


def se3_exp(xi: np.ndarray):
    """Rotation quaternions and translations of ``exp(ξ^)`` for twists ``(..., 6)``."""
    shape = xi.shape[:-1]
    flat = xi.reshape(-1, 6)
    phi = flat[:, 3:]
    c = exp_coefficients((phi * phi).sum(1))
    q = np.concatenate([c[:, :1], c[:, 1:2] * phi], 1)
    return q.reshape(shape + (4,)), exp_translation(c, phi, flat[:, :3]).reshape(shape + (3,))


def se3_left_jacobian_inverse(xi) -> np.ndarray:
    """``J_l⁻¹(ξ)`` ``(..., 6, 6)`` of twists ``(..., 6)`` whose angles are at most π (every
    logarithm's): ``log(exp(ζ^) exp(ξ^)) = ξ + J_l⁻¹ζ + O(ζ²)``."""
    xi = np.asarray(xi, dtype=float)
    flat = xi.reshape(-1, 6)
    phi = flat[:, 3:]
    Jl_inv = left_jacobian_inverse(coefficients((phi * phi).sum(1)), ad_powers(flat))
    return Jl_inv.reshape(xi.shape[:-1] + (6, 6))


def se3_exp_matrix(xi):
    """Rotation matrices ``(..., 3, 3)`` and translations ``(..., 3)`` of ``exp(ξ^)`` for twists
    ``(..., 6)``: the transform ``x ↦ R x + t``."""
    q, t = se3_exp(np.asarray(xi, dtype=float))
    return qmatrix(q), t


def se3_log_matrix(R, t) -> np.ndarray:
    """Twists ``ξ = [ρ; φ]`` ``(..., 6)`` of the transforms ``x ↦ R x + t`` (rotation matrices
    ``(..., 3, 3)``, translations ``(..., 3)``; angles in [0, π])."""
    R, t = np.asarray(R, dtype=float), np.asarray(t, dtype=float)
    phi = so3_log(R).reshape(-1, 3)
    coef = coefficients((phi * phi).sum(1))
    xi = np.concatenate([log_translation(phi, t.reshape(-1, 3), coef), phi], 1)
    return xi.reshape(R.shape[:-2] + (6,))
