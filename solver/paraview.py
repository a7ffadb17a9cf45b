"""ParaView files of a trunk: VTK XML PolyData (``.vtp``) of one state and ParaView collections
(``.pvd``) of a time series. What each array means, with units: ``docs/paraview.md``.

meshio writes VTK unstructured grids, not PolyData, and no string arrays (the cable names), so
this module writes the XML itself: ASCII, floats in shortest round-trip form (they read back bit
for bit), no dependency beyond numpy.

One ``.vtp`` holds the frames (points with their axes), the backbone (one line cell per link),
the cables (one line cell per piece between holes, with its tension), the vertebra discs
(polygons), the point effectors and their targets (vertex cells), and the names of the cables,
chambers and effectors as field data.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from vertebra import __version__
from vertebra.solver import display
from vertebra.solver.friction import FrictionState
from vertebra.solver.friction import routes as friction_routes
from vertebra.core.lie import qmatrix

# parts of the trunk, by the value of the cell array "part" (their names go to field data)
PARTS = ("backbone", "cable", "vertebra", "effector", "target")
BACKBONE, CABLE, VERTEBRA, EFFECTOR, TARGET = range(len(PARTS))
CONTACT = len(PARTS)       # contact points: a part of files written with contacts only
DISC_SIDES = 32
CELL_KINDS = ("verts", "lines", "polys")          # VTK's order of cell data in PolyData (no strips)

_VTK_TYPES = {"i": "Int32", "f": "Float64"}


@dataclass(frozen=True)
class Cells:
    """Cells of one kind as VTK stores them: the point indices of every cell one after the
    other (``connectivity``) and where each cell ends (``offsets``)."""

    connectivity: np.ndarray
    offsets: np.ndarray

    @classmethod
    def of(cls, cells: list[np.ndarray]) -> "Cells":
        sizes = np.array([len(c) for c in cells], dtype=np.int64)
        connectivity = np.concatenate(cells).astype(np.int64) if cells else np.zeros(0, np.int64)
        return cls(connectivity, np.cumsum(sizes))

    @property
    def count(self) -> int:
        return self.offsets.size


@dataclass(frozen=True)
class PolyData:
    """Points, cells (vertices, lines, polygons), and named arrays on the points, on the cells
    (in VTK's order: vertices, then lines, then polygons) and on the whole data set (field data:
    numbers, or lists of strings)."""

    points: np.ndarray
    verts: Cells
    lines: Cells
    polys: Cells
    point_data: dict = field(default_factory=dict)
    cell_data: dict = field(default_factory=dict)
    field_data: dict = field(default_factory=dict)
    active_scalars: str | None = None
    active_vectors: str | None = None

    def __post_init__(self):
        n = len(self.points)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3), got {self.points.shape}")
        for kind in CELL_KINDS:
            cells = getattr(self, kind)
            if cells.connectivity.size and not (0 <= cells.connectivity.min() and cells.connectivity.max() < n):
                raise ValueError(f"{kind} refer to points outside 0..{n - 1}")
        n_cells = sum(getattr(self, kind).count for kind in CELL_KINDS)
        for where, data, size in (("point_data", self.point_data, n), ("cell_data", self.cell_data, n_cells)):
            for name, values in data.items():
                if len(values) != size:
                    raise ValueError(f"len({where}[{name!r}]) = {len(values)}, but there are {size} "
                                     f"{'points' if where == 'point_data' else 'cells'}")


def trunk_polydata(model, state, actuation=None, targets=None, *, time: float | None = None,
                   friction=None, contacts=None) -> PolyData:
    """The PolyData of ``model`` at ``state`` under ``actuation`` (default: the scene's), with
    the point effectors' ``targets`` ((n_eff, 3), NaN where none; default: the scene's) and,
    when given, ``time`` (s) as the field ``TimeValue`` that ParaView reads as the time. With the
    ``friction`` state of a frictional solve (``result.friction``) each cable cell carries its
    span's own tension and each cable point ``stick`` (1: the cable is stuck at that hole). With
    ``contacts`` (``result.contacts``, docs/contact.md) each contact is a vertex (part
    ``contact``) at its point on the body with ``contact_force`` (N), ``contact_gap`` (m) and
    ``contact_normal`` (friction at obstacles: ``result.friction`` is no cable state, and ignored
    here; the contacts' tangential forces are in the JSON)."""
    if not isinstance(friction, FrictionState):
        friction = None
    actuation = model.actuation(actuation)
    targets = model.effector_targets if targets is None else np.asarray(targets, dtype=float)
    n_frames, nc = model.n_frames, model.n_cables
    vertebra_frames = np.asarray(model.vertebra_frames)
    rotations = qmatrix(state.quaternions)                 # columns: the frame's axes in the world
    backbone_radius = display.frame_radii(model)

    vertebra_of_frame = np.full(n_frames, -1)
    vertebra_of_frame[vertebra_frames] = np.arange(vertebra_frames.size)
    extra = (("stick",) if friction is not None else ()) + (("contact_force", "contact_gap") if contacts else ())
    points = _Points(extra, ("contact_normal",) if contacts else ())
    frames = points.add(state.positions, frame=np.arange(n_frames), vertebra=vertebra_of_frame,
                        radius=backbone_radius, x_axis=rotations[:, :, 0], y_axis=rotations[:, :, 1],
                        z_axis=rotations[:, :, 2])

    cells = {kind: [] for kind in CELL_KINDS}
    cell_rows = {kind: [] for kind in CELL_KINDS}        # per cell: (part, link, vertebra, cable, effector)

    # backbone: link k joins frames k and k + 1; it belongs to the vertebra that ends its repetition
    link_vertebra = np.searchsorted(vertebra_frames, np.arange(1, n_frames))
    for k in range(n_frames - 1):
        cells["lines"].append(frames[[k, k + 1]])
        cell_rows["lines"].append((BACKBONE, k, link_vertebra[k], -1, -1))

    cable_radius = display.cable_radii(model)
    routes = friction_routes(model.trunk.cables).pieces
    span_tension = []
    for c, path in enumerate(display.cable_paths(model, state)):
        stick = np.zeros(len(path))
        if friction is not None:
            stick[1:-1] = friction.slip[routes[c][1:]] == 0
            span_tension.append(friction.tension[routes[c]])
        ids = points.add(path, cable=np.full(len(path), c), radius=np.full(len(path), cable_radius[c]),
                         **({"stick": stick} if friction is not None else {}))
        for a, b in zip(ids[:-1], ids[1:]):
            cells["lines"].append(np.array([a, b]))
            cell_rows["lines"].append((CABLE, -1, -1, c, -1))
    cable_cells = np.array([row[0] == CABLE for row in cell_rows["lines"]])
    cable_of_cell = np.array([row[3] for row in cell_rows["lines"]])

    rims = display.disc_rims(model, state, DISC_SIDES)
    disc_radius = display.vertebra_radius(model)
    for v, rim in enumerate(rims):
        ids = points.add(rim, vertebra=np.full(DISC_SIDES, v), radius=np.full(DISC_SIDES, disc_radius[v]))
        cells["polys"].append(ids)
        cell_rows["polys"].append((VERTEBRA, -1, v, -1, -1))

    positions = model.effector_positions(state)
    marker = float(backbone_radius.max())
    error = []
    for e in np.flatnonzero(~np.asarray(model.effector_is_axis)):   # directions are not places
        has_target = bool(np.all(np.isfinite(targets[e])))
        gap = float(np.linalg.norm(positions[e] - targets[e])) if has_target else 0.0
        for part, where in ((EFFECTOR, positions[e]), (TARGET, targets[e])):
            if part == TARGET and not has_target:
                continue
            ids = points.add(where[None], effector=np.array([e]), radius=np.array([marker]))
            cells["verts"].append(ids)
            cell_rows["verts"].append((part, -1, -1, -1, e))
            error.append(gap)

    for c in contacts or ():
        ids = points.add(np.array([c.point]), contact_force=np.array([c.force]), contact_gap=np.array([c.gap]),
                         contact_normal=np.array([c.normal]), radius=np.array([marker]))
        cells["verts"].append(ids)
        cell_rows["verts"].append((CONTACT, -1, -1, -1, -1))
        error.append(0.0)

    rows = np.array([row for kind in CELL_KINDS for row in cell_rows[kind]], dtype=np.int64).reshape(-1, 5)
    n_verts, n_lines = len(cells["verts"]), len(cells["lines"])
    tension = np.zeros(len(rows))
    tension[n_verts:n_verts + n_lines][cable_cells] = (actuation[cable_of_cell[cable_cells]] if friction is None
                                                       else np.concatenate(span_tension))
    cell_error = np.zeros(len(rows))
    cell_error[:n_verts] = error
    cell_data = {"part": rows[:, 0], "link": rows[:, 1], "vertebra": rows[:, 2], "cable": rows[:, 3],
                 "effector": rows[:, 4], "tension": tension, "error": cell_error}

    names = model.actuator_names
    field_data = {"part_names": list(PARTS) + (["contact"] if contacts else []), "vertebra_version": [__version__],
                  "cable_names": names[:nc], "cable_tension": actuation[:nc],
                  "chamber_names": names[nc:], "chamber_pressure": actuation[nc:],
                  "effector_names": list(model.effector_names)}
    if time is not None:
        field_data["TimeValue"] = np.array([float(time)])
    field_data = {name: values for name, values in field_data.items() if len(values)}
    xyz, point_data = points.finish()
    return PolyData(xyz, *(Cells.of(cells[kind]) for kind in CELL_KINDS),
                    point_data=point_data, cell_data=cell_data, field_data=field_data,
                    active_scalars="radius", active_vectors="z_axis")


class _Points:
    """Points added block by block, with their arrays (unset entries: −1 for indices, 0 for
    values and vectors)."""

    INDEX = ("vertebra", "frame", "cable", "effector")
    VECTOR = ("x_axis", "y_axis", "z_axis")

    def __init__(self, extra: tuple = (), vectors: tuple = ()):
        self.blocks, self.count = [], 0
        self.vectors = self.VECTOR + tuple(vectors)
        self.parts = {name: [] for name in self.INDEX + ("radius",) + tuple(extra) + self.vectors}

    def add(self, xyz: np.ndarray, **arrays) -> np.ndarray:
        n = len(xyz)
        self.blocks.append(np.asarray(xyz, dtype=float).reshape(n, 3))
        for name, parts in self.parts.items():
            if name in arrays:
                parts.append(np.asarray(arrays[name]))
            elif name in self.INDEX:
                parts.append(np.full(n, -1, dtype=np.int32))
            else:
                parts.append(np.zeros((n, 3) if name in self.vectors else n))
        ids = np.arange(self.count, self.count + n)
        self.count += n
        return ids

    def finish(self) -> tuple[np.ndarray, dict]:
        """The points ``(n, 3)`` and their arrays."""
        return np.vstack(self.blocks), {name: np.concatenate(parts).astype(np.int32 if name in self.INDEX else float)
                                        for name, parts in self.parts.items()}


# ----------------------------------------------------------------------------- writing

def _text(values: np.ndarray) -> str:
    values = np.asarray(values).reshape(-1)
    if values.dtype.kind == "f":
        return " ".join(repr(float(v)) for v in values)      # shortest round-trip form
    return " ".join(str(int(v)) for v in values)


def _strings(values) -> str:
    """VTK's ASCII form of a string array: each string's UTF-8 bytes as numbers, then a 0."""
    return " ".join(" ".join(str(b) for b in (*str(v).encode("utf-8"), 0)) for v in values)


def _data_array(name: str, values, indent: str, *, tuples: bool = False) -> str:
    """One ``<DataArray>`` element; ``tuples``: say ``NumberOfTuples`` (field data does)."""
    head = f"{indent}<DataArray"
    if isinstance(values, (list, tuple)):
        return (f'{head} type="String" Name={quoteattr(name)} NumberOfTuples="{len(values)}" format="ascii">'
                f"{_strings(values)}</DataArray>\n")
    values = np.asarray(values)
    kind = values.dtype.kind
    vtk_type = "Int64" if name in ("connectivity", "offsets") else _VTK_TYPES["f" if kind == "f" else "i"]
    components = f' NumberOfComponents="{values.shape[1]}"' if values.ndim == 2 else ""
    count = f' NumberOfTuples="{values.shape[0]}"' if tuples else ""
    return (f'{head} type="{vtk_type}" Name={quoteattr(name)}{components}{count} format="ascii">'
            f"{_text(values)}</DataArray>\n")


def vtp_text(data: PolyData) -> str:
    """The VTK XML PolyData document of ``data`` (ASCII)."""
    out = ['<?xml version="1.0"?>\n',
           '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64">\n',
           "  <PolyData>\n"]
    if data.field_data:
        out.append("    <FieldData>\n")
        out += [_data_array(name, values, " " * 6, tuples=True) for name, values in data.field_data.items()]
        out.append("    </FieldData>\n")
    counts = {kind: getattr(data, kind).count for kind in CELL_KINDS}
    out.append(f'    <Piece NumberOfPoints="{len(data.points)}" NumberOfVerts="{counts["verts"]}" '
               f'NumberOfLines="{counts["lines"]}" NumberOfStrips="0" NumberOfPolys="{counts["polys"]}">\n')
    active = "".join(f" {attr}={quoteattr(name)}" for attr, name in (("Scalars", data.active_scalars),
                                                                      ("Vectors", data.active_vectors)) if name)
    out.append(f"      <PointData{active}>\n")
    out += [_data_array(name, values, " " * 8) for name, values in data.point_data.items()]
    out.append("      </PointData>\n      <CellData>\n")
    out += [_data_array(name, values, " " * 8) for name, values in data.cell_data.items()]
    out.append("      </CellData>\n      <Points>\n")
    out.append(_data_array("Points", data.points, " " * 8))
    out.append("      </Points>\n")
    for kind, tag in (("verts", "Verts"), ("lines", "Lines"), ("polys", "Polys")):
        cells = getattr(data, kind)
        out.append(f"      <{tag}>\n")
        out.append(_data_array("connectivity", cells.connectivity, " " * 8))
        out.append(_data_array("offsets", cells.offsets, " " * 8))
        out.append(f"      </{tag}>\n")
    out.append("    </Piece>\n  </PolyData>\n</VTKFile>\n")
    return "".join(out)


def write_vtp(path, data: PolyData) -> Path:
    """Write ``data`` as a ``.vtp`` file (replaced atomically). Returns the path."""
    path = Path(path)
    _replace(path, vtp_text(data))
    return path


def write_pvd(path, series) -> list[Path]:
    """Write a ParaView collection ``path`` (``.pvd``) of ``series``: ``(time, PolyData)`` pairs.
    Each step goes to ``<stem>/<stem>_<step>.vtp`` beside it (referred to by a relative path).
    Times must increase strictly (ParaView shows one data set per time); otherwise the step
    indices are used. Returns the step files."""
    path = Path(path)
    series = list(series)
    times = np.array([float(t) for t, _ in series])
    if times.size > 1 and not np.all(np.diff(times) > 0):
        times = np.arange(times.size, dtype=float)
    folder = path.with_suffix("")
    folder.mkdir(exist_ok=True)
    width = max(4, len(str(len(series) - 1)))
    files = []
    lines = ['<?xml version="1.0"?>\n', '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n',
             "  <Collection>\n"]
    for i, (t, (_, data)) in enumerate(zip(times, series)):
        step = folder / f"{folder.name}_{i:0{width}d}.vtp"
        write_vtp(step, data)
        files.append(step)
        relative = f"{folder.name}/{step.name}"
        lines.append(f'    <DataSet timestep="{float(t)!r}" group="" part="0" file={quoteattr(relative)}/>\n')
    lines.append("  </Collection>\n</VTKFile>\n")
    _replace(path, "".join(lines))
    return files


def _replace(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it over ``path``."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text(text, encoding="utf-8")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
