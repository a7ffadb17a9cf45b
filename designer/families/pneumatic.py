"""Multi-cavity pneumatic segment: one intervertebral slice of a CBHA-like section.

``chambers`` sealed cylindrical chambers of radius ``chamber_radius`` whose axes
sit at ``chamber_offset`` from the segment axis (the first at ``chamber_angle_deg``
degrees from +x, the others equally spaced), in a solid cylinder of radius
``outer_radius`` with an optional central bore ``inner_radius`` (0 = none). The
chambers run through the slice and are sealed by the vertebrae at both ends.

The geometry code is shared with ``tapered_pneumatic`` (radii changing linearly
along the length): :func:`check_chambers`, :func:`build_chambered`,
:func:`classify_chambered` take bottom and top values.
"""

from __future__ import annotations

import math

from vertebra.designer.families.base import (MATERIAL, Family, Parameter, SegmentSymmetry, check_material, nearest,
                                             register_family, require)

CHAMBER_PARAMETERS = (
    Parameter("chambers", "number of sealed chambers", default=3, integer=True),
    Parameter("chamber_angle_deg", "angle of chamber 0 about +z from +x", default=0.0, unit="deg"),
    Parameter("inner_radius", "central bore radius (0 = no bore)", default=0.0, unit="m"),
)


def chamber_symmetry(p: dict, end_flip: bool) -> SegmentSymmetry:
    """Dihedral symmetry of N equal chambers (mirror planes through the chambers' axes)."""
    n, first = p["chambers"], math.radians(p["chamber_angle_deg"])
    return SegmentSymmetry(order=n, mirror=True, mirror_angle=first, end_flip=end_flip,
                           cavity_angles=tuple(first + 2 * math.pi * k / n for k in range(n)))


def _lerp(a, b, t):
    return a + (b - a) * t


def check_chambers(p: dict, sections: dict[str, tuple[float, float, float]]) -> None:
    """Geometric conditions at each end section (they are linear in z, so the ends suffice).

    ``sections``: label -> (outer_radius, chamber_radius, chamber_offset); the
    parameter names used in messages are derived from the label prefix.
    """
    n = p["chambers"]
    require(p["length"] > 0, "length", f"must be > 0, got {p['length']}")
    require(n >= 1, "chambers", f"must be >= 1, got {n}")
    require(p["inner_radius"] >= 0, "inner_radius", f"must be >= 0, got {p['inner_radius']}")
    for prefix, (outer, radius, offset) in sections.items():
        name = (lambda s: f"{prefix}{s}")
        require(outer > 0, name("outer_radius"), f"must be > 0, got {outer}")
        require(radius > 0, name("chamber_radius"), f"must be > 0, got {radius}")
        require(offset >= 0, name("chamber_offset"), f"must be >= 0, got {offset}")
        wall = outer - offset - radius
        require(wall > 0, name("chamber_offset"),
                f"chambers pierce the outer wall: outer_radius - chamber_offset - chamber_radius = {wall:.6g} must be > 0")
        if n >= 2:
            gap = 2 * offset * math.sin(math.pi / n) - 2 * radius
            require(gap > 0, name("chamber_radius"),
                    f"chambers intersect: 2*chamber_offset*sin(pi/chambers) - 2*chamber_radius = {gap:.6g} must be > 0")
        if p["inner_radius"] > 0:
            web = offset - radius - p["inner_radius"]
            require(web > 0, "inner_radius",
                    f"chambers pierce the central bore: {prefix}chamber_offset - {prefix}chamber_radius - inner_radius = {web:.6g} must be > 0")
        elif n == 1 and offset > 0:
            pass  # an eccentric single chamber is fine
    check_material(p)


def chamber_centres(p: dict, offset: float) -> list[tuple[float, float]]:
    n, first = p["chambers"], math.radians(p["chamber_angle_deg"])
    return [(offset * math.cos(first + 2 * math.pi * k / n),
             offset * math.sin(first + 2 * math.pi * k / n)) for k in range(n)]


