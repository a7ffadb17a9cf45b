"""Scene files (docs/scenes.md, TOML version 1): loading and validation.

Every table is read through :class:`Table`, which consumes the fields it knows and
raises :class:`SceneError` naming the file, the dotted field and the reason for unknown
fields, wrong types and impossible values. A valid :class:`Scene` is immutable and holds
SI values only (degrees are converted where a field name says ``_deg``). The ``[[segment]]``
tables are read by :mod:`vertebra.solver.segments` (beams, catalogue entries, designs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vertebra.solver.plausible import scene_warnings
from vertebra.solver.obstacles import parse_obstacle
from vertebra.solver.segments import (DESIGN_MATERIALS, SEGMENT_TYPES, DesignSpec, SegmentSpec, VertebraSpec,
                                      parse_disc, parse_segment)
from vertebra.solver.tables import Table
from vertebra.core.errors import SceneError
from vertebra.core.inputs import check_depth, load_toml

__all__ = ["CableSpec", "ChamberSpec", "DESIGN_MATERIALS", "DesignSpec", "EffectorSpec", "LoadSpec", "SEGMENT_TYPES",
           "Scene", "SegmentSpec", "SolverSettings", "VertebraSpec", "gallery_names", "gallery_path", "load_scene",
           "parse_scene", "scene_toml"]
MAX_LINKS = 200_000          # links in one scene (tested up to 10,000; compile time ~ 10 µs per link)


@dataclass(frozen=True)
class SolverSettings:
    tolerance: float = 1e-9
    max_iterations: int = 100
    load_steps: int = 1


@dataclass(frozen=True)
class CableSpec:
    name: str
    radius: float
    angle: float            # rad, about local +z from local +x
    first: int              # first vertebra it passes through ("from")
    last: int               # vertebra where it is terminated ("to")
    tension: float = 0.0
    min_tension: float = 0.0
    max_tension: float = math.inf
    min_stroke: float = -math.inf
    max_stroke: float = math.inf
    max_tension_change: float | None = None     # N per control tick (None: derived from the bounds)
    # a tendon driven by a servo stroke (``stroke`` given) instead of a tension: it stretches with
    # the spring rate ``stiffness`` (N/m; or ``axial_stiffness`` EA over its rest length plus
    # ``free_length``), carries ``pretension`` at zero stroke and goes slack (never pushes)
    stroke: float | None = None                 # m pulled in by the servo (None: tension-driven)
    stiffness: float | None = None              # N/m
    axial_stiffness: float | None = None        # N (EA)
    free_length: float = 0.0                    # m of tendon outside the robot (servo to base hole)
    pretension: float = 0.0                     # N at zero stroke with the trunk at rest
    max_stroke_change: float | None = None      # m per control tick (None: derived from the bounds)
    friction: float = 0.0                       # μ of the capstan law at every hole it passes (solver/friction.py)

    @property
    def stroke_driven(self) -> bool:
        return self.stroke is not None


@dataclass(frozen=True)
class ChamberSpec:
    name: str
    cavity: int
    first: int
    last: int
    pressure: float = 0.0
    min_pressure: float = 0.0
    max_pressure: float = math.inf
    min_volume_growth: float = -math.inf
    max_volume_growth: float = math.inf
    max_pressure_change: float | None = None    # Pa per control tick (None: derived from the bounds)


@dataclass(frozen=True)
class LoadSpec:
    """A wrench at a vertebra's origin: dead (world axes) or, with ``follower``, fixed in the
    vertebra's own axes (it turns with the vertebra)."""

    vertebra: int
    force: tuple = (0.0, 0.0, 0.0)
    moment: tuple = (0.0, 0.0, 0.0)
    follower: bool = False


@dataclass(frozen=True)
class EffectorSpec:
    """A point on a vertebra (``offset`` in its frame, ``target`` in the world), or — with
    ``axis`` — a unit direction fixed in the vertebra whose world direction should match the
    unit vector ``target`` (an orientation target; its error is dimensionless)."""

    name: str
    vertebra: int
    offset: tuple = (0.0, 0.0, 0.0)
    target: tuple | None = None
    weight: float = 1.0
    axis: tuple | None = None


