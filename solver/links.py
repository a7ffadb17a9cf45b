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

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import zeta

from solver.rotations import _HAT_TABLE, _QL_INDEX, _QL_SIGN, qconj, qmatrix, qmul

_TERMS = 40
_k = np.arange(1, _TERMS + 3, dtype=float)
_A = 2.0 * zeta(2.0 * _k) / (2.0 * np.pi) ** (2.0 * _k)        # a_1 … a_42


def _series_table() -> np.ndarray:
    """Rows: powers t⁰ … t^(N−1) of t = θ²; columns: c (SO(3) J⁻¹), c₂, c₄, c₂′, c₄′."""
    table = np.zeros((_TERMS, 5))
    a = dict(zip(range(1, _TERMS + 3), _A))
    for j in range(_TERMS):
        table[j, 0] = a[j + 1]                                  # Σ a_k t^(k−1)
        table[j, 1] = (2 - (j + 1)) * a[j + 1]                  # Σ (2−k) a_k t^(k−1)
        table[j, 2] = (1 - (j + 2)) * a[j + 2]                  # Σ (1−k) a_k t^(k−2)
        table[j, 3] = (2 - (j + 2)) * (j + 1) * a[j + 2]        # d/dt of c₂
        table[j, 4] = (1 - (j + 3)) * (j + 1) * a[j + 3]        # d/dt of c₄
    return table


_SERIES = _series_table()
_POWERS = np.arange(_TERMS, dtype=float)


def _block_table(blocks) -> np.ndarray:
    """(6, 36) table T with M(v).ravel() = v @ T for a 6×6 matrix of hats of v's halves.
    ``blocks`` maps (row block, column block) to the half of v (0: first, 1: second)."""
    table = np.zeros((6, 6, 6))
    for (r, c), half in blocks.items():
        table[3 * half:3 * half + 3, 3 * r:3 * r + 3, 3 * c:3 * c + 3] = _HAT_TABLE.reshape(3, 3, 3)
    return table.reshape(6, 36)


_AD_TABLE = _block_table({(0, 0): 1, (0, 1): 0, (1, 1): 1})        # ad([ρ; φ]) = [[φ^, ρ^], [0, φ^]]
_LAMBDA_TABLE = _block_table({(0, 1): 0, (1, 0): 0, (1, 1): 1})    # Λ(u) = [[0, u_f^], [u_f^, u_m^]]
_EYE6 = np.eye(6)


def coefficients(theta2: np.ndarray) -> np.ndarray:
    """``(…, 5)``: SO(3) ``c`` (J⁻¹ = I − ½Φ + cΦ²), SE(3) ``c₂``, ``c₄`` and ``dc₂/dθ²``, ``dc₄/dθ²``."""
    return (theta2[..., None] ** _POWERS) @ _SERIES


