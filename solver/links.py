"""Compliance links in closed form: strain, forces and exact tangent with real arithmetic.

A link between frames ``a`` and ``b`` has the strain ``ξ = log(T_a⁻¹ T_b) = [ρ; φ]`` and the
energy ``½ eᵀ K e``, ``e = ξ − ξ_rest``. Everything here follows from one fact about SE(3):
the adjoint ``A = ad(ξ)`` satisfies ``A⁵ + 2θ²A³ + θ⁴A = 0`` (θ = |φ|), so any analytic
function of ``A`` is a polynomial of degree four in ``A`` whose coefficients depend on θ² only.
For the inverse left Jacobian (the map from a perturbation ``ζ`` to ``dξ``)::

    J_l⁻¹(ξ) = I − ½A + c₂(θ²) A² + c₄(θ²) A⁴

with ``c₂ = Σ (2−k) a_k θ^{2k−2}``, ``c₄ = Σ (1−k) a_k θ^{2k−4}`` and
``a_k = |B_2k|/(2k)! = 2ζ(2k)/(2π)^{2k}`` — the coefficients of ``1 − (θ/2)cot(θ/2)``
(Hermite interpolation of ``(x/2)coth(x/2)`` on the spectrum {0, ±iθ, ±iθ}). The series
converge for θ < 2π; at the largest angle a link can take (π) 40 terms leave < 1e-24.

Because ``ad`` is linear in its argument (``ad(δ)ᵀu = Λ(u)δ`` with
``Λ(u) = [[0, û_f], [û_f, û_m]]``), the derivative of the generalised force
``y = J_l⁻ᵀ K e`` follows by the product rule — no complex step, no finite difference::

    ∂y/∂ξ = J_l⁻ᵀK − ½Λ(w) + c₂[Λ(u₁) + AᵀΛ(w)]
            + c₄[Λ(u₃) + AᵀΛ(u₂) + A²ᵀΛ(u₁) + A³ᵀΛ(w)] + (c₂′u₂ + c₄′u₄) ⊗ 2[0; φ]

with ``w = Ke`` and ``u_k = (Aᵀ)^k w``. The tangent is then a handful of batched 6×6
products per link. It is the same tangent as :func:`solver.elements.pair_tangent` (the
complex-step reference the tests compare it with), at a fraction of the numpy calls: for
trunks of tens of links the cost of a Newton iteration is the number of numpy calls.

Perturbations follow the solver's chart (``x + dx``, ``exp(dφ) R``, world axes). In the axes
of ``a``: ``ζ_a = −Bᵀ dq_a`` and ``ζ_b = P Bᵀ dq_b`` with ``B = diag(R_a, R_a)`` and
``P = [[I, p̂], [0, I]]``, ``p = R_aᵀ(x_b − x_a)``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.special import zeta

from vertebra.solver.rotations import _HAT_TABLE, _QL_INDEX, _QL_SIGN, _R_TABLE

_TERMS = 40
_k = np.arange(1, _TERMS + 3, dtype=float)
_A = 2.0 * zeta(2.0 * _k) / (2.0 * np.pi) ** (2.0 * _k)        # a_1 … a_42


def _series_table() -> np.ndarray:
    """(N, 31) table: ``coefficients(θ²) = [t^0 … t^(N−1)] @ table``, t = θ². Columns: SO(3) ``c``
    (J⁻¹ = I − ½Φ + cΦ²); the weights of [I, A, A², A³, A⁴] in J_l⁻¹ (1, −½, c₂, 0, c₄); and the 5×5
    matrix (row-major) taking ``[w, u₁, u₂, u₃, u₄]`` to the vectors :func:`link_tangent` needs."""
    a = dict(zip(range(1, _TERMS + 3), _A))
    j = np.arange(_TERMS)
    const = lambda value: np.where(j == 0, value, 0.0)                  # noqa: E731
    c_so3 = np.array([a[i + 1] for i in j])
    c2 = np.array([(1 - i) * a[i + 1] for i in j])                         # Σ (2−k) a_k t^(k−1)
    c4 = np.array([-(i + 1) * a[i + 2] for i in j])                        # Σ (1−k) a_k t^(k−2)
    dc2 = np.array([-i * (i + 1) * a[i + 2] for i in j])                   # d/dt of c₂
    dc4 = np.array([-(i + 2) * (i + 1) * a[i + 3] for i in j])             # d/dt of c₄
    zero = np.zeros(_TERMS)
    columns = [c_so3, const(1.0), const(-0.5), c2, zero, c4,
               const(-0.5), c2, zero, c4, zero,            # v₃ = −½w + c₂u₁ + c₄u₃
               c2, zero, c4, zero, zero,                   # v₂ = c₂w + c₄u₂
               zero, c4, zero, zero, zero,                 # v₁ = c₄u₁
               c4, zero, zero, zero, zero,                 # v₀ = c₄w
               zero, zero, 2.0 * dc2, zero, 2.0 * dc4]     # ∂(c₂, c₄)/∂φ direction: 2(c₂′u₂ + c₄′u₄)
    return np.stack(columns, 1)


_SERIES = _series_table()


def _block_table(blocks) -> np.ndarray:
    """(6, 36) table T with M(v).ravel() = v @ T for a 6×6 matrix of hats of v's halves.
    ``blocks`` maps (row block, column block) to the half of v (0: first, 1: second)."""
    table = np.zeros((6, 6, 6))
    for (r, c), half in blocks.items():
        table[3 * half:3 * half + 3, 3 * r:3 * r + 3, 3 * c:3 * c + 3] = _HAT_TABLE.reshape(3, 3, 3)
    return table.reshape(6, 36)


def _left_table() -> np.ndarray:
    """(4, 16): L(q).ravel() = q @ T, with p ⊗ q = L(p) q."""
    left = np.zeros((4, 16))
    left[_QL_INDEX, np.arange(16)] = _QL_SIGN
    return left


def _zw_table():
    """(18, 72): ``Zw = [[−R, 0], [0, −R], [R, 0], [−ŝR, R]] = ([R, ŝR] flattened) @ T``:
    ``diag(R, R)[−I; Pᵀ]`` with ``Pᵀ = [[I, 0], [−p̂, I]]`` and ``R p̂ = ŝ R`` (s = R p)."""
    table = np.zeros((2, 3, 3, 12, 6))
    for r in range(3):
        for c in range(3):
            table[0, r, c, r, c] = -1.0           # −R (force at a)
            table[0, r, c, 3 + r, 3 + c] = -1.0   # −R (moment at a)
            table[0, r, c, 6 + r, c] = 1.0        # R (force at b)
            table[0, r, c, 9 + r, 3 + c] = 1.0    # R (moment at b)
            table[1, r, c, 9 + r, c] = -1.0       # −ŝR (moment at b of the force)
    return table.reshape(18, 72)


def _geometric_table() -> np.ndarray:
    """(21, 144): geometric stiffness of a link (world axes) from ``[g, span ⊗ f_b]``, where
    ``g`` is the link's gradient (forces/moments on a, b) and ``f_b = g[6:9]``. Rotating the
    frames turns the lever arms and the forces: the columns of ``dφ_a`` carry ``−ĝ`` (every
    3-block of g turns with a common rotation; objectivity), and the moment at ``b`` depends on
    the span ``x_b − x_a``: ``±f̂_b`` on ``dx_a``, ``dx_b`` and ``f̂_b ŝ = s f_bᵀ − (f_b·s) I`` on ``dφ_a``."""
    hat = _HAT_TABLE.reshape(3, 3, 3)
    table = np.zeros((21, 12, 12))
    for block in range(4):                                   # −ĝ in the dφ_a columns
        table[3 * block:3 * block + 3, 3 * block:3 * block + 3, 3:6] -= hat
    table[6:9, 9:12, 6:9] += hat                             # f̂_b on dx_b
    table[6:9, 9:12, 0:3] -= hat                             # −f̂_b on dx_a
    for i in range(3):
        for j in range(3):
            table[12 + 3 * i + j, 9 + i, 3 + j] += 1.0       # s f_bᵀ
            if i == j:
                table[12 + 3 * i + j, 9:12, 3:6] -= np.eye(3)   # −(f_b·s) I
    return table.reshape(21, 144)


_AD_TABLE = _block_table({(0, 0): 1, (0, 1): 0, (1, 1): 1})        # ad([ρ; φ]) = [[φ^, ρ^], [0, φ^]]
_LAMBDA_TABLE = _block_table({(0, 1): 0, (1, 0): 0, (1, 1): 1})    # Λ(u) = [[0, u_f^], [u_f^, u_m^]]
_L_TABLE = _left_table()
_ZW_TABLE = _zw_table()
_GEOMETRIC_TABLE = _geometric_table()
_EYE6 = np.eye(6)


def _terms(largest: float) -> int:
    """Series terms needed for θ² ≤ ``largest``: the k-th is below ``(θ²/4π²)^k`` relative."""
    ratio = largest / (4.0 * np.pi * np.pi)
    return _TERMS if ratio >= 0.25 else min(_TERMS, 4 + int(-41.5 / math.log(max(ratio, 1e-300))))


def coefficients(theta2: np.ndarray) -> np.ndarray:
    """``(n, 31)`` polynomial coefficients of the links (see :func:`_series_table`)."""
    terms = _terms(float(theta2.max()) if theta2.size else 0.0)
    return _powers(theta2, terms) @ _SERIES[:terms]


def _powers(t: np.ndarray, count: int) -> np.ndarray:
    """``[t⁰, t¹, …]`` (n, count) by running products: unlike ``t ** k`` (libm ``pow``), tiny
    and zero ``t`` cost nothing extra (``pow`` takes ~10× longer when results underflow)."""
    table = np.empty((t.shape[0], count))
    table[:, 0] = 1.0
    table[:, 1:] = t[:, None]
    return np.multiply.accumulate(table, axis=1, out=table)


def rotation_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector of unit quaternions ``(n, 4)``, angle in [0, π] (real input)."""
    w, v = q[:, 0], q[:, 1:]
    s = np.sqrt((v * v).sum(1))
    angle = 2.0 * np.arctan2(s, np.abs(w))            # q and −q: the same rotation
    return (np.copysign(angle, w) / np.maximum(s, 1e-300))[:, None] * v


