"""A reader of the ASCII VTK XML files vertebra writes (``.vtp`` PolyData, ``.pvd`` collections),
written from the VTK file-format description, independent of the writer: the tests read back
what was written with it (meshio reads no PolyData)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_DTYPES = {"Float64": float, "Float32": float, "Int32": np.int64, "Int64": np.int64, "UInt8": np.int64}


def _array(element):
    """One ASCII ``<DataArray>``: a numpy array ((n,) or (n, components)), or a list of str."""
    assert element.get("format") == "ascii", element.attrib
    text = (element.text or "").split()
    if element.get("type") == "String":
        codes, strings, current = [int(v) for v in text], [], []
        for code in codes:
            if code == 0:
                strings.append(bytes(current).decode("utf-8"))
                current = []
            else:
                current.append(code)
        assert not current, "string array not 0-terminated"
        return strings
    values = np.array([_DTYPES[element.get("type")](v) for v in text])
    components = int(element.get("NumberOfComponents", "1"))
    return values.reshape(-1, components) if components > 1 else values


@dataclass
class PolyDataFile:
    points: np.ndarray
    cells: dict            # "verts"/"lines"/"polys" -> list of point-index arrays
    point_data: dict
    cell_data: dict
    field_data: dict
    active: dict           # PointData attributes Scalars / Vectors


def read_vtp(path) -> PolyDataFile:
    root = ET.parse(path).getroot()
    assert root.get("type") == "PolyData"
    poly = root.find("PolyData")
    field = poly.find("FieldData")
    field_data = {a.get("Name"): _array(a) for a in (field if field is not None else [])}
    piece = poly.find("Piece")
    points = _array(piece.find("Points/DataArray"))
    assert points.shape == (int(piece.get("NumberOfPoints")), 3)
    cells = {}
    for tag, kind in (("Verts", "verts"), ("Lines", "lines"), ("Polys", "polys")):
        arrays = {a.get("Name"): _array(a) for a in piece.find(tag)}
        ends = arrays["offsets"]
        starts = np.r_[0, ends[:-1]]
        cells[kind] = [arrays["connectivity"][a:b] for a, b in zip(starts, ends)]
        assert len(cells[kind]) == int(piece.get(f"NumberOf{tag}"))
    point_data = {a.get("Name"): _array(a) for a in piece.find("PointData")}
    cell_data = {a.get("Name"): _array(a) for a in piece.find("CellData")}
    return PolyDataFile(points, cells, point_data, cell_data, field_data, dict(piece.find("PointData").attrib))


def read_pvd(path) -> list[tuple[float, Path]]:
    """(time, step file) of every data set of a ``.pvd`` collection."""
    root = ET.parse(path).getroot()
    assert root.get("type") == "Collection"
    return [(float(d.get("timestep")), Path(path).parent / d.get("file")) for d in root.find("Collection")]