@dataclass(frozen=True)
class Scene:
    """A validated scene. Vertebra indices are resolved (no negative indices remain)."""

    segments: tuple
    name: str = ""
    solver: SolverSettings = SolverSettings()
    gravity: tuple | None = None
    base_position: tuple = (0.0, 0.0, 0.0)
    base_quaternion: tuple = (1.0, 0.0, 0.0, 0.0)
    catalogue: str | None = None
    cables: tuple = ()
    chambers: tuple = ()
    loads: tuple = ()
    effectors: tuple = ()
    source: str = "<scene>"
    obstacles: tuple = ()                  # solver.obstacles: Plane, Sphere, Capsule, Box, Mesh
    base_disc: tuple = (0.0, 0.0)          # the base's contact disc: (radius, thickness)

    @property
    def n_vertebrae(self) -> int:
        return 1 + sum(s.count for s in self.segments)

    @property
    def design_segments(self) -> tuple[int, ...]:
        """Indices of the segments given by their design (resolved or not)."""
        return tuple(i for i, s in enumerate(self.segments) if s.design is not None)

    def check_resolved(self) -> None:
        """Raise :class:`SceneError` naming the first design segment that has no entry yet."""
        for i, segment in enumerate(self.segments):
            if not segment.resolved:
                raise SceneError(f"a design segment (family {segment.design.family!r}) has no catalogue entry yet: "
                                 f"run `vertebra prepare {self.source}` (or pass --prepare; from Python: "
                                 "vertebra.designer.prepare) to design the missing entries", file=self.source,
                                 field=f"segment[{i}]")


GALLERY = Path(__file__).with_name("gallery")     # the gallery's scenes: <name>.toml


def gallery_names() -> list[str]:
    """Names of the gallery's scenes."""
    return sorted(p.stem for p in GALLERY.glob("*.toml"))


def gallery_path(name: str) -> Path:
    """The TOML file of the gallery scene ``name``."""
    candidate = GALLERY / f"{name}.toml"
    if not candidate.is_file():
        raise SceneError(f"no gallery scene {name!r}; available: {', '.join(gallery_names())}", file="gallery")
    return candidate


def load_scene(path) -> Scene:
    """Read and validate a TOML scene file; ``gallery:NAME`` names a gallery scene."""
    if str(path).startswith("gallery:"):
        path = gallery_path(str(path).split(":", 1)[1])
    path = Path(path)
    data = load_toml(path, SceneError)      # bounded: size, encoding, nesting (core/inputs.py)
    return parse_scene(data, source=str(path), base_dir=path.parent)


