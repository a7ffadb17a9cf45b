"""What a calibration reads besides the scene: the mapping file and the measured samples.

The **mapping file** (TOML, docs/calibration.md) says how a data set's columns meet the
scene: which column drives which stroke-driven cable, in which unit and with which sign; which columns
hold each marker's measured position, in which unit, and on which vertebra (with which
offset) the marker sits; the pose of the scene's world in the measurement frame (an
initial guess that calibration may refine); and, optionally, the parameters to fit with
their bounds. Nothing about a particular robot lives in code.

**Samples** are rows of a CSV file: one static equilibrium each, actuator commands in,
marker positions out, converted to SI through the mapping. Every error names the file, the
field (or row and column) and the reason.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import InputError, SceneError
from vertebra.core.inputs import load_toml, read_text
from vertebra.solver.tables import Table

__all__ = ["ActuatorMap", "MappingError", "MarkerMap", "Mapping", "Samples", "TIME_UNITS", "UNITS", "lag",
           "load_mapping", "load_samples", "parse_mapping", "play", "transmission"]

#: largest samples file read (a million rows of a dozen numbers)
MAX_DATA_BYTES = 256 * 2**20
#: length units a mapping may name, in metres
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}
#: time units a mapping may name, in seconds
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0}


class MappingError(InputError):
    """A mapping file or a data file read through it is invalid (names file, field and reason)."""


@dataclass(frozen=True)
class ActuatorMap:
    """One actuator column: the servo stroke of the scene's stroke-driven ``cable`` (its spring
    rate and pretension come from the scene), ``sign · scale · value`` metres pulled in."""

    column: str
    cable: str
    scale: float           # metres per unit of the column
    sign: float            # +1: a larger value pulls the tendon


@dataclass(frozen=True)
class MarkerMap:
    """One measured point: columns x, y, z (in the measurement frame) of a point fixed on
    ``vertebra`` at ``offset`` (metres, the vertebra's frame)."""

    name: str
    columns: tuple
    scale: float
    vertebra: int
    offset: tuple


@dataclass(frozen=True)
class Mapping:
    actuators: tuple            # ActuatorMap, in column order
    markers: tuple              # MarkerMap
    frame_position: tuple       # the scene world's origin in the measurement frame, m
    frame_rotation: tuple       # rotation vector (rad) of the scene world in the measurement frame
    pattern_column: str | None  # column naming the pattern a sample belongs to
    pattern_strip: tuple        # regular expressions removed from pattern names (grouping)
    fit: tuple                  # parameter specifications (strings) to fit when none are given
    max_samples: int | None     # training samples used at most (evenly spaced over the file)
    source: str = "<mapping>"
    time_column: str | None = None  # column of each sample's time (a lag needs it)
    time_scale: float = 1.0         # seconds per unit of the time column

    @property
    def cables(self) -> tuple:
        return tuple(a.cable for a in self.actuators)


def load_mapping(path) -> Mapping:
    """Read and validate a mapping file (bounded like a scene: size, encoding, nesting)."""
    return parse_mapping(load_toml(path, MappingError), str(path))


def _unit(t: Table, key: str = "unit") -> float:
    return UNITS[t.string(key, "m", choices=tuple(UNITS))]


def parse_mapping(data: dict, source: str = "<mapping>") -> Mapping:
    """Validate a mapping given as a dictionary (the parsed TOML)."""
    try:
        return _parse_mapping(data, source)
    except SceneError as error:       # the table reader's errors, re-labelled for a mapping file
        raise MappingError(error.reason, file=error.file, field=error.field) from None


def _parse_mapping(data: dict, source: str) -> Mapping:
    top = Table(data, "", source)
    dt = top.table("data")
    pattern_column = dt.string("pattern", None)
    time_column = dt.string("time", None)
    time_scale = TIME_UNITS[dt.string("time_unit", "s", choices=tuple(TIME_UNITS))]
    strip = dt.raw("pattern_strip", [])
    if not isinstance(strip, list) or not all(isinstance(s, str) for s in strip):
        raise dt.error("pattern_strip", f"expected a list of regular expressions, got {strip!r}")
    for s in strip:
        try:
            re.compile(s)
        except re.error as error:
            raise dt.error("pattern_strip", f"{s!r} is not a regular expression: {error}")
    dt.done()

    actuators, seen = [], set()
    tables = top.tables("actuator")
    if not tables:
        raise MappingError("a mapping needs at least one [[actuator]]", file=source, field="actuator")
    for t in tables:
        column, cable = t.string("column", required=True), t.string("cable", required=True)
        if cable in seen:
            raise t.error("cable", f"cable {cable!r} is driven by two columns")
        seen.add(cable)
        sign = t.number("sign", 1.0)
        if sign not in (1.0, -1.0):
            raise t.error("sign", f"must be +1 (a larger value pulls) or -1, got {sign!r}")
        actuators.append(ActuatorMap(column, cable, _unit(t), sign))
        t.done()

    markers, names = [], set()
    tables = top.tables("marker")
    if not tables:
        raise MappingError("a mapping needs at least one [[marker]]", file=source, field="marker")
    for i, t in enumerate(tables):
        name = t.string("name", f"marker{i}")
        if name in names:
            raise t.error("name", f"duplicate marker name {name!r}")
        names.add(name)
        columns = t.raw("columns")
        if columns is None:
            raise t.missing("columns")
        if not isinstance(columns, list) or len(columns) != 3 or not all(isinstance(c, str) and c for c in columns):
            raise t.error("columns", f"expected the names of the x, y and z columns, got {columns!r}")
        scale = _unit(t)
        offset = t.vector("offset", 3, (0.0, 0.0, 0.0))
        markers.append(MarkerMap(name, tuple(columns), scale, t.number("vertebra", -1, integer=True),
                                 tuple(scale * v for v in offset)))
        t.done()

    ft = top.table("frame")
    scale = _unit(ft)
    position = tuple(scale * v for v in ft.vector("position", 3, (0.0, 0.0, 0.0)))
    rotation = tuple(math.radians(v) for v in ft.vector("rotation_deg", 3, (0.0, 0.0, 0.0)))
    ft.done()

    fit_t = top.table("fit")
    fit = fit_t.raw("parameters", [])
    if not isinstance(fit, list) or not all(isinstance(s, str) and s for s in fit):
        raise fit_t.error("parameters", f"expected a list of parameter specifications, got {fit!r}")
    max_samples = fit_t.number("max_samples", None, positive=True, integer=True)
    fit_t.done()
    top.done()
    return Mapping(tuple(actuators), tuple(markers), position, rotation, pattern_column, tuple(strip),
                   tuple(fit), max_samples, source, time_column, time_scale)


@dataclass(frozen=True)
class Samples:
    """Measured static samples in SI units: ``commands`` (n, n_actuators) in metres of pull
    (sign applied), ``markers`` (n, n_markers, 3) in metres in the measurement frame,
    ``patterns`` the pattern name of each sample (grouped by the mapping's ``pattern_strip``),
    ``rows`` each sample's row in ``source`` (default 0…n−1; a selection keeps them: a sample is
    the same sample in every selection of its file), ``times`` each sample's time in seconds
    (None: the mapping names no time column)."""

    commands: np.ndarray
    markers: np.ndarray
    patterns: tuple
    source: str = "<samples>"
    rows: np.ndarray | None = None
    times: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.commands)
        if self.markers.shape[0] != n or len(self.patterns) != n:
            raise ValueError(f"len(commands) = {n}, but len(markers) = {self.markers.shape[0]} "
                             f"and len(patterns) = {len(self.patterns)}")
        if self.rows is None:
            object.__setattr__(self, "rows", np.arange(n))
        elif len(self.rows) != n:
            raise ValueError(f"len(commands) = {n}, but len(rows) = {len(self.rows)}")
        if self.times is not None and len(self.times) != n:
            raise ValueError(f"len(commands) = {n}, but len(times) = {len(self.times)}")

    def __len__(self) -> int:
        return len(self.commands)

    def take(self, index) -> "Samples":
        index = np.asarray(index)
        return Samples(self.commands[index], self.markers[index], tuple(self.patterns[i] for i in index),
                       self.source, self.rows[index], None if self.times is None else self.times[index])


