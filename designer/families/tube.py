"""Hollow circular tube (open bore, no cavity: the bore is not sealed)."""

from __future__ import annotations

from vertebra.designer.families.base import (AXISYMMETRIC, MATERIAL, Family, Parameter, check_material, register_family,
                                             require)


@register_family
class Tube(Family):
    name = "tube"
    description = "hollow circular cylinder (open bore)"
    parameters = (
        Parameter("outer_radius", "outer radius", unit="m"),
        Parameter("inner_radius", "bore radius", unit="m"),
        Parameter("length", "segment length (vertebra to vertebra)", unit="m"),
        *MATERIAL,
    )

    def check(self, p):
        require(p["length"] > 0, "length", f"must be > 0, got {p['length']}")
        require(p["inner_radius"] > 0, "inner_radius", f"must be > 0 (use family 'rod' for a solid), got {p['inner_radius']}")
        require(p["outer_radius"] > p["inner_radius"], "outer_radius",
                f"wall thickness outer_radius - inner_radius = {p['outer_radius'] - p['inner_radius']:.6g} must be > 0")
        check_material(p)

    def default_mesh_size(self, p):
        wall = p["outer_radius"] - p["inner_radius"]
        return min(max(wall / 1.5, p["outer_radius"] / 4.0), p["length"] / 4.0)

    def build(self, occ, p):
        outer = occ.addCylinder(0, 0, 0, 0, 0, p["length"], p["outer_radius"])
        inner = occ.addCylinder(0, 0, -p["length"], 0, 0, 3 * p["length"], p["inner_radius"])
        out, _ = occ.cut([(3, outer)], [(3, inner)])
        return out

    def symmetry(self, p):
        return AXISYMMETRIC

    def classify(self, point, p):
        return "wall"