def parse_scene(data: dict, source: str = "<dict>", base_dir=".") -> Scene:
    """Validate a scene given as a dictionary (the parsed TOML)."""
    check_depth(data, SceneError, source=source)
    top = Table(data, "", source)
    scene_name = top.string("name", "")
    version = top.number("version", 1, integer=True)
    if version != 1:
        raise top.error("version", f"unsupported scene version {version} (this vertebra reads version 1)")

    st = top.table("solver")
    settings = SolverSettings(
        tolerance=st.number("tolerance", 1e-9, positive=True),
        max_iterations=st.number("max_iterations", 100, positive=True, integer=True),
        load_steps=st.number("load_steps", 1, positive=True, integer=True),
    )
    st.done()

    gravity = None
    if top.has("gravity"):
        gt = top.table("gravity")
        gravity = gt.vector("vector", 3, required=True)
        gt.done()

    bt = top.table("base")
    base_position = bt.vector("position", 3, (0.0, 0.0, 0.0))
    base_quaternion = bt.vector("quaternion", 4, (1.0, 0.0, 0.0, 0.0))
    norm = math.sqrt(sum(v * v for v in base_quaternion))
    if abs(norm - 1.0) > 1e-6:
        raise bt.error("quaternion", f"must have unit norm, got norm {norm:.6g}")
    base_quaternion = tuple(v / norm for v in base_quaternion)
    base_disc = parse_disc(bt)
    bt.done()

    catalogue = None
    if top.has("catalogue"):
        ct = top.table("catalogue")
        catalogue = str(Path(base_dir) / ct.string("path", required=True))
        ct.done()

    segment_tables = top.tables("segment")
    if not segment_tables:
        raise SceneError("a scene needs at least one [[segment]]", file=source, field="segment")
    segments = tuple(parse_segment(t) for t in segment_tables)
    n_links = sum(s.count * s.elements for s in segments)
    if n_links > MAX_LINKS:
        raise SceneError(f"the scene would have {n_links} links (count × elements over all segments); "
                         f"at most {MAX_LINKS} are supported", file=source, field="segment")
    if any(s.type == "entry" for s in segments) and catalogue is None:
        raise SceneError("segments of type 'entry' need a [catalogue] path", file=source, field="catalogue.path")
    n_vertebrae = 1 + sum(s.count for s in segments)

    def vertebra_index(table, key, default=None, *, allow_base=True):
        index = table.number(key, default, integer=True, required=default is None)
        resolved = index + n_vertebrae if index < 0 else index
        lowest = 0 if allow_base else 1
        if not lowest <= resolved < n_vertebrae:
            raise table.error(key, f"vertebra {index} out of range: the scene has vertebrae 0..{n_vertebrae - 1}"
                                   + ("" if allow_base else " and 0 is the clamped base"))
        return resolved

    def vertebra_range(table):
        """``from``/``to`` of a cable or chamber: vertebrae first..last, never the base."""
        first = vertebra_index(table, "from", 1, allow_base=False)
        last = vertebra_index(table, "to", allow_base=False)
        if last < first:
            raise table.error("to", f"vertebra {last} comes before the first vertebra {first}")
        return first, last

    names = set()

    def unique_name(table, kind):
        value = table.string("name", required=True)
        if value in names:
            raise table.error("name", f"duplicate actuator/effector name {value!r}")
        names.add(value)
        return value

    cables = []
    for t in top.tables("cable"):
        first, last = vertebra_range(t)
        name = unique_name(t, "cable")
        radius = t.number("radius", required=True, nonneg=True)
        angle, tension = math.radians(t.number("angle_deg", 0.0)), t.number("tension", 0.0)
        cables.append(CableSpec(name, radius, angle, first, last, tension, *_bounds(t, "tension"),
                                *_bounds(t, "stroke", -math.inf),
                                t.number("max_tension_change", None, positive=True, unbounded=True),
                                **_tendon(t), friction=t.number("friction", 0.0, nonneg=True)))
        t.done()

    chambers = []
    for t in top.tables("chamber"):
        first, last = vertebra_range(t)
        name = unique_name(t, "chamber")
        cavity = t.number("cavity", 0, integer=True, nonneg=True)
        pressure = t.number("pressure", 0.0)
        chambers.append(ChamberSpec(name, cavity, first, last, pressure, *_bounds(t, "pressure"),
                                    *_bounds(t, "volume_growth", -math.inf),
                                    t.number("max_pressure_change", None, positive=True, unbounded=True)))
        t.done()

    loads = []
    for t in top.tables("load"):
        follower = t.raw("follower", False)
        if not isinstance(follower, bool):
            raise t.error("follower", f"expected true (force and moment in the vertebra's axes, turning with it) "
                                      f"or false (world axes), got {follower!r}")
        loads.append(LoadSpec(vertebra=vertebra_index(t, "vertebra", allow_base=False),
                              force=t.vector("force", 3, (0.0, 0.0, 0.0)),
                              moment=t.vector("moment", 3, (0.0, 0.0, 0.0)), follower=follower))
        t.done()

    effectors = []
    for t in top.tables("effector"):
        axis = _unit(t, "axis", t.vector("axis", 3, None))
        if axis is not None and t.has("offset"):
            raise t.error("offset", "an effector has an offset (a point) or an axis (a direction), not both")
        target = t.vector("target", 3, None)
        effectors.append(EffectorSpec(name=unique_name(t, "effector"), vertebra=vertebra_index(t, "vertebra", -1),
                                      offset=t.vector("offset", 3, (0.0, 0.0, 0.0)),
                                      target=_unit(t, "target", target) if axis is not None else target,
                                      weight=t.number("weight", 1.0, positive=True), axis=axis))
        t.done()
    obstacles = tuple(parse_obstacle(t, base_dir) for t in top.tables("obstacle"))
    top.done()
    scene = Scene(segments=segments, name=scene_name, solver=settings, gravity=gravity, base_position=base_position,
                 base_quaternion=base_quaternion, catalogue=catalogue, cables=tuple(cables),
                 chambers=tuple(chambers), loads=tuple(loads), effectors=tuple(effectors), source=source,
                 obstacles=obstacles, base_disc=(base_disc["disc_radius"], base_disc["disc_thickness"]))
    scene_warnings(scene)           # unit slips (a pressure of 1.5 Pa): warnings, not errors
    return scene