def load_samples(path, mapping: Mapping) -> Samples:
    """Read a CSV file with a header row through ``mapping``."""
    source = str(path)
    reader = csv.reader(io.StringIO(read_text(path, MappingError, limit=MAX_DATA_BYTES), newline=""))
    try:
        header = next(reader, None)
        rows = list(reader)
    except csv.Error as error:
        raise MappingError(f"not a CSV file: {error}", file=source) from None
    if header is None:
        raise MappingError("the file is empty (a header row is needed)", file=source)
    header = [h.strip() for h in header]

    def column(name, what):
        if name not in header:
            raise MappingError(f"column {name!r} ({what}, named in {mapping.source}) is not in the header "
                               f"({', '.join(header)})", file=source, field=name)
        return header.index(name)

    act = [column(a.column, f"actuator of cable {a.cable}") for a in mapping.actuators]
    mk = [[column(c, f"marker {m.name}") for c in m.columns] for m in mapping.markers]
    pat = column(mapping.pattern_column, "pattern") if mapping.pattern_column else None
    tim = column(mapping.time_column, "time") if mapping.time_column else None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise MappingError("no samples after the header row", file=source)
    numeric = sorted(set(act) | {i for m in mk for i in m} | ({tim} if tim is not None else set()))
    values = np.empty((len(rows), len(header)))
    for i, row in enumerate(rows):
        if len(row) != len(header):
            raise MappingError(f"{len(row)} values for {len(header)} columns", file=source, field=f"row {i + 2}")
        for j in numeric:
            try:
                values[i, j] = float(row[j])
            except ValueError:
                raise MappingError(f"expected a number, got {row[j]!r}", file=source,
                                   field=f"row {i + 2}, column {header[j]}") from None
            if not math.isfinite(values[i, j]):
                raise MappingError(f"expected a finite number, got {row[j]!r}", file=source,
                                   field=f"row {i + 2}, column {header[j]}")
    commands = values[:, act] * np.array([a.sign * a.scale for a in mapping.actuators])
    markers = np.stack([values[:, m] * marker.scale for m, marker in zip(mk, mapping.markers)], axis=1)
    if pat is None:
        patterns = ("all",) * len(rows)
    else:
        patterns = []
        for row in rows:
            name = row[pat].strip()
            for expression in mapping.pattern_strip:
                name = re.sub(expression, "", name)
            patterns.append(name or "(unnamed)")
        patterns = tuple(patterns)
    times = None
    if tim is not None:
        times = values[:, tim] * mapping.time_scale
        back = np.flatnonzero(np.diff(times) < 0.0)
        if back.size:
            i = int(back[0]) + 1
            raise MappingError(f"time runs backwards ({rows[i - 1][tim].strip()} then {rows[i][tim].strip()}): "
                               f"the rows must be in the order they were recorded", file=source,
                               field=f"row {i + 2}, column {header[tim]}")
    return Samples(commands, markers, patterns, source, times=times)


