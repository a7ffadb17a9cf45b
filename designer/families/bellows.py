"""Bellows: a corrugated thin-walled tube whose bore is one sealed cavity.

Radial wall profile ``r_mid(z) = (inner_radius + outer_radius)/2 - A cos(2π N z / L)``
with ``A = (outer_radius - inner_radius - wall_thickness)/2``, inner surface at
``r_mid - wall_thickness/2`` and outer at ``r_mid + wall_thickness/2``: the bore
is ``inner_radius`` at the valleys (and at both ends, where the vertebrae seal it)
and the outside reaches ``outer_radius`` at the crests.
"""

from __future__ import annotations

import math

from vertebra.designer.families.base import (MATERIAL, Family, Parameter, SegmentSymmetry, check_material, register_family,
                                             require)


@register_family
class Bellows(Family):
    name = "bellows"
    description = "corrugated tube, bore sealed by the vertebrae (one cavity)"
    parameters = (
        Parameter("inner_radius", "bore radius at the valleys and ends", unit="m"),
        Parameter("outer_radius", "outer radius at the crests", unit="m"),
        Parameter("wall_thickness", "radial wall thickness", unit="m"),
        Parameter("convolutions", "number of corrugations", default=2, integer=True),
        Parameter("length", "segment length (vertebra to vertebra)", unit="m"),
        *MATERIAL,
    )

    def check(self, p):
        require(p["length"] > 0, "length", f"must be > 0, got {p['length']}")
        require(p["inner_radius"] > 0, "inner_radius", f"must be > 0, got {p['inner_radius']}")
        require(p["wall_thickness"] > 0, "wall_thickness", f"must be > 0, got {p['wall_thickness']}")
        require(p["convolutions"] >= 1, "convolutions", f"must be >= 1, got {p['convolutions']}")
        amplitude = p["outer_radius"] - p["inner_radius"] - p["wall_thickness"]
        require(amplitude >= 0, "outer_radius",
                f"outer_radius - inner_radius - wall_thickness = {amplitude:.6g} must be >= 0 "
                "(the corrugation depth cannot be negative)")
        check_material(p)

    def n_cavities(self, p):
        return 1

    def default_mesh_size(self, p):
        # ~1 quadratic element through the wall (gmsh failed at 2.7 wall thicknesses; thin walls
        # also make AMG stall, so these meshes go to the direct solver — keep them small)
        pitch = p["length"] / p["convolutions"]
        return min(max(1.5 * p["wall_thickness"], pitch / 6.0), p["outer_radius"] / 3.0)

    def symmetry(self, p):
        # a solid of revolution; r_mid(L − z) = r_mid(z), so the ends are alike; the bore is on the axis
        return SegmentSymmetry(order=0, mirror=True, end_flip=True, cavity_angles=(None,))

    def mid_radius(self, z, p):
        amplitude = 0.5 * (p["outer_radius"] - p["inner_radius"] - p["wall_thickness"])
        mean = 0.5 * (p["outer_radius"] + p["inner_radius"])
        return mean - amplitude * math.cos(2 * math.pi * p["convolutions"] * z / p["length"])

    def build(self, occ, p):
        L, t = p["length"], p["wall_thickness"]
        n = 16 * p["convolutions"] + 1
        zs = [L * i / (n - 1) for i in range(n)]
        inner = [occ.addPoint(self.mid_radius(z, p) - t / 2, 0, z) for z in zs]
        outer = [occ.addPoint(self.mid_radius(z, p) + t / 2, 0, z) for z in zs]
        c_in = occ.addSpline(inner)
        c_top = occ.addLine(inner[-1], outer[-1])
        c_out = occ.addSpline(outer[::-1])
        c_bot = occ.addLine(outer[0], inner[0])
        face = occ.addPlaneSurface([occ.addCurveLoop([c_in, c_top, c_out, c_bot])])
        out = occ.revolve([(2, face)], 0, 0, 0, 0, 0, 1, 2 * math.pi)
        return [dt for dt in out if dt[0] == 3]

    def classify(self, point, p):
        x, y, z = point
        rho = math.hypot(x, y)
        r_mid = self.mid_radius(z, p)
        return "cavity_0" if rho < r_mid else "wall"
