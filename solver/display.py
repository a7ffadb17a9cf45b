"""Display geometry of a trunk, shared by the pictures (:mod:`~vertebra.solver.report`) and the
ParaView files (:mod:`~vertebra.solver.paraview`): how thick the backbone is at each frame, how
large the vertebra discs are, where the cables run.

Only the backbone radius is physical (from the scene's beam sections or the catalogue entries'
parameters); disc and cable radii are for display.
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.core.lie import qrotate

DEFAULT_RADIUS = 0.02      # backbone radius as a fraction of the trunk length when nothing says it
DISC_OVER_HOLES = 1.2      # vertebra disc radius over the largest cable hole radius
CABLE_OVER_HOLE = 0.05     # displayed cable radius over its hole radius (cables have no radius in a scene)


def section_outer_radius(section) -> float:
    """Outer radius of the tube (or solid circle) with the section's area ``A`` and mean second
    moment ``Ī``: ``r_o² = (4Ī/A + A/π)/2`` (exact for circles and tubes)."""
    inertia = 0.5 * (section.Ixx + section.Iyy)
    return math.sqrt(0.5 * (4.0 * inertia / section.area + section.area / math.pi))


def _entry_radius(parameters: dict, end: str) -> float | None:
    """A catalogue entry's outer radius at its ``end`` ("bottom" at frame a, "top" at frame b)
    from its parameters (``<end>_outer_radius``, ``outer_radius`` or ``radius``)."""
    for name in (f"{end}_outer_radius", "outer_radius", "radius"):
        value = parameters.get(name)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
            return float(value)
    return None


def frame_radii(model) -> np.ndarray:
    """Backbone radius (m) at every frame: each link's radius at its top frame (the base frame
    takes the first link's bottom). Beam links: :func:`section_outer_radius`; entry links: the
    entry's outer radius parameter; otherwise ``DEFAULT_RADIUS`` × the trunk length."""
    fallback = DEFAULT_RADIUS * model.length_scale
    entries = model.entries
    bottom, top = [], []
    for segment in model.scene.segments:
        if segment.section is not None:
            r0 = r1 = section_outer_radius(segment.section)
        else:
            entry = entries.get(segment.entry)
            parameters = entry.parameters if entry is not None else {}
            r0, r1 = _entry_radius(parameters, "bottom"), _entry_radius(parameters, "top")
        links = segment.count * segment.elements
        bottom += [r0 or fallback] * links
        top += [r1 or fallback] * links
    return np.array([bottom[0]] + top, dtype=float)


def vertebra_radius(model) -> np.ndarray:
    """Display radius of each vertebra disc (m): ``DISC_OVER_HOLES`` × the largest cable hole
    radius, at least the backbone radius there."""
    holes = max((c.radius for c in model.scene.cables), default=0.0)
    return np.maximum(DISC_OVER_HOLES * holes, frame_radii(model)[model.vertebra_frames])


def cable_radii(model) -> np.ndarray:
    """Display radius of each cable (m): ``CABLE_OVER_HOLE`` × its hole radius (a central cable:
    the same fraction of the largest hole radius, or of the backbone's)."""
    holes = np.array([c.radius for c in model.scene.cables], dtype=float)
    floor = holes.max(initial=0.0) or float(frame_radii(model).max())
    return CABLE_OVER_HOLE * np.where(holes > 0, holes, floor)


def cable_paths(model, state) -> list[np.ndarray]:
    """World polyline of each cable through its holes (m)."""
    return model.trunk.cables.paths(state.positions, state.quaternions)


def disc_rims(model, state, sides: int = 32) -> np.ndarray:
    """Rim points ``(n_vertebrae, sides, 3)`` of the vertebra discs in their frames' x–y planes."""
    angle = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    unit = np.stack([np.cos(angle), np.sin(angle), np.zeros(sides)], -1)
    frames = model.vertebra_frames
    circles = vertebra_radius(model)[:, None, None] * unit[None]
    q = np.broadcast_to(state.quaternions[frames][:, None, :], circles.shape[:2] + (4,))
    return state.positions[frames][:, None, :] + qrotate(q, circles)