def play(commands: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The strokes that reach the tendons through a transmission with play (backlash) of
    ``width`` (per actuator column, m) under the time-ordered ``commands`` (n, n_actuators):
    a stroke stays where it is until the command has moved more than ``width`` away from it,
    then follows at that distance — it lags the command by ``width`` while the command rises and
    leads it by ``width`` while it falls. The first row starts where it is commanded. Returns the
    strokes and their derivatives with respect to each column's width (−1 while pulled, +1 while
    released, carried along while inside the play)."""
    commands = np.asarray(commands, float)
    width = np.broadcast_to(np.asarray(width, float), commands.shape[1:])
    strokes, slopes = commands.copy(), np.zeros_like(commands)
    for k in range(1, len(commands)):
        low, high = commands[k] - width, commands[k] + width
        behind, ahead = strokes[k - 1] < low, strokes[k - 1] > high
        strokes[k] = np.where(behind, low, np.where(ahead, high, strokes[k - 1]))
        slopes[k] = np.where(behind, -1.0, np.where(ahead, 1.0, slopes[k - 1]))
    return strokes, slopes


def lag(strokes: np.ndarray, times, tau: np.ndarray, carried: dict | None = None):
    """The strokes that reach the tendons when they relax towards ``strokes`` (n, n_actuators),
    the time-ordered targets (the commands, or what a play passes on), with the time constant
    ``tau`` (per actuator column, s) between the samples' ``times`` (n,) s: a first-order lag
    ``s_k = u_k + a_k (s_{k−1} − u_k)``, ``a_k = exp(−(t_k − t_{k−1})/τ)`` (0 where ``τ = 0``: no
    lag). The first row starts where it is targeted. Returns the strokes, their derivatives by
    each column's ``τ`` and ``carried`` (name → (n, n_actuators) derivatives of the targets by
    another parameter) passed through the lag."""
    strokes = np.asarray(strokes, float)
    tau = np.broadcast_to(np.asarray(tau, float), strokes.shape[1:])
    out, d_tau = strokes.copy(), np.zeros_like(strokes)
    carried = {name: np.array(d, float) for name, d in (carried or {}).items()}
    if not np.any(tau):
        return out, d_tau, carried
    times = np.asarray(times, float)
    lagging = tau > 0.0
    safe = np.where(lagging, tau, 1.0)
    for k in range(1, len(strokes)):
        dt = times[k] - times[k - 1]
        a = np.where(lagging, np.exp(-dt / safe), 0.0)
        da = np.where(lagging, a * dt / safe ** 2, 0.0)
        gap = out[k - 1] - strokes[k]
        out[k] = strokes[k] + a * gap
        d_tau[k] = a * d_tau[k - 1] + da * gap
        for d in carried.values():
            d[k] = (1.0 - a) * d[k] + a * d[k - 1]
    return out, d_tau, carried


def transmission(commands: np.ndarray, times, width: np.ndarray, tau: np.ndarray):
    """The strokes that reach the tendons from the time-ordered ``commands`` through a play of
    ``width`` (:func:`play`) and then a lag of time constant ``tau`` (:func:`lag`; ``times``
    needed when any ``tau`` > 0), and their derivatives: ``{"backlash": d/d width, "lag":
    d/d tau}``, each (n, n_actuators), a column's derivative by its own element."""
    strokes, slopes = play(commands, width)
    if not np.any(tau):
        return strokes, {"backlash": slopes, "lag": np.zeros_like(strokes)}
    strokes, d_tau, carried = lag(strokes, times, tau, {"backlash": slopes})
    return strokes, {"backlash": carried["backlash"], "lag": d_tau}