@dataclass
class Links:
    """Kinematics of a batch of links at one state (``n`` links)."""

    Zw: np.ndarray         # (n, 12, 6) strain-space force → forces/moments on [a; b] (world);
                           # also ζ = Zwᵀ [dq_a; dq_b]. Zw = diag(R_a, R_a) [−I; Pᵀ] (see module doc)
    xi: np.ndarray         # (n, 6) strain [ρ; φ]
    Apow: np.ndarray       # (n, 5, 6, 6) I, A, A², A³, A⁴ with A = ad(ξ)
    Jl_inv: np.ndarray     # (n, 6, 6) inverse left Jacobian
    coef: np.ndarray       # (n, 31) see coefficients()
    span: np.ndarray       # (n, 3) x_b − x_a, world

    @classmethod
    def of(cls, qa, xa, qb, xb) -> "Links":
        """From the poses of the frames (quaternions, positions) at both ends of each link."""
        n = qa.shape[0]
        Ra = ((qa[:, :, None] * qa[:, None, :]).reshape(n, 16) @ _R_TABLE).reshape(n, 3, 3)
        span = xb - xa
        p = (span[:, None, :] @ Ra)[:, 0]                              # R_aᵀ (x_b − x_a)
        relative = (qb[:, None, :] @ (qa @ _L_TABLE).reshape(n, 4, 4))[:, 0]   # q̄_a ⊗ q_b = L(q_a)ᵀ q_b
        phi = rotation_log(relative)
        coef = coefficients((phi * phi).sum(1))
        Phi = (phi @ _HAT_TABLE).reshape(n, 3, 3)
        xi = np.empty((n, 6))
        xi[:, 3:] = phi
        xi[:, :3] = p + (Phi @ (coef[:, :1, None] * (Phi @ p[:, :, None]) - 0.5 * p[:, :, None]))[:, :, 0]
        return cls._complete(Ra, xi, coef, span)

    @classmethod
    def of_strains(cls, Ra, xi, span, coef=None) -> "Links":
        """From the strains ``ξ`` themselves, with the rotations ``R_a`` of the first frames and
        the world spans (what :func:`chain_poses` computed from ``ξ``): the same kinematics as
        :meth:`of` on the composed poses, without taking logarithms."""
        if coef is None:
            coef = coefficients((xi[:, 3:] * xi[:, 3:]).sum(1))
        return cls._complete(Ra, xi, coef, span)

    @classmethod
    def _complete(cls, Ra, xi, coef, span) -> "Links":
        n = xi.shape[0]
        flat = np.empty((n, 5, 36))
        flat[:, 0] = _EYE6.ravel()
        np.matmul(xi, _AD_TABLE, out=flat[:, 1])
        Apow = flat.reshape(n, 5, 6, 6)
        np.matmul(Apow[:, 1], Apow[:, 1], out=Apow[:, 2])
        np.matmul(Apow[:, 2], Apow[:, 1], out=Apow[:, 3])
        np.matmul(Apow[:, 2], Apow[:, 2], out=Apow[:, 4])
        Jl_inv = (coef[:, None, 1:6] @ flat).reshape(n, 6, 6)
        features = np.empty((n, 18))                   # [R_a, ŝ R_a] with s = x_b − x_a
        features[:, :9] = Ra.reshape(n, 9)
        np.matmul((span @ _HAT_TABLE).reshape(n, 3, 3), Ra, out=features[:, 9:].reshape(n, 3, 3))
        return cls((features @ _ZW_TABLE).reshape(n, 12, 6), xi, Apow, Jl_inv, coef, span)

    def transport(self, w: np.ndarray) -> np.ndarray:
        """``J_l⁻ᵀ w`` for ``w`` of shape (n, 6) or (n, m, 6)."""
        if w.ndim == 2:
            return (w[:, None, :] @ self.Jl_inv)[:, 0]
        return w @ self.Jl_inv

    def strain_change(self, zeta: np.ndarray) -> np.ndarray:
        """``J_l⁻¹ ζ``: change of the strain under a left twist ``ζ`` in ``a``'s axes."""
        return (self.Jl_inv @ zeta[:, :, None])[:, :, 0]

    def generalised_force(self, y: np.ndarray) -> np.ndarray:
        """Generalised force (…, 12) on ``[a, b]`` (world axes) of strain-space forces ``y``,
        (n, 6) or (n, m, 6): ``Zw y = diag(B, B) [−y; Pᵀ y]``."""
        if y.ndim == 2:
            return (self.Zw @ y[:, :, None])[:, :, 0]
        return (self.Zw @ y.mT).mT

    def zeta(self, dq: np.ndarray) -> np.ndarray:
        """Left twists ζ (n, 6) in ``a``'s axes of frame increments ``dq = [dx; dφ]`` (world
        axes, all n + 1 frames, (n + 1, 6)): ``ζ = Zwᵀ [dq_a; dq_b]``."""
        pairs = np.concatenate([dq[:-1], dq[1:]], 1)
        return (self.Zw.mT @ pairs[:, :, None])[:, :, 0]