def _tendon(t: Table) -> dict:
    """The fields of a stroke-driven cable (empty for a tension-driven one): ``stroke`` with
    either ``stiffness`` (N/m) or ``axial_stiffness`` (EA, N; with ``free_length``), and
    ``pretension``, ``max_stroke_change``."""
    tendon_fields = ("stiffness", "axial_stiffness", "free_length", "pretension", "max_stroke_change")
    if t.number("stroke", None) is None:
        given = [key for key in tendon_fields if t.number(key, None, unbounded=True) is not None]
        if given:
            raise t.error(given[0], "applies to a stroke-driven cable only: give its servo `stroke` (m) "
                                    "instead of a `tension`")
        return {}
    if t.number("tension", None) is not None:
        raise t.error("tension", "a cable is driven either by a `tension` or by a `stroke`, not both")
    stiffness = t.number("stiffness", None, positive=True)
    axial = t.number("axial_stiffness", None, positive=True)
    if (stiffness is None) == (axial is None):
        raise t.error("stiffness", "a stroke-driven cable needs exactly one of `stiffness` (spring rate, N/m) "
                                   "and `axial_stiffness` (EA, N)")
    free_length = t.number("free_length", 0.0, nonneg=True)
    if stiffness is not None and t.number("free_length", None) is not None:
        raise t.error("free_length", "sets the tendon's length for `axial_stiffness`; with `stiffness` "
                                     "(the spring rate itself) it has no meaning")
    return {"stroke": t.number("stroke"), "stiffness": stiffness, "axial_stiffness": axial,
            "free_length": free_length, "pretension": t.number("pretension", 0.0),
            "max_stroke_change": t.number("max_stroke_change", None, positive=True, unbounded=True)}


def _bounds(t: Table, quantity: str, lowest: float = 0.0) -> tuple[float, float]:
    """``min_<quantity>`` (default ``lowest``) and ``max_<quantity>`` (default +inf), ordered."""
    low = t.number(f"min_{quantity}", lowest, unbounded=math.isinf(lowest))
    high = t.number(f"max_{quantity}", math.inf, unbounded=True)
    if low > high:
        raise t.error(f"min_{quantity}", f"{low} exceeds max_{quantity} {high}")
    return low, high


def _unit(t: Table, key: str, vector):
    """Normalise a direction given in the scene; a zero vector is an error naming the field."""
    if vector is None:
        return None
    norm = math.sqrt(sum(v * v for v in vector))
    if not norm > 0.0:
        raise t.error(key, "a direction must not be the zero vector")
    return tuple(v / norm for v in vector)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return ("" if value > 0 else "-") + "inf" if math.isinf(value) else "nan"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v.item() if hasattr(v, "item") else v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def scene_toml(data: dict, header: str = "") -> str:
    """Write a scene dictionary (as :func:`parse_scene` takes it) as TOML text: scalars first,
    then tables and arrays of tables in the dictionary's order (dictionaries inside them become
    inline tables); ``header`` becomes leading comment lines."""
    lines = [f"# {line}" for line in header.splitlines()]
    tables = []
    for key, value in data.items():
        if isinstance(value, dict):
            tables.append((f"[{key}]", value))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            tables.extend((f"[[{key}]]", item) for item in value)
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    for title, table in tables:
        lines += ["", title] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
