"""Tapered multi-cavity pneumatic segment: outer radius, chamber radius and
chamber offset change linearly from the bottom (z = 0) to the top (z = length)."""

from __future__ import annotations

from vertebra.designer.families.base import MATERIAL, Family, Parameter, register_family
from vertebra.designer.families.pneumatic import (CHAMBER_PARAMETERS, build_chambered, chamber_symmetry, check_chambers,
                                                  classify_chambered)


@register_family
class TaperedPneumatic(Family):
    name = "tapered_pneumatic"
    description = "pneumatic segment whose radii change linearly along its length"
    parameters = (
        Parameter("bottom_outer_radius", "outer radius at z = 0", unit="m"),
        Parameter("top_outer_radius", "outer radius at z = length", unit="m"),
        Parameter("length", "segment length (vertebra to vertebra)", unit="m"),
        Parameter("bottom_chamber_radius", "chamber radius at z = 0", unit="m"),
        Parameter("top_chamber_radius", "chamber radius at z = length", unit="m"),
        Parameter("bottom_chamber_offset", "chamber axis distance from the segment axis at z = 0", unit="m"),
        Parameter("top_chamber_offset", "chamber axis distance from the segment axis at z = length", unit="m"),
        *CHAMBER_PARAMETERS,
        *MATERIAL,
    )

    def _sections(self, p):
        return ((p["bottom_outer_radius"], p["bottom_chamber_radius"], p["bottom_chamber_offset"]),
                (p["top_outer_radius"], p["top_chamber_radius"], p["top_chamber_offset"]))

    def check(self, p):
        bottom, top = self._sections(p)
        check_chambers(p, {"bottom_": bottom, "top_": top})

    def n_cavities(self, p):
        return p["chambers"]

    def default_mesh_size(self, p):
        R = min(p["bottom_outer_radius"], p["top_outer_radius"])
        r = min(p["bottom_chamber_radius"], p["top_chamber_radius"])
        return min(R / 3.0, 1.2 * r, p["length"] / 3.0)

    def outer_radius(self, p):
        return max(p["bottom_outer_radius"], p["top_outer_radius"])

    def symmetry(self, p):
        # the taper makes the two ends different: no end flip
        return chamber_symmetry(p, end_flip=False)

    def build(self, occ, p):
        return build_chambered(occ, p, *self._sections(p))

    def classify(self, point, p):
        return classify_chambered(point, p, *self._sections(p))