def link_forces(links: Links, stiffness: np.ndarray, xi_rest: np.ndarray):
    """Gradient (n, 12) and total energy ``½ Σ eᵀ K e`` of the links, with ``w = K e`` and
    ``y = J_l⁻ᵀ w`` (n, 6); :func:`link_tangent` reuses ``w`` and the gradient."""
    e = links.xi - xi_rest
    w = (stiffness @ e[:, :, None])[:, :, 0]
    y = (w[:, None, :] @ links.Jl_inv)[:, 0]
    return (links.Zw @ y[:, :, None])[:, :, 0], 0.5 * float(np.vdot(e, w)), w, y


def link_tangent(links: Links, stiffness: np.ndarray, w: np.ndarray, gradient: np.ndarray, out=None):
    """Exact tangent (n, 12, 12) of the links at the state of ``links``, from ``w = K e`` and the
    links' gradient (see :func:`link_forces`): ``Zw (∂y/∂ξ) J_l⁻¹ Zwᵀ`` plus the geometric
    stiffness of the lever arms (:func:`_geometric_table`). The formula is in the module
    docstring; tests check it against the complex-step reference. ``out``: an (n, 12, 12)
    array to write into."""
    n = links.xi.shape[0]
    W = (w[:, None, None, :] @ links.Apow)[:, :, 0]   # [w, u₁ … u₄], u_k = (Aᵀ)^k w as rows
    V = links.coef[:, 6:].reshape(n, 5, 5) @ W   # the four Λ arguments and the coefficient term
    # ∂(J_l⁻ᵀ)/∂ξ [w] = Λ(v₃) + AᵀΛ(v₂) + A²ᵀΛ(v₁) + A³ᵀΛ(v₀): one product of the stacks
    # [I, Aᵀ, A²ᵀ, A³ᵀ] (the transposed vertical stack of powers) and [Λ(v₃); …; Λ(v₀)]
    D = links.Apow[:, :4].reshape(n, 24, 6).mT @ (V[:, :4] @ _LAMBDA_TABLE).reshape(n, 24, 6)
    D += links.Jl_inv.mT @ stiffness
    D[:, :, 3:] += V[:, 4, :, None] * links.xi[:, None, 3:]
    H = np.matmul(links.Zw @ (D @ links.Jl_inv), links.Zw.mT, out=out)
    features = np.empty((n, 21))                # [g (12), span ⊗ f_b (9)]
    features[:, :12] = gradient
    np.multiply(links.span[:, :, None], gradient[:, None, 6:9], out=features[:, 12:].reshape(n, 3, 3))
    H += (features @ _GEOMETRIC_TABLE).reshape(n, 12, 12)
    return H


