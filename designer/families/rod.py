"""Solid circular rod: the simplest segment, and the closed-form reference case."""

from __future__ import annotations

from vertebra.designer.families.base import (AXISYMMETRIC, MATERIAL, Family, Parameter, check_material, register_family,
                                             require)


@register_family
class Rod(Family):
    name = "rod"
    description = "solid circular cylinder of given radius and length"
    parameters = (
        Parameter("radius", "rod radius", unit="m"),
        Parameter("length", "segment length (vertebra to vertebra)", unit="m"),
        *MATERIAL,
    )

    def check(self, p):
        require(p["radius"] > 0, "radius", f"must be > 0, got {p['radius']}")
        require(p["length"] > 0, "length", f"must be > 0, got {p['length']}")
        check_material(p)

    def default_mesh_size(self, p):
        return min(p["radius"] / 2.0, p["length"] / 4.0)

    def build(self, occ, p):
        return [(3, occ.addCylinder(0, 0, 0, 0, 0, p["length"], p["radius"]))]

    def outer_radius(self, p):
        return p["radius"]

    def symmetry(self, p):
        return AXISYMMETRIC

    def classify(self, point, p):
        return "wall"