def _frustum(occ, z0, z1, centre0, centre1, r0, r1):
    """Solid between two horizontal circles (ruled): a cylinder, cone or oblique frustum."""
    w0 = occ.addCurveLoop([occ.addCircle(centre0[0], centre0[1], z0, r0)])
    w1 = occ.addCurveLoop([occ.addCircle(centre1[0], centre1[1], z1, r1)])
    return occ.addThruSections([w0, w1], makeSolid=True, makeRuled=True)


def build_chambered(occ, p: dict, bottom: tuple, top: tuple) -> list[tuple[int, int]]:
    """bottom/top: (outer_radius, chamber_radius, chamber_offset) at z = 0 and z = length."""
    length = p["length"]
    (R0, r0, d0), (R1, r1, d1) = bottom, top
    if R0 == R1:
        body = [(3, occ.addCylinder(0, 0, 0, 0, 0, length, R0))]
    else:
        body = [(3, occ.addCone(0, 0, 0, 0, 0, length, R0, R1))]
    # tools extend 10 % beyond both end planes (no coplanar boolean faces); the
    # section of a ruled surface between two horizontal circles is a circle, so the
    # holes in the end faces are exact circles of the interpolated radius/centre
    e = 0.1
    tools = []
    for (x0, y0), (x1, y1) in zip(chamber_centres(p, d0), chamber_centres(p, d1)):
        c_lo = (_lerp(x0, x1, -e), _lerp(y0, y1, -e))
        c_hi = (_lerp(x0, x1, 1 + e), _lerp(y0, y1, 1 + e))
        tools += _frustum(occ, -e * length, (1 + e) * length, c_lo, c_hi, _lerp(r0, r1, -e), _lerp(r0, r1, 1 + e))
    if p["inner_radius"] > 0:
        tools.append((3, occ.addCylinder(0, 0, -e * length, 0, 0, (1 + 2 * e) * length, p["inner_radius"])))
    out, _ = occ.cut(body, tools)
    return out


def classify_chambered(point, p: dict, bottom: tuple, top: tuple) -> str:
    x, y, z = point
    t = z / p["length"]
    R = _lerp(bottom[0], top[0], t)
    r = _lerp(bottom[1], top[1], t)
    d = _lerp(bottom[2], top[2], t)
    rho = math.hypot(x, y)
    distances = {"wall": abs(rho - R)}
    if p["inner_radius"] > 0:
        distances["wall_bore"] = abs(rho - p["inner_radius"])
    for k, (cx, cy) in enumerate(chamber_centres(p, d)):
        distances[f"cavity_{k}"] = abs(math.hypot(x - cx, y - cy) - r)
    label = nearest(distances)
    return "wall" if label.startswith("wall") else label


@register_family
class Pneumatic(Family):
    name = "pneumatic"
    description = "solid cylinder with N sealed chambers at a radius (CBHA-like slice)"
    parameters = (
        Parameter("outer_radius", "outer radius", unit="m"),
        Parameter("length", "segment length (vertebra to vertebra)", unit="m"),
        Parameter("chamber_radius", "radius of each chamber", unit="m"),
        Parameter("chamber_offset", "distance of the chamber axes from the segment axis", unit="m"),
        *CHAMBER_PARAMETERS,
        *MATERIAL,
    )

    def _section(self, p):
        return (p["outer_radius"], p["chamber_radius"], p["chamber_offset"])

    def check(self, p):
        check_chambers(p, {"": self._section(p)})

    def n_cavities(self, p):
        return p["chambers"]

    def default_mesh_size(self, p):
        return min(p["outer_radius"] / 3.0, 1.2 * p["chamber_radius"], p["length"] / 3.0)

    def symmetry(self, p):
        return chamber_symmetry(p, end_flip=True)

    def build(self, occ, p):
        s = self._section(p)
        return build_chambered(occ, p, s, s)

    def classify(self, point, p):
        s = self._section(p)
        return classify_chambered(point, p, s, s)