def _exp_table() -> np.ndarray:
    """(40, 5) series in t = θ² of cos(θ/2), sin(θ/2)/θ, 1, (1 − cos θ)/θ² and (θ − sin θ)/θ³
    (the last three weigh ρ, Φρ, Φ²ρ in ``V ρ``): alternating, used for t ≤ 16 (θ ≤ 4 rad,
    more than any link turns in one Newton step), where 16 terms leave < 1e-18."""
    k = np.arange(_TERMS)
    fact = np.array([float(math.factorial(i)) for i in range(2 * _TERMS + 4)])
    sign = (-1.0) ** k
    table = np.stack([sign / (4.0 ** k * fact[2 * k]), sign / (2.0 * 4.0 ** k * fact[2 * k + 1]),
                      np.where(k == 0, 1.0, 0.0), sign / fact[2 * k + 2], sign / fact[2 * k + 3]], 1)
    table[16:] = 0.0
    return table


def _pose_table() -> np.ndarray:
    """(24, 64): ``diag(L(q), [[R(q), p], [0, 1]]).ravel() = [q, q⊗q, p, 1] @ T``."""
    table = np.zeros((24, 8, 8))
    table[:4, :4, :4] = _L_TABLE.reshape(4, 4, 4)
    table[4:20, 4:7, 4:7] = _R_TABLE.reshape(16, 3, 3)
    table[20 + np.arange(3), 4 + np.arange(3), 7] = 1.0
    table[23, 7, 7] = 1.0
    return table.reshape(24, 64)


