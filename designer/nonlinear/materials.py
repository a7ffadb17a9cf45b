"""Hyperelastic materials for the total-Lagrangian FE models: a registry.

Every material is evaluated from the displacement gradient ``H = ∇_X u``
(``F = I + H``), vectorised over any leading shape (quadrature points), and
returns the strain energy density ``W``, the first Piola–Kirchhoff stress
``P = ∂W/∂F`` and the consistent tangent ``A = ∂P/∂F`` (``A[..., i, J, k, L]``,
material and geometric stiffness together). The second Piola–Kirchhoff stress is
``S = F⁻¹ P`` (:func:`second_piola`). Working from ``H`` rather than ``F`` keeps
small strains accurate (``E = ½(H + Hᵀ + HᵀH)``, ``J − 1`` from the invariants of
``H``, no difference of O(1) terms in the stress): the small-load limit of the FE
models is compared with the linear condensation at strains of 1e-8.

* ``linear`` — small-strain linear elasticity, ``W = ½λ (tr ε)² + μ ε:ε`` with
  ``ε = sym H``: ``P = λ tr ε I + 2μ ε``, ``A = λ δ_iJ δ_kL + μ (δ_ik δ_JL + δ_iL δ_Jk)``.
  Not objective (a finite rotation strains it); the infinitesimal model of the
  linear designer.
* ``svk`` — St Venant–Kirchhoff: ``S = λ tr(E) I + 2μ E`` with the Green–Lagrange
  strain ``E = ½(FᵀF − I)``, ``W = ½λ (tr E)² + μ E:E``, ``P = F S``,
  ``A_iJkL = δ_ik S_JL + λ F_iJ F_kL + μ (F Fᵀ)_ik δ_JL + μ F_iL F_kJ``.
* ``neo_hookean`` — the compressible form of Abaqus and CalculiX:
  ``W = C10 (Ī₁ − 3) + (J − 1)²/D1``, ``Ī₁ = J^(−2/3) I₁``, ``C10 = μ/2``,
  ``D1 = 2/K``, with ``μ = E/(2(1+ν))`` and ``K = E/(3(1−2ν))``; with ``G = F⁻ᵀ``,
  ``P = μ J^(−2/3) (F − ⅓ I₁ G) + K (J − 1) J G`` and
  ``A_iJkL = μ J^(−2/3) [δ_ik δ_JL − ⅔ (F_iJ G_kL + G_iJ F_kL) + (2/9) I₁ G_iJ G_kL
  + ⅓ I₁ G_iL G_kJ] + K [(2J − 1) J G_iJ G_kL − (J − 1) J G_iL G_kJ]``.
  ``W = +∞`` where ``J ≤ 0`` (an inverted element; line searches step back).

All three have the same small-strain limit (Lamé λ, μ; for ``neo_hookean``
``K − 2μ/3 = λ``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from vertebra.core.errors import OptionError

_I = np.eye(3)
_I4 = _I[:, None, :, None] * _I[None, :, None, :]          # δ_ik δ_JL as [i, J, k, L]


def lame(youngs_modulus: float, poisson_ratio: float) -> tuple[float, float]:
    """Lamé parameters (λ, μ)."""
    E, nu = youngs_modulus, poisson_ratio
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


class Material(Protocol):
    name: str
    youngs_modulus: float
    poisson_ratio: float

    def evaluate(self, H: np.ndarray, tangent: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(W, P, A)`` at displacement gradients ``H`` (..., 3, 3); ``A`` is None without ``tangent``."""

    def energy(self, H: np.ndarray) -> np.ndarray:
        """``W`` only (line searches)."""


MATERIALS: dict[str, type] = {}


def register_material(cls):
    MATERIALS[cls.name] = cls
    return cls


def get_material(name: str, youngs_modulus: float, poisson_ratio: float) -> "Material":
    """The material registered as ``name`` with these constants."""
    if name not in MATERIALS:
        raise OptionError(f"unknown material {name!r} (known: {', '.join(sorted(MATERIALS))})", field="material")
    if not youngs_modulus > 0:
        raise OptionError(f"youngs_modulus must be > 0, got {youngs_modulus}", field="youngs_modulus")
    if not -1.0 < poisson_ratio < 0.5:
        raise OptionError(f"poisson_ratio must satisfy -1 < ν < 0.5, got {poisson_ratio}", field="poisson_ratio")
    return MATERIALS[name](float(youngs_modulus), float(poisson_ratio))


def green_lagrange(H: np.ndarray) -> np.ndarray:
    """``E = ½(H + Hᵀ + HᵀH)``."""
    Ht = np.swapaxes(H, -1, -2)
    return 0.5 * (H + Ht + Ht @ H)


def cofactor(F: np.ndarray) -> np.ndarray:
    """``cof F = det(F) F⁻ᵀ`` (columns: cross products of the other two columns)."""
    c0, c1, c2 = F[..., :, 0], F[..., :, 1], F[..., :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=-1)


