"""Rigid vertebra: a disc with cable holes (and an optional central bore).

Not a catalogue entry: its mass, centre of mass and inertia follow from the
geometry and density in closed form, and go into the scene as
``vertebra = { mass = .., center_of_mass = [..], inertia = [..] }``. The disc is
centred on the vertebra frame (z from −thickness/2 to +thickness/2); hole k sits
at ``hole_offset`` from the axis, at ``hole_angle_deg + 360°·k/holes`` from +x —
the ``radius``/``angle_deg`` of a scene ``[[cable]]`` through it.
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.designer.families.base import Family, Parameter, require

VERTEBRA_PARAMETERS = (
    Parameter("radius", "disc radius", unit="m"),
    Parameter("thickness", "disc thickness along z", unit="m"),
    Parameter("density", "mass density", unit="kg/m^3"),
    Parameter("holes", "number of cable holes", default=0, integer=True),
    Parameter("hole_radius", "radius of each cable hole", default=0.0, unit="m"),
    Parameter("hole_offset", "distance of the hole centres from the axis", default=0.0, unit="m"),
    Parameter("hole_angle_deg", "angle of hole 0 about +z from +x", default=0.0, unit="deg"),
    Parameter("inner_radius", "central bore radius (0 = none)", default=0.0, unit="m"),
)


class VertebraDisc(Family):
    """Parameters and conditions of a rigid vertebra (not a segment family: not registered)."""

    name = "vertebra"
    parameters = VERTEBRA_PARAMETERS
    is_segment = False

    def check(self, p):
        require(p["radius"] > 0, "radius", f"must be > 0, got {p['radius']}")
        require(p["thickness"] > 0, "thickness", f"must be > 0, got {p['thickness']}")
        require(p["density"] >= 0, "density", f"must be >= 0, got {p['density']}")
        require(p["holes"] >= 0, "holes", f"must be >= 0, got {p['holes']}")
        require(0 <= p["inner_radius"] < p["radius"], "inner_radius",
                f"must satisfy 0 <= inner_radius < radius, got {p['inner_radius']}")
        if p["holes"] == 0:
            return
        n, r, d = p["holes"], p["hole_radius"], p["hole_offset"]
        require(r > 0, "hole_radius", f"must be > 0 when holes > 0, got {r}")
        rim = p["radius"] - d - r
        require(rim > 0, "hole_offset", f"holes pierce the rim: radius - hole_offset - hole_radius = {rim:.6g} must be > 0")
        if p["inner_radius"] > 0:
            web = d - r - p["inner_radius"]
            require(web > 0, "hole_offset",
                    f"holes pierce the central bore: hole_offset - hole_radius - inner_radius = {web:.6g} must be > 0")
        if n >= 2:
            gap = 2 * d * math.sin(math.pi / n) - 2 * r
            require(gap > 0, "hole_radius",
                    f"holes intersect: 2*hole_offset*sin(pi/holes) - 2*hole_radius = {gap:.6g} must be > 0")


def canonical_vertebra(parameters: dict) -> dict:
    return VertebraDisc().canonical(dict(parameters))


def _cylinder(mass: float, radius: float, thickness: float, x: float, y: float) -> np.ndarray:
    """Inertia tensor about the origin of a z-cylinder centred at (x, y, 0)."""
    I = np.diag([mass * (3 * radius ** 2 + thickness ** 2) / 12] * 2 + [mass * radius ** 2 / 2])
    d = np.array([x, y, 0.0])
    return I + mass * (d @ d * np.eye(3) - np.outer(d, d))


def vertebra_properties(parameters: dict) -> dict:
    """Mass (kg), centre of mass (m, vertebra frame), inertia about the centre of mass (kg m²),
    hole positions and the scene snippet values."""
    p = canonical_vertebra(parameters)
    rho, t = p["density"], p["thickness"]
    parts = [(+1, p["radius"], 0.0, 0.0)]
    if p["inner_radius"] > 0:
        parts.append((-1, p["inner_radius"], 0.0, 0.0))
    holes = []
    for k in range(p["holes"]):
        angle = math.radians(p["hole_angle_deg"]) + 2 * math.pi * k / p["holes"]
        x, y = p["hole_offset"] * math.cos(angle), p["hole_offset"] * math.sin(angle)
        holes.append({"position": [x, y], "radius": p["hole_offset"], "angle_deg": math.degrees(angle)})
        parts.append((-1, p["hole_radius"], x, y))
    mass, first, inertia = 0.0, np.zeros(3), np.zeros((3, 3))
    for sign, r, x, y in parts:
        m = sign * rho * math.pi * r ** 2 * t
        mass += m
        first += m * np.array([x, y, 0.0])
        inertia += _cylinder(m, r, t, x, y)
    com = first / mass if mass > 0 else np.zeros(3)
    com[np.abs(com) < 1e-12 * p["radius"]] = 0.0          # round-off of symmetric hole patterns
    inertia_com = inertia - mass * (com @ com * np.eye(3) - np.outer(com, com))
    return {"parameters": p, "mass": mass, "center_of_mass": com.tolist(), "inertia": inertia_com.tolist(),
            "thickness": t, "holes": holes}


def vertebra_snippet(properties: dict) -> str:
    """Scene-ready TOML: ``vertebra = { mass = .., center_of_mass = [..], inertia = [..] }``."""
    def num(x):
        return f"{x:.6g}" if abs(x) > 1e-300 else "0.0"
    com = ", ".join(num(v) for v in properties["center_of_mass"])
    inertia = ", ".join(num(v) for row in properties["inertia"] for v in row)
    lines = [f"vertebra = {{ mass = {num(properties['mass'])}, center_of_mass = [{com}], inertia = [{inertia}] }}"]
    for k, hole in enumerate(properties["holes"]):
        lines.append(f"# cable hole {k}: radius = {hole['radius']:.6g}, angle_deg = {hole['angle_deg']:.6g}")
    return "\n".join(lines)
