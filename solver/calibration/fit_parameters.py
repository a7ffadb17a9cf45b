"""The calibration parameters: what can be fitted, by name, and how each value acts.

Every quantity a calibration may change is an *element* of :class:`Values` (one stiffness
scale per segment, one hole-angle and hole-radius correction per cable, one axial stiffness
and pretension per driven tendon, the pose of the scene's world in the measurement frame and
each marker's offset). A *parameter* is one scalar that sets one or more elements to its
value (a shared parameter, e.g. one stiffness scale for every segment). Parameters are chosen
by specification strings::

    KIND                 one parameter shared by every element of the kind
    KIND.*               one parameter per element
    KIND.A+B+C           one parameter shared by elements A, B and C
    KIND.A               the element A alone
    ...=LOW:HIGH         bounds (in the parameter's unit; either side may be empty)

Kinds (:data:`KINDS`): ``stiffness`` (scale of a segment's E and G; members: segment index),
``angle`` (hole-angle correction, rad; members: cable), ``radius`` (hole-radius correction, m;
cable), ``cable_stiffness`` (spring rate, N/m; a driven cable), ``pretension`` (N at zero stroke; a
driven cable),
``frame`` (members x, y, z in m, rx, ry, rz as a rotation vector in rad), ``marker``
(offset of a marker, m; members ``NAME.x``, ``NAME.y``, ``NAME.z``), ``friction`` (μ at a driven
cable's holes, docs/friction.md: a calibration with friction predicts the samples as one
time-ordered sequence, :mod:`~vertebra.solver.calibration.sequence`), ``backlash`` (play of a
driven tendon's transmission, m: the stroke that reaches the tendon lags the command by up to
this much in the direction it last moved, :func:`~vertebra.solver.calibration.data.play`; the
samples are then a time-ordered sequence), ``lag`` (time constant of a driven tendon's stroke, s:
the stroke relaxes towards the command at this rate between the samples' times,
:func:`~vertebra.solver.calibration.data.lag`; the mapping names a time column),
``backlash_rate`` (growth of the play with the tendon's tension, m/N: the play is
``backlash + backlash_rate·T``, :mod:`~vertebra.solver.calibration.tension_play`),
``entry_friction`` (N: friction at a tendon's entry into the robot; a released tendon slides back
in only while its tension exceeds it, :mod:`~vertebra.solver.calibration.tension_play`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import OptionError

__all__ = ["KINDS", "Kind", "ParameterSet", "Values", "initial_values", "parse_parameters"]


@dataclass(frozen=True)
class Values:
    """Every element a calibration may change (SI units, radians)."""

    stiffness: np.ndarray        # (n_segments,) scale of E and G
    angle: np.ndarray            # (n_cables,) hole-angle correction of every scene cable, rad
    radius: np.ndarray           # (n_cables,) hole-radius correction, m
    cable_stiffness: np.ndarray  # (n_cables,) N/m of the stroke-driven tendons (0 for the others)
    pretension: np.ndarray       # (n_cables,) N of the stroke-driven tendons at zero stroke
    frame: np.ndarray            # (6,) world origin (m) and rotation vector (rad) in the measurement frame
    marker: np.ndarray           # (n_markers, 3) offsets, m
    friction: np.ndarray         # (n_cables,) μ of the capstan law at a cable's holes (0: frictionless)
    backlash: np.ndarray         # (n_cables,) play between a driven tendon's command and its stroke, m
    lag: np.ndarray              # (n_cables,) time constant of a driven tendon's stroke behind its command, s
    backlash_rate: np.ndarray    # (n_cables,) growth of a driven tendon's play with its tension, m/N
    entry_friction: np.ndarray   # (n_cables,) friction force holding a released tendon's tension at its entry, N

    def get(self, kind: str, index) -> float:
        return float(getattr(self, kind)[index])

    def with_elements(self, elements) -> "Values":
        """A copy with ``elements`` ((kind, index), value) pairs set."""
        arrays = {kind: getattr(self, kind).copy() for kind in KINDS}
        for (kind, index), value in elements:
            arrays[kind][index] = value
        return Values(**arrays)

    def model_key(self) -> tuple:
        """What a model build depends on (segment stiffness, hole geometry)."""
        return (tuple(self.stiffness), tuple(self.angle), tuple(self.radius))


@dataclass(frozen=True)
class Kind:
    unit: str
    doc: str


KINDS = {
    "stiffness": Kind("", "scale of a segment's Young's and shear moduli"),
    "angle": Kind("rad", "correction of a cable's hole angle"),
    "radius": Kind("m", "correction of a cable's hole radius"),
    "cable_stiffness": Kind("N/m", "spring rate of a driven tendon"),
    "pretension": Kind("N", "tension of a driven tendon at zero command (negative: slack)"),
    "frame": Kind("m | rad", "pose of the scene's world in the measurement frame"),
    "marker": Kind("m", "offset of a marker on its vertebra"),
    "friction": Kind("", "friction coefficient μ at a driven tendon's holes (capstan law; the samples are "
                         "then a time-ordered sequence)"),
    "backlash": Kind("m", "play between a driven tendon's command and the stroke that reaches it (the "
                          "samples are then a time-ordered sequence)"),
    "backlash_rate": Kind("m/N", "growth of a driven tendon's play with the tension it carries (the samples are "
                                 "then a time-ordered sequence)"),
    "entry_friction": Kind("N", "friction at a driven tendon's entry into the robot: a released tendon keeps up "
                                "to this tension (the samples are then a time-ordered sequence)"),
    "lag": Kind("s", "time constant with which a driven tendon's stroke follows its command (the samples are "
                     "then a time-ordered sequence with times)"),
}


def initial_values(scene, mapping, model) -> Values:
    """The elements as the scene (compiled into ``model``) and the mapping give them (no correction)."""
    return Values(stiffness=np.ones(len(scene.segments)),
                  angle=np.zeros(len(scene.cables)), radius=np.zeros(len(scene.cables)),
                  cable_stiffness=np.array(model.compiled.actuators.cable_stiffness, float),
                  pretension=np.array(model.compiled.actuators.pretension, float),
                  frame=np.array(mapping.frame_position + mapping.frame_rotation),
                  marker=np.array([m.offset for m in mapping.markers]),
                  friction=np.array(model.compiled.actuators.friction, float),
                  backlash=np.zeros(len(scene.cables)), lag=np.zeros(len(scene.cables)),
                  backlash_rate=np.zeros(len(scene.cables)), entry_friction=np.zeros(len(scene.cables)))


def _members(kind: str, scene, mapping) -> dict:
    """Member name -> element index of ``kind``."""
    if kind == "stiffness":
        return {str(i): i for i in range(len(scene.segments))}
    if kind in ("angle", "radius"):
        return {c.name: i for i, c in enumerate(scene.cables)}
    if kind in ("cable_stiffness", "pretension", "friction", "backlash", "backlash_rate", "entry_friction", "lag"):
        names = [c.name for c in scene.cables]
        return {a.cable: names.index(a.cable) for a in mapping.actuators if a.cable in names}
    if kind == "frame":
        return {c: i for i, c in enumerate(("x", "y", "z", "rx", "ry", "rz"))}
    return {f"{m.name}.{c}": (i, j) for i, m in enumerate(mapping.markers) for j, c in enumerate("xyz")}


@dataclass(frozen=True)
class ParameterSet:
    """The fitted parameters: names, the elements each sets, initial values, bounds and the
    typical size of a change (the optimiser's scaling)."""

    names: tuple
    elements: tuple       # per parameter: tuple of (kind, index)
    initial: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    typical: np.ndarray
    base: Values          # the values of every element not fitted

    def __len__(self) -> int:
        return len(self.names)

    def values(self, x) -> Values:
        return self.base.with_elements(((e, float(v)) for elements, v in zip(self.elements, x) for e in elements))

    def units(self) -> list:
        return [KINDS[elements[0][0]].unit if elements[0][0] != "frame"
                else ("rad" if elements[0][1] >= 3 else "m") for elements in self.elements]


def _typical(kind: str, index, base: Values, scene, length: float) -> float:
    if kind == "stiffness":
        return 0.1
    if kind == "angle":
        return 0.05
    if kind == "radius":
        return 0.05 * scene.cables[index].radius
    if kind == "cable_stiffness":
        return 0.1 * base.cable_stiffness[index]
    if kind == "pretension":
        return 5e-3 * base.cable_stiffness[index] * length    # the tension of a stretch of 0.5 % of the trunk
    if kind == "frame":
        return 0.01 * length if index < 3 else 0.02
    if kind == "friction":
        return 0.05
    if kind == "backlash":
        return 1e-3 * length
    if kind == "lag":
        return 0.1
    if kind == "backlash_rate":
        return 1.0 / base.cable_stiffness[index]        # a play of 1 mm per the tension of a 1 mm stretch
    if kind == "entry_friction":
        return 1e-3 * base.cable_stiffness[index] * length  # the tension of a stretch of 0.1 % of the trunk
    return 0.01 * length


def _default_bounds(kind: str, index, value: float, base: Values, scene, length: float) -> tuple:
    if kind == "stiffness":
        return 0.1, 10.0
    if kind == "angle":
        return -0.5, 0.5
    if kind == "radius":
        r = scene.cables[index].radius
        return -0.5 * r, 0.5 * r
    if kind == "cable_stiffness":
        return value / 100.0, value * 100.0
    if kind == "pretension":
        k = base.cable_stiffness[index]
        return -0.1 * k * length, 0.1 * k * length          # slack or stretch of a tenth of the trunk
    if kind == "frame":
        return (value - length, value + length) if index < 3 else (value - math.pi / 2, value + math.pi / 2)
    if kind == "friction":
        return 0.0, 1.0
    if kind == "backlash":
        return 0.0, 0.05 * length
    if kind == "lag":
        return 0.0, 60.0
    if kind == "backlash_rate":
        return 0.0, 10.0 / base.cable_stiffness[index]
    if kind == "entry_friction":
        return 0.0, 0.1 * base.cable_stiffness[index] * length
    return value - 0.5 * length, value + 0.5 * length


SPEC = re.compile(r"^(?P<kind>[a-z_]+)(?:\.(?P<members>[^=]+))?(?:=(?P<low>[^:]*):(?P<high>.*))?$")


def parse_parameters(specs, scene, mapping, model, option: str = "--fit") -> ParameterSet:
    """The parameters named by ``specs`` (strings, module docstring), in order, for ``scene``
    compiled into ``model``. Unknown kinds, members or malformed bounds are :class:`OptionError`
    naming the specification."""
    base = initial_values(scene, mapping, model)
    length = float(model.length_scale)
    names, elements, initial, lower, upper, typical, taken = [], [], [], [], [], [], set()
    for spec in specs:
        match = SPEC.match(spec.replace(" ", ""))
        if not match or match["kind"] not in KINDS:
            raise OptionError(f"{spec!r}: expected KIND[.MEMBER|.*|.A+B][=LOW:HIGH] with KIND one of "
                              f"{', '.join(KINDS)}", field=option)
        kind, members = match["kind"], _members(match["kind"], scene, mapping)
        if not members:
            raise OptionError(f"{spec!r}: the scene and mapping have no {kind} to fit", field=option)
        given = match["members"]
        if given is None:
            groups = [list(members)]
            label = [kind]
        elif given == "*":
            groups = [[m] for m in members]
            label = [f"{kind}.{m}" for m in members]
        else:
            group = given.split("+")
            unknown = [m for m in group if m not in members]
            if unknown:
                raise OptionError(f"{spec!r}: unknown {kind} member(s) {', '.join(unknown)}; the scene and "
                                  f"mapping have {', '.join(members)}", field=option)
            groups, label = [group], [f"{kind}.{given}"]
        for name, group in zip(label, groups):
            indices = tuple((kind, members[m]) for m in group)
            clash = [m for m, e in zip(group, indices) if e in taken]
            if clash:
                raise OptionError(f"{spec!r}: {kind} {', '.join(clash)} is already fitted by another "
                                  f"specification", field=option)
            taken.update(indices)
            value = float(np.mean([base.get(k, i) for k, i in indices]))
            k0, i0 = indices[0]
            low, high = _default_bounds(k0, i0, value, base, scene, length)
            try:
                if match["low"]:
                    low = float(match["low"])
                if match["high"]:
                    high = float(match["high"])
            except ValueError:
                raise OptionError(f"{spec!r}: bounds must be numbers, got {match['low']!r}:{match['high']!r}",
                                  field=option) from None
            if not low < high:
                raise OptionError(f"{spec!r}: lower bound {low:g} is not below upper bound {high:g}", field=option)
            if k0 in ("friction", "backlash", "backlash_rate", "entry_friction", "lag") and value == low:
                # none in the scene: start inside (the bounded optimiser cannot leave a start on its bound)
                value = min(low + _typical(k0, i0, base, scene, length), 0.5 * (low + high))
            if not low <= value <= high:
                raise OptionError(f"{spec!r}: the initial value {value:g} lies outside the bounds "
                                  f"[{low:g}, {high:g}]", field=option)
            names.append(name)
            elements.append(indices)
            initial.append(value)
            lower.append(low)
            upper.append(high)
            typical.append(_typical(k0, i0, base, scene, length))
    if not names:
        raise OptionError("no parameters to fit (give --fit or [fit] parameters in the mapping file)",
                          field=option)
    return ParameterSet(tuple(names), tuple(elements), np.array(initial), np.array(lower), np.array(upper),
                        np.array(typical), base)
