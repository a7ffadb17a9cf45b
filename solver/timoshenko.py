"""Analytic beam sections and their cantilever compliance (Timoshenko).

A uniform beam of length ``l`` clamped at frame ``a`` and loaded at frame ``b`` has a
closed-form 6×6 compliance: displacement ``[Δx; Δθ]`` of ``b`` in
``a``'s axes per unit wrench ``[f; m]`` at ``b``'s origin. The beam axis is local +z;
``Ixx`` governs bending in the y–z plane (deflection along y), ``Iyy`` in the x–z plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Section:
    """Cross-section properties. ``shear_area_*`` = κ·A; ``inf`` means shear-rigid."""

    area: float
    Ixx: float
    Iyy: float
    J: float
    shear_area_x: float = math.inf
    shear_area_y: float = math.inf

    def __post_init__(self):
        for name in ("area", "Ixx", "Iyy", "J", "shear_area_x", "shear_area_y"):
            value = getattr(self, name)
            if not (value > 0.0):
                raise ValueError(f"section {name} = {value!r} must be positive")

    @classmethod
    def circle(cls, radius: float, poisson_ratio: float) -> "Section":
        area = math.pi * radius ** 2
        inertia = math.pi * radius ** 4 / 4.0
        kappa = 6.0 * (1.0 + poisson_ratio) / (7.0 + 6.0 * poisson_ratio)  # Cowper (1966)
        return cls(area, inertia, inertia, 2.0 * inertia, kappa * area, kappa * area)

    @classmethod
    def tube(cls, outer_radius: float, inner_radius: float, poisson_ratio: float) -> "Section":
        area = math.pi * (outer_radius ** 2 - inner_radius ** 2)
        inertia = math.pi * (outer_radius ** 4 - inner_radius ** 4) / 4.0
        m2 = (inner_radius / outer_radius) ** 2
        nu = poisson_ratio
        kappa = 6.0 * (1 + nu) * (1 + m2) ** 2 / ((7 + 6 * nu) * (1 + m2) ** 2 + (20 + 12 * nu) * m2)  # Cowper
        return cls(area, inertia, inertia, 2.0 * inertia, kappa * area, kappa * area)


def timoshenko_compliance(length: float, youngs_modulus: float, shear_modulus: float,
                          section: Section) -> np.ndarray:
    """6×6 cantilever compliance of a uniform Timoshenko beam (tip wrench → tip displacement)."""
    l, E, G, s = length, youngs_modulus, shear_modulus, section
    C = np.zeros((6, 6))
    C[0, 0] = l ** 3 / (3 * E * s.Iyy) + l / (G * s.shear_area_x)
    C[1, 1] = l ** 3 / (3 * E * s.Ixx) + l / (G * s.shear_area_y)
    C[2, 2] = l / (E * s.area)
    C[3, 3] = l / (E * s.Ixx)
    C[4, 4] = l / (E * s.Iyy)
    C[5, 5] = l / (G * s.J)
    C[0, 4] = C[4, 0] = l ** 2 / (2 * E * s.Iyy)      # f_x bends about +y
    C[1, 3] = C[3, 1] = -l ** 2 / (2 * E * s.Ixx)     # f_y bends about −x
    return C
