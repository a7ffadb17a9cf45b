"""Unit-slip warnings for a parsed scene (:mod:`vertebra.core.plausibility` says which and why).

:func:`scene_warnings` looks at what the scene itself states — moduli, design mesh sizes,
chamber pressures, cable radii against the design segments' outer radii and the trunk's length,
effector targets against the trunk's length — and warns; it never refuses a scene. The trunk's
length is known when no segment is a catalogue entry (beams and designs state theirs).
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.core import plausibility


def _trunk(scene) -> tuple[list, float | None]:
    """Per vertebra (1..n), the outer radius of the segment ending at it (None where unknown),
    and the trunk's length (None when a segment's length is not stated)."""
    radii, length = [None], 0.0
    for segment in scene.segments:
        if segment.design is not None:
            parameters = segment.design.parameter_dict()
            radius = plausibility.outer_radius(parameters)
            piece = parameters.get("length")
        else:
            radius, piece = None, segment.length if segment.type == "beam" else None
        radii += [radius] * segment.count
        length = None if length is None or not isinstance(piece, (int, float)) else length + segment.count * piece
    return radii, length


def scene_warnings(scene) -> None:
    """Issue a PlausibilityWarning for each value of ``scene`` that looks like a unit slip."""
    source = scene.source
    for i, segment in enumerate(scene.segments):
        if segment.type == "beam":
            plausibility.modulus(segment.youngs_modulus, f"segment[{i}].youngs_modulus", source)
        elif segment.design is not None:
            plausibility.design(segment.design.parameter_dict(), segment.design.mesh_size, source,
                                parameters_field=f"segment[{i}].parameters", mesh_field=f"segment[{i}].mesh_size")
    for k, chamber in enumerate(scene.chambers):
        for name in ("pressure", "min_pressure", "max_pressure"):
            plausibility.pressure(getattr(chamber, name), f"chamber[{k}].{name}", source)
    radii, length = _trunk(scene)
    for k, cable in enumerate(scene.cables):
        known = [r for r in radii[cable.first:cable.last + 1] if r is not None]
        if known:
            plausibility.cable_radius(cable.radius, max(known), f"cable[{k}].radius", source)
        elif length is not None:
            plausibility.cable_length_scale(cable.radius, length, f"cable[{k}].radius", source)
    if length is None:
        return
    for k, effector in enumerate(scene.effectors):
        if effector.target is not None and effector.axis is None:
            distance = math.dist(effector.target, scene.base_position)
            plausibility.reach(distance, length, f"effector[{k}].target", source)


def trajectory_warnings(model, targets, source: str) -> None:
    """Warn when a trajectory's point targets ``(n_steps, n_eff, 3)`` lie far beyond the trunk's
    reach (its length Σ|d0| over the links); one warning, for the farthest step and effector."""
    points = ~np.asarray(model.effector_is_axis, bool)
    if not points.any():
        return
    distance = np.linalg.norm(np.asarray(targets, float)[:, points] - np.asarray(model.scene.base_position), axis=-1)
    distance = np.where(np.isfinite(distance), distance, 0.0)
    step, k = np.unravel_index(np.argmax(distance), distance.shape)
    name = np.asarray(model.effector_names)[points][k]
    plausibility.reach(float(distance[step, k]), float(model.length_scale), f"step {step}, {name}", source)