_EXP_TABLE = _exp_table()
_CHAIN_TABLE = np.concatenate([_SERIES, _EXP_TABLE], 1)     # link coefficients and exp coefficients
_POSE_TABLE = _pose_table()
_IDENTITY_FEATURES = np.zeros(24)
_IDENTITY_FEATURES[[0, 4, 23]] = 1.0
CARRY_ANGLE = 0.99 * math.pi     # largest link rotation whose strain a composed state carries


def _exp_closed(theta2: np.ndarray) -> np.ndarray:
    """The five exp coefficients of :func:`_exp_table` in closed form (any θ > 0)."""
    theta = np.sqrt(theta2)
    return np.stack([np.cos(0.5 * theta), np.sin(0.5 * theta) / theta, np.ones_like(theta),
                     (1.0 - np.cos(theta)) / theta2, (theta - np.sin(theta)) / (theta2 * theta)], 1)


@functools.lru_cache(maxsize=64)
def _feature_template(rows: int) -> np.ndarray:
    """Pose features of identity transforms (what the unused padding rows keep)."""
    return np.tile(_IDENTITY_FEATURES, (rows, 1))


def chain_poses(q0: np.ndarray, x0: np.ndarray, xi: np.ndarray) -> "Chain":
    """World quaternions (n+1, 4) and positions (n+1, 3) of a chain from its base pose and the
    strains of its links: ``T_k = T_0 ∘ exp(ξ_1^) ∘ … ∘ exp(ξ_k^)``.

    Each transform is packed as ``diag(L(q), [[R, p], [0, 1]])`` (8×8; ``L(q)`` multiplies
    quaternions, so the product carries the quaternion along) and the prefix products are
    taken by doubling for short chains (log₂N batched products) and in √N blocks for long
    ones (O(N) work in about 2√N products). When every link turns less than
    :data:`CARRY_ANGLE`, the links' polynomial coefficients come from the same product."""
    n = xi.shape[0]
    N = n + 1
    rho, phi = xi[:, :3], xi[:, 3:]
    theta2 = (phi[:, None, :] @ phi[:, :, None])[:, 0, 0]
    largest = float(theta2.max()) if n else 0.0
    link_coef = None
    if largest <= 16.0:
        carry = largest < CARRY_ANGLE ** 2
        terms = max(_terms(largest) if carry else 0, 16 if largest > 1e-2 else 8)
        coef = _powers(theta2, terms) @ _CHAIN_TABLE[:terms]
        expc = coef[:, 31:]
        if carry:
            link_coef = coef[:, :31]
    else:
        expc = np.where(theta2[:, None] <= 16.0, _powers(theta2, 16) @ _EXP_TABLE[:16],
                        _exp_closed(np.maximum(theta2, 16.0)))
    doubling = N <= 64
    c = 1 if doubling else math.isqrt(N - 1) + 1
    m = N if doubling else -(-N // c)
    F = _feature_template(m * c).copy()                # features [q, q⊗q, p, 1] of each factor
    F[0, :4], F[0, 20:23] = q0, x0
    F[1:N, 0] = expc[:, 0]
    F[1:N, 1:4] = expc[:, 1:2] * phi
    Phi = (phi @ _HAT_TABLE).reshape(n, 3, 3)
    T = np.empty((n, 3, 3))                            # rows ρ, Φρ, Φ²ρ: V ρ = [1, b, c] · T
    T[:, 0] = rho
    np.matmul(Phi, rho[:, :, None], out=T[:, 1, :, None])
    np.matmul(Phi, T[:, 1, :, None], out=T[:, 2, :, None])
    F[1:N, 20:23] = (expc[:, None, 2:] @ T)[:, 0]
    quats = F[:N, :4]
    F[:N, 4:20] = (quats[:, :, None] * quats[:, None, :]).reshape(N, 16)
    if doubling:
        M = (F @ _POSE_TABLE).reshape(N, 8, 8)
        shift = 1
        while shift < N:
            M[shift:] = M[:-shift] @ M[shift:]
            shift *= 2
    else:
        M = (F @ _POSE_TABLE).reshape(m, c, 8, 8)
        for j in range(1, c):
            M[:, j] = M[:, j - 1] @ M[:, j]
        for i in range(1, m):
            M[i] = M[i - 1, -1] @ M[i]
        M = M.reshape(m * c, 8, 8)[:N]
    quaternions = M[:, :4, 0]
    quaternions = quaternions / np.sqrt(quaternions[:, None, :] @ quaternions[:, :, None])[:, 0]
    return Chain(quaternions, M[:, 4:7, 7].copy(), M[:, 4:7, 4:7], F[1:N, 20:23], link_coef)


@dataclass
class Chain:
    """Poses composed by :func:`chain_poses`, with what :meth:`Links.of_strains` reuses."""

    quaternions: np.ndarray    # (N, 4) world
    positions: np.ndarray      # (N, 3) world
    rotations: np.ndarray      # (N, 3, 3) world rotation matrices (the same products)
    translations: np.ndarray   # (n, 3) relative translations p of the links, in a's axes
    link_coefficients: np.ndarray | None   # (n, 31) coefficients() of the strains, when carried
