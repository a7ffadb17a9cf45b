"""Kinematics of links between frames: strain, generalised forces and the exact tangent.

A link between frames ``a`` and ``b`` has the strain ``ξ = log(T_a⁻¹ T_b) = [ρ; φ]`` and stores
an energy ``ψ(ξ, p)`` (its *kind* says which: :mod:`vertebra.solver.kinds`). Everything here
depends on the energy only through ``w = ∂ψ/∂ξ`` (the strain-space force) and the material
tangent ``M = ∂²ψ/∂ξ²``:

* gradient on the frames: ``g = Zw y = Gᵀ w`` with ``y = J_l⁻ᵀ w`` (``J_l⁻¹`` from
  :mod:`vertebra.core.lie`); ``Zw`` maps strain-space forces to the 12 forces/moments on
  ``[a; b]`` (world axes) and ``G = J_l⁻¹ Zwᵀ = ∂ξ/∂[q_a; q_b]`` is the strain's Jacobian;
* tangent: ``Zw (∂y/∂ξ) G`` plus the geometric stiffness of the lever arms, where,
  because ``ad`` is linear in its argument (``ad(δ)ᵀu = Λ(u)δ``,
  ``Λ(u) = [[0, û_f], [û_f, û_m]]``), the product rule gives — no complex step, no finite
  difference::

    ∂y/∂ξ = J_l⁻ᵀM − ½Λ(w) + c₂[Λ(u₁) + AᵀΛ(w)]
            + c₄[Λ(u₃) + AᵀΛ(u₂) + A²ᵀΛ(u₁) + A³ᵀΛ(w)] + (c₂′u₂ + c₄′u₄) ⊗ 2[0; φ]

  with ``u_k = (Aᵀ)^k w``: a handful of batched 6×6 products per link.

Perturbations follow the solver's chart (``x + dx``, ``exp(dφ) R``, world axes). In the axes
of ``a``: ``ζ_a = −Bᵀ dq_a`` and ``ζ_b = P Bᵀ dq_b`` with ``B = diag(R_a, R_a)`` and
``P = [[I, p̂], [0, I]]``, ``p = R_aᵀ(x_b − x_a)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vertebra.core.lie import (
    HAT_TABLE,
    L_TABLE,
    R_TABLE,
    ad_powers,
    block_table,
    coefficients,
    left_jacobian_inverse,
    log_translation,
    qlog,
)

_LAMBDA_TABLE = block_table({(0, 1): 0, (1, 0): 0, (1, 1): 1})    # Λ(u) = [[0, u_f^], [u_f^, u_m^]]
_SWAP = np.array([3, 4, 5, 0, 1, 2])          # S: a twist's halves swapped (S = Sᵀ = S⁻¹)
_LAMBDA_SWAPPED = _LAMBDA_TABLE[_SWAP]         # Λ(S v) = v @ _LAMBDA_SWAPPED
_PHI_MASK = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])     # [ρ; φ] → [0; φ]


def _zw_table() -> np.ndarray:
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
    hat = HAT_TABLE.reshape(3, 3, 3)
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


_ZW_TABLE = _zw_table()
_GEOMETRIC_TABLE = _geometric_table()


@dataclass
class Links:
    """Kinematics of a batch of links at one state (``n`` links)."""

    Zw: np.ndarray         # (n, 12, 6) strain-space force → forces/moments on [a; b] (world);
                           # also ζ = Zwᵀ [dq_a; dq_b]. Zw = diag(R_a, R_a) [−I; Pᵀ] (see module doc)
    xi: np.ndarray         # (n, 6) strain [ρ; φ]
    Apow: np.ndarray       # (n, 5, 6, 6) I, A, A², A³, A⁴ with A = ad(ξ)
    Jl_inv: np.ndarray     # (n, 6, 6) inverse left Jacobian
    coef: np.ndarray       # (n, 31) lie.coefficients() of the strains
    span: np.ndarray       # (n, 3) x_b − x_a, world
    G: np.ndarray          # (n, 6, 12) J_l⁻¹ Zwᵀ = ∂ξ/∂[q_a; q_b], the strain's Jacobian (world chart)

    @classmethod
    def of(cls, qa, xa, qb, xb) -> "Links":
        """From the poses of the frames (quaternions, positions) at both ends of each link."""
        n = qa.shape[0]
        Ra = ((qa[:, :, None] * qa[:, None, :]).reshape(n, 16) @ R_TABLE).reshape(n, 3, 3)
        span = xb - xa
        p = (span[:, None, :] @ Ra)[:, 0]                              # R_aᵀ (x_b − x_a)
        relative = (qb[:, None, :] @ (qa @ L_TABLE).reshape(n, 4, 4))[:, 0]   # q̄_a ⊗ q_b = L(q_a)ᵀ q_b
        phi = qlog(relative)
        coef = coefficients((phi * phi).sum(1))
        xi = np.empty((n, 6))
        xi[:, 3:] = phi
        xi[:, :3] = log_translation(phi, p, coef)
        return cls._complete(Ra, xi, coef, span)

    @classmethod
    def of_strains(cls, Ra, xi, span, coef=None) -> "Links":
        """From the strains ``ξ`` themselves, with the rotations ``R_a`` of the first frames and
        the world spans (what :func:`~vertebra.solver.chain.chain_poses` computed from ``ξ``):
        the same kinematics as :meth:`of` on the composed poses, without taking logarithms."""
        if coef is None:
            coef = coefficients((xi[:, 3:] * xi[:, 3:]).sum(1))
        return cls._complete(Ra, xi, coef, span)

    @classmethod
    def _complete(cls, Ra, xi, coef, span) -> "Links":
        n = xi.shape[0]
        flat = ad_powers(xi)
        features = np.empty((n, 18))                   # [R_a, ŝ R_a] with s = x_b − x_a
        features[:, :9] = Ra.reshape(n, 9)
        np.matmul(span.dot(HAT_TABLE).reshape(n, 3, 3), Ra, out=features[:, 9:].reshape(n, 3, 3))
        Zw = features.dot(_ZW_TABLE).reshape(n, 12, 6)
        Jl_inv = left_jacobian_inverse(coef, flat)
        return cls(Zw, xi, flat.reshape(n, 5, 6, 6), Jl_inv, coef, span, Jl_inv @ Zw.mT)

    def transport(self, w: np.ndarray) -> np.ndarray:
        """``J_l⁻ᵀ w`` for ``w`` of shape (n, 6) or (n, m, 6)."""
        if w.ndim == 2:
            return (w[:, None, :] @ self.Jl_inv)[:, 0]
        return w @ self.Jl_inv

    def strain_change(self, dq: np.ndarray) -> np.ndarray:
        """``G [dq_a; dq_b] = J_l⁻¹ ζ``: the linearised change (n, 6) of the strains under frame
        increments ``dq = [dx; dφ]`` (world axes, all n + 1 frames, (n + 1, 6)); for links of a batch
        of B chains (B·n rows, sample by sample), ``dq`` (B, n + 1, 6) gives (B·n, 6)."""
        pairs = np.concatenate([dq[..., :-1, :], dq[..., 1:, :]], -1)
        if pairs.ndim > 2:
            pairs = pairs.reshape(-1, 12)
        return (self.G @ pairs[:, :, None])[:, :, 0]

    def generalised_force(self, y: np.ndarray) -> np.ndarray:
        """Generalised force (…, 12) on ``[a, b]`` (world axes) of strain-space forces ``y``,
        (n, 6) or (n, m, 6): ``Zw y = diag(B, B) [−y; Pᵀ y]``."""
        if y.ndim == 2:
            return (self.Zw @ y[:, :, None])[:, :, 0]
        return (self.Zw @ y.mT).mT

    def gradient(self, w: np.ndarray) -> np.ndarray:
        """Gradient on ``[a, b]`` of link energies with ``∂ψ/∂ξ = w``: ``Gᵀ w = Zw J_l⁻ᵀ w``, (n, 12)
        for ``w`` (n, 6) or (n, m, 12) for (n, m, 6)."""
        if w.ndim == 2:
            return (w[:, None, :] @ self.G)[:, 0]
        return w @ self.G


def link_tangent(links: Links, w: np.ndarray, material: np.ndarray, gradient: np.ndarray, out=None):
    """Exact tangent (n, 12, 12) of the links' energies at the state of ``links``, from
    ``w = ∂ψ/∂ξ`` (n, 6), the material tangent ``∂²ψ/∂ξ²`` (n, 6, 6) and the links' gradient
    (:meth:`Links.gradient`): ``Zw (∂y/∂ξ) G`` plus the geometric stiffness of the lever
    arms (:func:`_geometric_table`); the formula is in the module docstring. ``out``: an
    (n, 12, 12) array to write into."""
    n = links.xi.shape[0]
    # u_k = (Aᵀ)^k w = (−1)^k S A^k S w (Aᵀ = −SAS): all five from one product of the stacked
    # powers [I; A; …; A⁴] with S w; the signs and the swaps are in the coefficients (S v) and Λ's table
    Z = links.Apow.reshape(n, 30, 6) @ w.take(_SWAP, 1, mode="clip")[:, :, None]
    V = links.coef[:, 6:].reshape(n, 5, 5) @ Z.reshape(n, 5, 6)   # S v: the four Λ arguments, the coefficient term
    # ∂(J_l⁻ᵀ)/∂ξ [w] = Λ(v₃) + AᵀΛ(v₂) + A²ᵀΛ(v₁) + A³ᵀΛ(v₀): one product of the stacks
    # [I, Aᵀ, A²ᵀ, A³ᵀ] (the transposed vertical stack of powers) and [Λ(v₃); …; Λ(v₀)]
    D = links.Apow[:, :4].reshape(n, 24, 6).mT @ V[:, :4].reshape(4 * n, 6).dot(_LAMBDA_SWAPPED).reshape(n, 24, 6)
    D += links.Jl_inv.mT @ material
    D += V[:, 4].take(_SWAP, 1, mode="clip")[:, :, None] @ (links.xi * _PHI_MASK)[:, None, :]   # v₄ ⊗ [0; φ]
    H = np.matmul(links.Zw, D @ links.G, out=out)
    features = np.empty((n, 21))                # [g (12), span ⊗ f_b (9)]
    features[:, :12] = gradient
    np.multiply(links.span[:, :, None], gradient[:, None, 6:9], out=features[:, 12:].reshape(n, 3, 3))
    H += features.dot(_GEOMETRIC_TABLE).reshape(n, 12, 12)
    return H