def rotation_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector of unit quaternions ``(n, 4)``, angle in [0, π] (real input)."""
    w, v = q[:, 0], q[:, 1:]
    s = np.sqrt(np.einsum("ij,ij->i", v, v))
    angle = 2.0 * np.arctan2(s, np.abs(w))            # q and −q: the same rotation
    return (np.copysign(angle, w) / np.maximum(s, 1e-300))[:, None] * v


@dataclass
class Links:
    """Kinematics of a batch of links at one state (everything in the axes of frame ``a``)."""

    B: np.ndarray          # (n, 6, 6) diag(R_a, R_a)
    P: np.ndarray          # (n, 6, 6) [[I, p̂], [0, I]]
    xi: np.ndarray         # (n, 6) strain [ρ; φ]
    A: np.ndarray          # (n, 6, 6) ad(ξ)
    Jl_inv: np.ndarray     # (n, 6, 6) inverse left Jacobian
    coef: np.ndarray       # (n, 5) see coefficients()
    span: np.ndarray       # (n, 3) x_b − x_a (world)

    @classmethod
    def of(cls, qa, xa, qb, xb) -> "Links":
        n = qa.shape[0]
        Ra = qmatrix(qa)
        B = np.zeros((n, 6, 6))
        B[:, :3, :3] = Ra
        B[:, 3:, 3:] = Ra
        p = ((xb - xa)[:, None, :] @ Ra)[:, 0]                     # R_aᵀ (x_b − x_a)
        phi = rotation_log(qmul(qconj(qa), qb))
        coef = coefficients(np.einsum("ij,ij->i", phi, phi))
        xi = np.empty((n, 6))
        xi[:, 3:] = phi
        Phi = (phi @ _HAT_TABLE).reshape(n, 3, 3)
        Phi_p = (Phi @ p[:, :, None])[:, :, 0]
        xi[:, :3] = p - 0.5 * Phi_p + coef[:, :1] * (Phi @ Phi_p[:, :, None])[:, :, 0]   # ρ = J⁻¹(φ) p
        A = (xi @ _AD_TABLE).reshape(n, 6, 6)
        A2 = A @ A
        Jl_inv = _EYE6 - 0.5 * A + coef[:, 1, None, None] * A2 + coef[:, 2, None, None] * (A2 @ A2)
        P = np.broadcast_to(_EYE6, (n, 6, 6)).copy()
        P[:, :3, 3:] = (p @ _HAT_TABLE).reshape(n, 3, 3)
        return cls(B, P, xi, A, Jl_inv, coef, xb - xa)

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
        (n, 6) or (n, m, 6): ``[−B y; B Pᵀ y]``."""
        single = y.ndim == 2
        Y = y[:, :, None] if single else np.swapaxes(y, 1, 2)           # (n, 6, m)
        world_a = self.B @ Y
        world_b = self.B @ (np.swapaxes(self.P, 1, 2) @ Y)
        g = np.concatenate([-world_a, world_b], 1)                       # (n, 12, m)
        return g[:, :, 0] if single else np.swapaxes(g, 1, 2)

    def zeta(self, dq_a: np.ndarray, dq_b: np.ndarray) -> np.ndarray:
        """Left twist in ``a``'s axes of frame increments ``dq = [dx; dφ]`` (world axes)."""
        local = np.concatenate([dq_b[:, :, None], dq_a[:, :, None]], 2)
        local = np.swapaxes(self.B, 1, 2) @ local
        return (self.P @ local[:, :, :1])[:, :, 0] - local[:, :, 1]


def link_forces(links: Links, stiffness: np.ndarray, xi_rest: np.ndarray):
    """Gradient (n, 12) and energies (n,) of the links, with ``w = K e`` for the tangent."""
    e = links.xi - xi_rest
    w = (stiffness @ e[:, :, None])[:, :, 0]
    energy = 0.5 * np.einsum("ij,ij->i", e, w)
    return links.generalised_force(links.transport(w)), energy, w


def link_tangent(links: Links, stiffness: np.ndarray, xi_rest: np.ndarray):
    """Gradient (n, 12), energies (n,) and exact tangent (n, 12, 12) of the links; see the
    module docstring for the formula (tests check it against the complex-step reference)."""
    n = links.xi.shape[0]
    A, coef = links.A, links.coef
    c2, c4 = coef[:, 1, None], coef[:, 2, None]
    e = links.xi - xi_rest
    AT = np.swapaxes(A, 1, 2)
    w = (stiffness @ e[:, :, None])[:, :, 0]
    energy = 0.5 * np.einsum("ij,ij->i", e, w)
    u = np.empty((n, 4, 6))                     # u_k = (Aᵀ)^k w as rows: u @ A = (Aᵀ u)ᵀ
    u[:, 0] = (w[:, None, :] @ A)[:, 0]
    u[:, 1] = (u[:, 0, None, :] @ A)[:, 0]
    u[:, 2] = (u[:, 1, None, :] @ A)[:, 0]
    u[:, 3] = (u[:, 2, None, :] @ A)[:, 0]
    y = w - 0.5 * u[:, 0] + c2 * u[:, 1] + c4 * u[:, 3]            # J_l⁻ᵀ w
    # Λ of the four combinations the Horner-like grouping below needs, in one product
    V = np.empty((n, 4, 6))
    V[:, 0] = w
    V[:, 1] = u[:, 0]
    V[:, 2] = c4 * u[:, 1] + c2 * w
    V[:, 3] = -0.5 * w + c2 * u[:, 0] + c4 * u[:, 2]
    L = (V @ _LAMBDA_TABLE).reshape(n, 4, 6, 6)
    T1 = L[:, 1] + AT @ L[:, 0]                                     # Λ(u₁) + AᵀΛ(w)
    T2 = L[:, 2] + c4[:, :, None] * (AT @ T1)
    D = np.swapaxes(links.Jl_inv, 1, 2) @ stiffness + L[:, 3] + AT @ T2
    D[:, :, 3:] += (2.0 * (coef[:, 3, None] * u[:, 1] + coef[:, 4, None] * u[:, 3]))[:, :, None] * links.xi[:, None, 3:]
    P, B = links.P, links.B
    DJP = D @ (links.Jl_inv @ P)                                    # ∂y/∂(Bᵀ dq_b)
    X = np.empty((n, 2, 6, 6))
    X[:, 0] = -DJP                                                  # g_a = −B y
    X[:, 1] = np.swapaxes(P, 1, 2) @ DJP                            # g_b = B Pᵀ y
    X[:, 1, 3:, :3] += (y[:, :3] @ _HAT_TABLE).reshape(n, 3, 3)   # p = R_aᵀ(x_b − x_a) moves with x_b
    H_b = (B[:, None] @ X @ np.swapaxes(B, 1, 2)[:, None]).reshape(n, 12, 6)
    g = links.generalised_force(y)
    # columns of frame a from objectivity (see solver.elements.pair_tangent)
    tangent = np.empty((n, 12, 12))
    tangent[:, :, 6:] = H_b
    tangent[:, :, :3] = -H_b[:, :, :3]
    d = (links.span @ _HAT_TABLE).reshape(n, 3, 3)                 # (x_b − x_a)^
    tangent[:, :, 3:6] = (-(g.reshape(n, 4, 3) @ _HAT_TABLE).reshape(n, 12, 3)
                          + H_b[:, :, :3] @ d - H_b[:, :, 3:])
    return g, energy, tangent


