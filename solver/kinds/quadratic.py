"""Quadratic links: the linear condensation of a segment (docs/catalogue.md) as an energy of the strain.

A link with compliance blocks ``[[C, G], [Gᵀ, V]]`` (displacement of ``b`` and volume growths
per unit wrench and pressure) stores

    ψ(ξ, p) = ½ eᵀ K e − ½ pᵀ V p,   e = ξ − ξ₀ − A G p,   K = (A C Aᵀ)⁻¹

where ``A = ∂ξ/∂δ`` at rest maps the displacement ``δ = [Δx; Δθ]`` of ``b`` in ``a``'s axes to
the strain (so the linearisation at rest reproduces ``C`` exactly), and a pressure shifts the
rest strain by ``A G p`` (the rest-pose shift ``G p`` of a pressurised entry). Hence ``w = K e``, the
material tangent is ``K``, the chamber forces are ``K A G`` and the volume growth is
``−∂ψ/∂p = (A G)ᵀ K e + V p`` (Maxwell–Betti reciprocity gives the ``Gᵀ`` row). ``K``, ``A G`` and
``V`` are the linear part of a segment's energy (:func:`vertebra.core.energy.linear_part`), the
same as a fitted energy's ψ_lin.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np

from vertebra.core.energy import linear_part
from vertebra.solver.kinds import CompiledLinks, LinkSource, RangeExcess, refuse_scaled_cavities


@dataclass(frozen=True)
class Compliance:
    """The compliance blocks of one link: ``C`` (6, 6), ``G`` (6, k), ``V`` (k, k)."""

    C: np.ndarray
    G: np.ndarray
    V: np.ndarray


@dataclass(frozen=True)
class QuadraticEnergy:
    """Quadratic links, batched (see the module docstring)."""

    links: np.ndarray             # (n,) which links of the trunk
    rest: np.ndarray              # (n, 6) ξ₀
    fitted: ClassVar[bool] = False  # the linear condensation itself: no fitted range
    stiffness: np.ndarray         # (n, 6, 6) K
    pressure_strain: np.ndarray   # (n, 6, m) A G per chamber
    pressure_force: np.ndarray    # (n, m, 6) K A G: the chamber forces
    volume_compliance: np.ndarray  # (m, m) Σ_links V over the chambers each link's cavities serve

    @classmethod
    def compile(cls, links: np.ndarray, compiled: CompiledLinks) -> "QuadraticEnergy":
        of = compiled.source_of_link[links]
        mine = np.unique(of).tolist()            # the sources of other kinds are theirs to compile
        K = np.empty((len(compiled.sources), 6, 6))
        parts = {}
        for s in mine:
            blocks = compiled.sources[s].parameters
            parts[s] = linear_part(blocks.C, blocks.G, blocks.V, compiled.strain_map[s])
            K[s] = parts[s].stiffness
            if not (parts[s].positive and np.all(np.isfinite(blocks.C))):
                raise compiled.error(s, "length, section and moduli give a compliance that is not finite and "
                                        "positive in double precision")
        cavity = compiled.cavity[links]
        n, m = cavity.shape
        P = np.zeros((n, 6, m))
        V = np.zeros((m, m))
        if m:
            for k in np.flatnonzero((cavity >= 0).any(1)):
                part = parts[of[k]]
                served = np.flatnonzero(cavity[k] >= 0)
                P[k][:, served] = part.pressure_map[:, cavity[k, served]]
                V[np.ix_(served, served)] += part.volume_compliance[np.ix_(cavity[k, served], cavity[k, served])]
        stiffness = K[of]
        return cls(links, compiled.rest[of], stiffness, P, np.einsum("nij,njk->nki", stiffness, P), V)

    def scaled(self, scale: np.ndarray) -> "QuadraticEnergy":
        """The links with their energies multiplied by ``scale`` (n,) — a stiffness scale of their
        material. Links with cavities are refused (a scaled material changes their pressure
        response too, which a scale of ψ alone does not capture)."""
        refuse_scaled_cavities(scale, self.pressure_strain.any(axis=(1, 2)))
        return dataclasses.replace(self, stiffness=self.stiffness * scale[:, None, None])

    def prepare(self, pressures: np.ndarray) -> tuple[np.ndarray, float]:
        """The rest strains under ``pressures`` (``ξ₀ + A G p``) and the pressure-only energy
        ``−½ pᵀ V p`` (constant at given pressures). ``pressures`` (B, m) of a batch of samples
        give (B, n, 6) rest strains and (B,) constants."""
        if not pressures.size or not np.any(pressures):
            return self.rest, 0.0
        if pressures.ndim == 2:
            constant = -0.5 * np.add.reduce((pressures @ self.volume_compliance) * pressures, 1)
            return self.rest + (self.pressure_strain @ pressures[:, None, :, None])[..., 0], constant
        return self.rest + self.pressure_strain @ pressures, -0.5 * float(pressures @ self.volume_compliance @ pressures)

    def response(self, xi: np.ndarray, prepared: tuple[np.ndarray, float]) -> tuple[float, np.ndarray, None]:
        """``(Σ ψ, w, None)`` at the strains ``xi`` (n, 6); for a batch (B, n, 6), Σ ψ per sample (B,)."""
        rest, constant = prepared
        e = xi - rest
        w = (self.stiffness @ e[..., None])[..., 0]
        if e.ndim == 2:
            return 0.5 * float(np.vdot(e, w)) + constant, w, None
        return 0.5 * np.add.reduce((e * w).reshape(e.shape[0], -1), 1) + constant, w, None

    def material_tangent(self, xi: np.ndarray, prepared: tuple, kept: None) -> np.ndarray:
        return self.stiffness

    def chamber_forces(self, xi: np.ndarray, prepared: tuple, kept: None) -> np.ndarray:
        return self.pressure_force

    def volume_growth(self, xi: np.ndarray, prepared: tuple, pressures: np.ndarray) -> np.ndarray:
        w = (self.stiffness @ (xi - prepared[0])[:, :, None])[:, :, 0]
        return np.einsum("nij,ni->j", self.pressure_strain, w) + self.volume_compliance @ pressures

    def out_of_range(self, xi: np.ndarray, prepared: tuple) -> tuple[RangeExcess, ...]:
        """None: a quadratic energy is the linear condensation itself, valid at any strain (its
        accuracy at large strain is the link discretisation's and the material's, not a fit's)."""
        return ()


@dataclass(frozen=True)
class QuadraticKind:
    """A link kind whose links are quadratic: the segments of one scene ``type``, each link's
    compliance and rest pose given by ``link(segment, entry)``."""

    name: str
    segment_type: str
    link: Callable[..., LinkSource]
    priority: int = 0
    energy: ClassVar[type] = QuadraticEnergy

    def claims(self, segment, entry) -> bool:
        return segment.type == self.segment_type

    def source(self, segment, entry) -> LinkSource:
        return self.link(segment, entry)
