"""Loads and parameters that change between solves without compiling the scene again.

A compiled :class:`~vertebra.solver.trunk.Trunk` is read-only. :class:`Parameters` names what a
robot's operator or a calibration changes at run time — gravity, dead loads, follower loads,
the tendons' spring rates and pretensions, a stiffness scale per segment, the cables' hole
radii and angles — and :func:`reparameterise` returns a new trunk that shares everything else
with the compiled one (frames, band layout, rest state, link energies), as scikit-fem's mesh
transforms return new meshes: a new load costs microseconds, not a compilation.

The base pose is not among them: a rigid motion of the base moves the equilibrium rigidly, so a
measurement frame is an output transform (see docs/calibration.md); gravity and dead loads are
given in world axes, follower loads in their vertebra's own axes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from vertebra.core.errors import OptionError
from vertebra.core.lie import qmatrix


@dataclasses.dataclass(frozen=True, eq=False)
class Parameters:
    """The run-time inputs of a trunk (read-only arrays; build one with
    :meth:`~vertebra.solver.model.TrunkModel.with_parameters`)."""

    gravity: np.ndarray             # (3,) m/s², world axes (zeros: none)
    dead: np.ndarray                # (n_frames, 6) forces and moments in world axes, at the frames
    cable_stiffness: np.ndarray     # (n_cables,) N/m of the stroke-driven tendons (0 for the others)
    pretension: np.ndarray          # (n_cables,) N of the stroke-driven tendons at zero stroke
    stiffness_scale: np.ndarray     # (n_segments,) multiplies every link energy of the segment
    hole_radius: np.ndarray         # (n_cables,) m, the holes' distance from the axis
    hole_angle: np.ndarray          # (n_cables,) rad, about local +z from local +x
    friction: np.ndarray            # (n_cables,) μ of the capstan law at the cable's holes (solver/friction.py)
    follower: np.ndarray            # (n_frames, 6) forces and moments in each frame's own axes, at the frames

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not np.all(np.isfinite(value)):
                raise OptionError(f"non-finite values in {field.name}", field=field.name)
            value.flags.writeable = False

    @classmethod
    def of_trunk(cls, trunk) -> "Parameters":
        """The values the scene gave (what the compiled trunk holds)."""
        cables = trunk.scene.cables
        gravity = np.zeros(3) if trunk.loads.gravity is None else np.array(trunk.loads.gravity, float)
        return cls(gravity, np.array(trunk.loads.dead, float),
                   np.array(trunk.actuators.cable_stiffness), np.array(trunk.actuators.pretension),
                   np.ones(len(trunk.scene.segments)), np.array([c.radius for c in cables], float),
                   np.array([c.angle for c in cables], float), np.array(trunk.actuators.friction),
                   np.array(trunk.loads.follower, float))

    def replace(self, **changes) -> "Parameters":
        """A copy with ``changes`` (whole arrays, shape-checked)."""
        for name, value in changes.items():
            old = getattr(self, name)
            value = np.asarray(value, float)
            if value.shape != old.shape:
                raise OptionError(f"expected shape {old.shape}, got {value.shape}", field=name)
            changes[name] = value.copy()
        return dataclasses.replace(self, **changes)


def parameters_of(trunk, base: Parameters, changes: Mapping) -> Parameters:
    """``base`` with ``changes`` given by name: ``gravity`` (3 values), ``dead`` and ``follower``
    (``{vertebra: [fx, fy, fz, mx, my, mz]}``, replacing that vertebra's load; a follower load
    in the vertebra's own axes),
    ``cable_stiffness`` / ``pretension`` / ``hole_radius`` / ``hole_angle`` / ``friction`` (``{cable name: value}``;
    angles in rad) and ``stiffness_scale`` (``{segment index: value}``), or whole arrays."""
    names = list(trunk.actuators.names[:trunk.actuators.n_cables])
    n_segments = len(trunk.scene.segments)
    n_vertebrae = trunk.frames.vertebra.size
    arrays = {}
    for name, value in changes.items():
        if not hasattr(base, name):
            known = ", ".join(f.name for f in dataclasses.fields(Parameters))
            raise OptionError(f"unknown parameter {name!r} (known: {known})", field=name)
        if not isinstance(value, Mapping):
            arrays[name] = value
            continue
        array = np.array(getattr(base, name))
        for key, item in value.items():
            if name in ("dead", "follower"):
                index = _index(key, n_vertebrae, name, "vertebra")
                array[trunk.frames.vertebra[index]] = _vector(item, 6, name)
            elif name == "stiffness_scale":
                array[_index(key, n_segments, name, "segment")] = float(item)
            else:
                if key not in names:
                    raise OptionError(f"unknown cable {key!r} (cables: {', '.join(names) or 'none'})", field=name)
                array[names.index(key)] = float(item)
        arrays[name] = array
    if "gravity" in arrays:
        arrays["gravity"] = _vector(arrays["gravity"], 3, "gravity")
    parameters = base.replace(**arrays)
    _check(trunk, parameters)
    return parameters


def _index(key, count: int, name: str, what: str) -> int:
    if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not -count <= int(key) < count:
        raise OptionError(f"{what} {key!r} out of range (0..{count - 1}, or negative from the end)", field=name)
    return int(key) % count


def _vector(value, size: int, name: str) -> np.ndarray:
    array = np.asarray(value, float).reshape(-1)
    if array.size != size:
        raise OptionError(f"expected {size} values, got {array.size}", field=name)
    return array


def _check(trunk, parameters: Parameters) -> None:
    actuators = trunk.actuators
    tendons = actuators.stroke_driven
    if np.any(parameters.cable_stiffness[tendons] <= 0.0):
        raise OptionError("a stroke-driven tendon's spring rate must be positive", field="cable_stiffness")
    if np.any(parameters.cable_stiffness[~tendons] != 0.0) or np.any(parameters.pretension[~tendons] != 0.0):
        raise OptionError("spring rates and pretensions apply to stroke-driven tendons only", field="cable_stiffness")
    if np.any(parameters.stiffness_scale <= 0.0):
        raise OptionError("a stiffness scale must be positive", field="stiffness_scale")
    if np.any(parameters.hole_radius < 0.0):
        raise OptionError("a hole's distance from the axis must not be negative", field="hole_radius")
    if np.any(parameters.friction < 0.0):
        raise OptionError("a friction coefficient must not be negative", field="friction")


def reparameterise(trunk, parameters: Parameters):
    """The trunk with ``parameters``: the loads, the tendons, the link energies of scaled segments
    and the cable routing are new; every other part is the compiled trunk's own."""
    from vertebra.solver.trunk import Loads, reassemble      # lazy: trunk imports this module's users

    changes = {}
    compiled = Parameters.of_trunk(trunk.compiled or trunk)
    gravity = parameters.gravity if np.any(parameters.gravity) else None
    dead = parameters.dead
    changes["loads"] = Loads.of(dead, gravity, parameters.follower, bool(np.any(trunk.frames.mass)))
    changes["actuators"] = dataclasses.replace(trunk.actuators, cable_stiffness=parameters.cable_stiffness,
                                               pretension=parameters.pretension, friction=parameters.friction)
    if not (np.array_equal(parameters.hole_radius, compiled.hole_radius)
            and np.array_equal(parameters.hole_angle, compiled.hole_angle)):
        changes["cables"] = trunk.cables.with_holes(parameters.hole_radius, parameters.hole_angle)
    scale = parameters.stiffness_scale
    if np.any(scale != 1.0):
        per_link = scale[trunk.links.segment]
        base_links = (trunk.compiled or trunk).links
        changes["links"] = dataclasses.replace(
            base_links, energies=tuple(energy.scaled(per_link[energy.links]) for energy in base_links.energies))
    elif trunk.compiled is not None:
        changes["links"] = trunk.compiled.links
    return reassemble(trunk, changes)