_EXP_SERIES = np.array([(-1.0) ** k / math.factorial(2 * k + 3) for k in range(9)])   # (θ − sin θ)/θ³


def exp_twist(xi: np.ndarray):
    """Rotation quaternions (n, 4) and translations (n, 3) of ``exp(ξ^)``, ``ξ = [ρ; φ]``."""
    rho, phi = xi[:, :3], xi[:, 3:]
    theta2 = np.einsum("ij,ij->i", phi, phi)
    theta = np.sqrt(theta2)
    half = 0.5 * np.sinc(theta / (2.0 * np.pi))              # sin(θ/2)/θ, exact at 0
    q = np.empty((xi.shape[0], 4))
    q[:, 0] = np.cos(0.5 * theta)
    q[:, 1:] = half[:, None] * phi
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(theta2 < 1.0, (theta2[:, None] ** np.arange(9.0)) @ _EXP_SERIES,
                     (theta - np.sin(theta)) / (theta2 * theta))
    Phi = (phi @ _HAT_TABLE).reshape(-1, 3, 3)
    Phi_rho = (Phi @ rho[:, :, None])[:, :, 0]
    V_rho = rho + 2.0 * (half * half)[:, None] * Phi_rho + c[:, None] * (Phi @ Phi_rho[:, :, None])[:, :, 0]
    return q, V_rho


def compose_chain(q0: np.ndarray, x0: np.ndarray, rel_q: np.ndarray, rel_p: np.ndarray):
    """World poses of a chain from its base pose and the relative transforms of its links:
    ``T_k = T_0 ∘ rel_1 ∘ … ∘ rel_k``. Each transform is packed as ``diag(L(q), [[R, p], [0, 1]])``
    (8×8; ``L(q)`` multiplies quaternions) and the prefix products are taken in √N blocks:
    O(N) work in about 2√N batched products, whatever the length of the chain."""
    N = rel_q.shape[0] + 1
    c = max(1, math.isqrt(N - 1) + 1)
    m = -(-N // c)
    M = np.zeros((m * c, 8, 8))
    quats = np.concatenate([q0[None], rel_q])
    M[:N, :4, :4] = (quats[:, _QL_INDEX] * _QL_SIGN).reshape(N, 4, 4)
    M[:N, 4:7, 4:7] = qmatrix(quats)
    M[:N, 4:7, 7] = np.concatenate([x0[None], rel_p])
    M[:, 7, 7] = 1.0
    M[N:] = np.eye(8)
    X = M.reshape(m, c, 8, 8)
    for j in range(1, c):
        X[:, j] = X[:, j - 1] @ X[:, j]
    for i in range(1, m):
        X[i] = X[i - 1, -1] @ X[i]
    quaternions = M[:N, :4, 0]
    quaternions = quaternions / np.sqrt(np.einsum("ij,ij->i", quaternions, quaternions))[:, None]
    return quaternions, M[:N, 4:7, 7].copy()