def determinant(H: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", H[..., :, 0], np.cross(H[..., :, 1], H[..., :, 2]))


def jacobian_minus_one(H: np.ndarray) -> np.ndarray:
    """``det(I + H) − 1 = I₁(H) + I₂(H) + I₃(H)`` without cancellation."""
    tr = np.trace(H, axis1=-2, axis2=-1)
    tr2 = np.einsum("...ij,...ji->...", H, H)
    return tr + 0.5 * (tr * tr - tr2) + determinant(H)


def second_piola(material: "Material", H: np.ndarray) -> np.ndarray:
    """``S = F⁻¹ P`` (symmetric for the Cauchy–Green materials)."""
    return np.linalg.solve(H + _I, material.evaluate(H, tangent=False)[1])


def _outer(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A_iJ B_kL`` as [..., i, J, k, L]."""
    return A[..., :, :, None, None] * B[..., None, None, :, :]


def _scalar(x: np.ndarray) -> np.ndarray:
    return x[..., None, None, None, None]


class _Isotropic:
    name = ""

    def __init__(self, youngs_modulus: float, poisson_ratio: float):
        self.youngs_modulus = youngs_modulus
        self.poisson_ratio = poisson_ratio
        self.lam, self.mu = lame(youngs_modulus, poisson_ratio)
        self.bulk = youngs_modulus / (3.0 * (1.0 - 2.0 * poisson_ratio))

    def __repr__(self):
        return f"{type(self).__name__}(E={self.youngs_modulus:g}, nu={self.poisson_ratio:g})"

    def energy(self, H):
        return self.evaluate(H, tangent=False)[0]


@register_material
class LinearElastic(_Isotropic):
    name = "linear"

    def __init__(self, youngs_modulus, poisson_ratio):
        super().__init__(youngs_modulus, poisson_ratio)
        self._A = self.lam * _outer(_I, _I) + self.mu * (_I4 + np.einsum("iL,kJ->iJkL", _I, _I))

    def evaluate(self, H, tangent: bool = True):
        eps = 0.5 * (H + np.swapaxes(H, -1, -2))
        tr = np.trace(eps, axis1=-2, axis2=-1)
        W = 0.5 * self.lam * tr ** 2 + self.mu * np.einsum("...ij,...ij->...", eps, eps)
        P = self.lam * tr[..., None, None] * _I + 2.0 * self.mu * eps
        A = np.broadcast_to(self._A, H.shape[:-2] + (3, 3, 3, 3)) if tangent else None
        return W, P, A


@register_material
class StVenantKirchhoff(_Isotropic):
    name = "svk"

    def evaluate(self, H, tangent: bool = True):
        lam, mu = self.lam, self.mu
        E = green_lagrange(H)
        trE = np.trace(E, axis1=-2, axis2=-1)
        W = 0.5 * lam * trE ** 2 + mu * np.einsum("...ij,...ij->...", E, E)
        S = lam * trE[..., None, None] * _I + 2.0 * mu * E
        F = H + _I
        P = F @ S
        if not tangent:
            return W, P, None
        FFt = F @ np.swapaxes(F, -1, -2)
        A = np.einsum("...JL,ik->...iJkL", S, _I) + lam * _outer(F, F) \
            + mu * np.einsum("...ik,JL->...iJkL", FFt, _I) + mu * np.einsum("...iL,...kJ->...iJkL", F, F)
        return W, P, A


@register_material
class NeoHookean(_Isotropic):
    name = "neo_hookean"

    def evaluate(self, H, tangent: bool = True):
        mu, K = self.mu, self.bulk
        E = green_lagrange(H)
        trE = np.trace(E, axis1=-2, axis2=-1)
        Jm1 = jacobian_minus_one(H)
        J = 1.0 + Jm1
        with np.errstate(invalid="ignore", divide="ignore"):
            # a = J^(−2/3); Ī₁ − 3 = 3 (a − 1) + 2 a tr E  (no cancellation at small strain)
            a_m1 = np.expm1(-2.0 / 3.0 * np.log1p(Jm1))
        a = 1.0 + a_m1
        I1 = 3.0 + 2.0 * trE
        W = 0.5 * mu * (3.0 * a_m1 + 2.0 * a * trE) + 0.5 * K * Jm1 ** 2
        W = np.where(J > 0, W, np.inf)
        F = H + _I
        G = cofactor(F) / J[..., None, None]                              # F⁻ᵀ
        # F − ⅓ I₁ F⁻ᵀ = F⁻ᵀ (FᵀF − ⅓ I₁ I) = F⁻ᵀ (2E − ⅔ tr E I): every term O(E)
        deviator = G @ (2.0 * E - (2.0 / 3.0 * trE)[..., None, None] * _I)
        P = (mu * a)[..., None, None] * deviator + (K * Jm1 * J)[..., None, None] * G
        if not tangent:
            return W, P, None
        s = lambda x: x[..., None, None]                                  # noqa: E731
        beta1 = -2.0 / 3.0 * mu * a
        beta2 = 2.0 / 9.0 * mu * a * I1 + K * (2.0 * J - 1.0) * J
        beta3 = mu * a * I1 / 3.0 - K * Jm1 * J
        # β1 (F⊗G + G⊗F) + β2 G⊗G = (β1 F + β2 G)⊗G + G⊗(β1 F)
        A = _outer(s(beta1) * F + s(beta2) * G, G) + _outer(G, s(beta1) * F) \
            + _scalar(beta3) * np.einsum("...iL,...kJ->...iJkL", G, G)
        diagonal = A.reshape(A.shape[:-4] + (9, 9))                       # δ_ik δ_JL: the 9×9 identity
        diagonal[..., np.arange(9), np.arange(9)] += s(mu * a)[..., 0]
        return W, P, A
