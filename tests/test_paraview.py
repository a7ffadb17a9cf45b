"""ParaView files: every documented array of a ``.vtp`` read back (by an independent XML reader,
and by VTK itself where it is installed), the ``.pvd`` time series of an inverse run, and the
frames CSV. Exactness: floats are written in shortest round-trip form, so positions, tensions
and transforms read back bit for bit."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.solver import gallery
from vertebra.solver.gallery.targets import pose_circle
from vertebra.solver.inverse.trajectory import Trajectory, write_trajectory
from vertebra.core.lie import qmatrix
from vertebra.solver.paraview import PARTS, trunk_polydata, write_vtp
from vertebra.solver.report import FRAME_COLUMNS
from test_inverse_controller import pneumatic_entry
from vtk_xml import read_pvd, read_vtp

POINT_ARRAYS = {"vertebra", "frame", "cable", "effector", "radius", "x_axis", "y_axis", "z_axis"}
CELL_ARRAYS = {"part", "link", "vertebra", "cable", "effector", "tension", "error"}


@pytest.fixture(scope="module")
def tendon():
    model = solver.build_model(gallery.load("tendon_two_section"))
    return model, model.solve({"s1-0": 3.0, "s2-180": 1.5})


def _part(data, part):
    """Cells of ``part`` (by name) as (kind, index within the kind, global cell index)."""
    code = PARTS.index(part)
    out, offset = [], 0
    for kind in ("verts", "lines", "polys"):
        for i, _ in enumerate(data.cells[kind]):
            if data.cell_data["part"][offset + i] == code:
                out.append((kind, i, offset + i))
        offset += len(data.cells[kind])
    return out


def test_vtp_carries_every_documented_array(tendon, tmp_path):
    model, result = tendon
    state = result.state
    path = write_vtp(tmp_path / "t.vtp", trunk_polydata(model, state, result.actuation, time=2.5))
    data = read_vtp(path)
    assert set(data.point_data) == POINT_ARRAYS and set(data.cell_data) == CELL_ARRAYS
    assert data.active == {"Scalars": "radius", "Vectors": "z_axis"}
    assert data.field_data["part_names"] == list(PARTS)
    assert data.field_data["cable_names"] == model.actuator_names
    assert np.array_equal(data.field_data["cable_tension"], result.actuation)
    assert data.field_data["effector_names"] == ["mid", "tip"]
    assert data.field_data["TimeValue"].tolist() == [2.5]
    assert data.field_data["vertebra_version"] == [__import__("vertebra").__version__]
    assert "chamber_names" not in data.field_data            # the scene has no chambers

    # frames: positions bit for bit, their axes the columns of the rotation, vertebra indices
    frame = data.point_data["frame"]
    at = np.flatnonzero(frame >= 0)
    assert np.array_equal(frame[at], np.arange(model.n_frames))
    assert np.array_equal(data.points[at], state.positions)
    R = qmatrix(state.quaternions)
    for k, axis in enumerate(("x_axis", "y_axis", "z_axis")):
        assert np.max(np.abs(data.point_data[axis][at] - R[:, :, k])) == 0.0
        assert np.all(data.point_data[axis][frame < 0] == 0.0)
    vertebra = data.point_data["vertebra"][at]
    assert np.array_equal(np.flatnonzero(vertebra >= 0), model.vertebra_frames)
    assert np.array_equal(vertebra[model.vertebra_frames], np.arange(len(model.vertebra_frames)))
    # a nitinol rod of radius 0.7 mm: the backbone's tube radius (m)
    assert np.allclose(data.point_data["radius"][at], 7e-4, rtol=1e-12)

    # backbone: one line per link, joining frames k and k + 1
    backbone = _part(data, "backbone")
    assert len(backbone) == model.n_links
    for link, (kind, i, c) in enumerate(backbone):
        assert kind == "lines" and data.cell_data["link"][c] == link
        assert frame[data.cells["lines"][i]].tolist() == [link, link + 1]

    # cables: pieces between holes; their lengths add up to the model's cable lengths and
    # every piece carries its cable's tension (N)
    lengths = np.zeros(model.n_cables)
    for kind, i, c in _part(data, "cable"):
        cable = data.cell_data["cable"][c]
        a, b = data.points[data.cells["lines"][i]]
        lengths[cable] += np.linalg.norm(b - a)
        assert data.cell_data["tension"][c] == result.actuation[cable]
        assert np.all(data.point_data["cable"][data.cells["lines"][i]] == cable)
    assert np.allclose(lengths, model.cable_lengths(state), rtol=1e-13)
    others = [c for part in ("backbone", "vertebra", "effector", "target") for _, _, c in _part(data, part)]
    assert np.all(data.cell_data["tension"][others] == 0.0) and np.all(data.cell_data["cable"][others] == -1)

    # vertebra discs: one polygon per vertebra, centred on its frame, in its x–y plane
    discs = _part(data, "vertebra")
    assert len(discs) == len(model.vertebra_frames)
    for v, (kind, i, c) in enumerate(discs):
        rim = data.points[data.cells["polys"][i]]
        f = model.vertebra_frames[v]
        assert kind == "polys" and data.cell_data["vertebra"][c] == v
        assert np.allclose(rim.mean(0), state.positions[f], atol=1e-15)
        assert np.max(np.abs((rim - state.positions[f]) @ R[f][:, 2])) < 1e-15

    # effectors and targets: vertex cells at the model's positions and the scene's targets,
    # each with its effector id and the distance between the two (m)
    positions, targets = model.effector_positions(state), model.effector_targets
    for part, where in (("effector", positions), ("target", targets)):
        cells = _part(data, part)
        assert [data.cell_data["effector"][c] for _, _, c in cells] == [0, 1]
        for kind, i, c in cells:
            e = data.cell_data["effector"][c]
            assert kind == "verts" and np.array_equal(data.points[data.cells["verts"][i]][0], where[e])
            assert data.cell_data["error"][c] == pytest.approx(np.linalg.norm(positions[e] - targets[e]), rel=1e-15)


def test_chambers_are_named_in_field_data(tmp_path):
    entry = pneumatic_entry()
    scene = solver.parse_scene({"catalogue": {"path": "unused.h5"},
                                "segment": [{"type": "entry", "entry": entry.name, "count": 3}],
                                "chamber": [{"name": f"c{k}", "cavity": k, "to": 3, "pressure": 1e4 * k}
                                            for k in range(3)],
                                "effector": [{"name": "tip"}]})
    model = solver.build_model(scene, entries={entry.name: entry})
    data = read_vtp(write_vtp(tmp_path / "p.vtp", trunk_polydata(model, model.solve().state)))
    assert data.field_data["chamber_names"] == ["c0", "c1", "c2"]
    assert data.field_data["chamber_pressure"].tolist() == [0.0, 1e4, 2e4]
    assert "cable_names" not in data.field_data and "target" not in [PARTS[p] for p in data.cell_data["part"]]
    # an entry without a radius parameter: the documented default, 2 % of the trunk's length
    frame = data.point_data["frame"] >= 0
    assert np.allclose(data.point_data["radius"][frame], 0.02 * model.length_scale)


def test_simulate_writes_vtp_and_frames(tmp_path, capsys):
    vtp, frames = tmp_path / "shape.vtp", tmp_path / "frames.csv"
    code = main(["simulate", "gallery:tendon_two_section", "--vtk", str(vtp), "--frames", str(frames)])
    assert code == 0
    model = solver.build_model(gallery.load("tendon_two_section"))
    state = model.solve().state
    data = read_vtp(vtp)
    assert np.array_equal(data.points[data.point_data["frame"] >= 0], state.positions)
    with open(frames, newline="") as handle:
        rows = list(csv.reader(handle))
    assert tuple(rows[0]) == FRAME_COLUMNS == ("T11", "T12", "T13", "T14", "T21", "T22", "T23", "T24",
                                               "T31", "T32", "T33", "T34", "T41", "T42", "T43", "T44")
    table = np.array(rows[1:], dtype=float)
    assert table.shape == (model.n_frames, 16)
    # row-major: T14, T24, T34 are the translation; the last row of each 4×4 is [0, 0, 0, 1]
    assert np.array_equal(table.reshape(-1, 4, 4), state.transforms())
    assert np.array_equal(table[:, [3, 7, 11]], state.positions)
    assert np.array_equal(table[:, 12:], np.tile([0.0, 0.0, 0.0, 1.0], (model.n_frames, 1)))


def _track(tmp_path, capsys):
    """``vertebra invert --vtk track.pvd`` along three points of a reachable circle (a pulled
    tendon's pose turned about the axis): the .pvd's path and the run's JSON document."""
    model = solver.build_model(gallery.load("paper_5v_16t"))
    pulled = np.zeros(16)
    pulled[[3, 15]] = 1.0
    trajectory = tmp_path / "path.csv"
    write_trajectory(trajectory, Trajectory(pose_circle(model, pulled, 3), np.array([0.0, 0.25, 0.5])),
                     model.effector_names)
    pvd = tmp_path / "track.pvd"
    code = main(["invert", "gallery:paper_5v_16t", "--trajectory", str(trajectory), "--vtk", str(pvd), "--json"])
    assert code == 0
    return pvd, __import__("json").loads(capsys.readouterr().out)


def test_invert_writes_a_pvd_time_series(tmp_path, capsys):
    pvd, document = _track(tmp_path, capsys)
    steps = read_pvd(pvd)
    assert [t for t, _ in steps] == [0.0, 0.25, 0.5]
    assert [f.relative_to(tmp_path).as_posix() for _, f in steps] == [f"track/track_{i:04d}.vtp" for i in range(3)]
    for k, (t, file) in enumerate(steps):
        data = read_vtp(file)
        assert data.field_data["TimeValue"].tolist() == [t]
        reported = document["steps"][k]
        tensions = [reported["cables"][name]["tension"] for name in data.field_data["cable_names"]]
        assert data.field_data["cable_tension"].tolist() == tensions
        for kind, i, c in _part(data, "target"):
            e = data.cell_data["effector"][c]
            name = data.field_data["effector_names"][e]
            assert data.points[data.cells["verts"][i]][0].tolist() == reported["effectors"][name]["target"]
            assert data.cell_data["error"][c] == pytest.approx(reported["effectors"][name]["error"], rel=1e-12)


@pytest.mark.parametrize("argv,option", [
    (["simulate", "gallery:tendon_two_section", "--vtk", "out.vtu"], "--vtk"),
    (["simulate", "gallery:tendon_two_section", "--frames", "out.txt"], "--frames"),
    (["invert", "gallery:paper_3v_4t", "--vtk", "out.vtp"], "--vtk"),
])
def test_wrong_output_extensions_are_refused_before_solving(argv, option, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert option in err and not any(tmp_path.iterdir())


def test_vtk_reads_the_files_and_tubes_take_the_radius(tendon, tmp_path):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    model, result = tendon
    write_vtp(tmp_path / "t.vtp", trunk_polydata(model, result.state, result.actuation, time=1.0))
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(tmp_path / "t.vtp"))
    reader.Update()
    data = reader.GetOutput()
    mine = read_vtp(tmp_path / "t.vtp")
    assert data.GetNumberOfPoints() == len(mine.points)
    assert (data.GetNumberOfVerts(), data.GetNumberOfLines(), data.GetNumberOfPolys()) == tuple(
        len(mine.cells[k]) for k in ("verts", "lines", "polys"))
    assert np.array_equal(vtk_to_numpy(data.GetPoints().GetData()), mine.points)
    for name in POINT_ARRAYS:
        assert np.array_equal(vtk_to_numpy(data.GetPointData().GetArray(name)), mine.point_data[name])
    for name in CELL_ARRAYS:
        assert np.array_equal(vtk_to_numpy(data.GetCellData().GetArray(name)), mine.cell_data[name])
    names = data.GetFieldData().GetAbstractArray("cable_names")
    assert [names.GetValue(i) for i in range(names.GetNumberOfValues())] == model.actuator_names
    assert data.GetPointData().GetScalars().GetName() == "radius"
    # ParaView's Tube filter with "Vary Radius: By Absolute Scalar" on the backbone: the tube's
    # surface lies at the rod's radius (0.7 mm) from the axis of a straight rest trunk
    rest = trunk_polydata(model, model.rest_state)
    write_vtp(tmp_path / "rest.vtp", rest)
    reader.SetFileName(str(tmp_path / "rest.vtp"))
    reader.Update()
    threshold = vtk.vtkThreshold()
    threshold.SetInputConnection(reader.GetOutputPort())
    threshold.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_CELLS, "part")
    threshold.SetLowerThreshold(0), threshold.SetUpperThreshold(0)
    surface = vtk.vtkGeometryFilter()
    surface.SetInputConnection(threshold.GetOutputPort())
    tube = vtk.vtkTubeFilter()
    tube.SetInputConnection(surface.GetOutputPort())
    tube.SetVaryRadiusToVaryRadiusByAbsoluteScalar()
    tube.SetNumberOfSides(12)
    tube.Update()
    xyz = vtk_to_numpy(tube.GetOutput().GetPoints().GetData())
    assert np.allclose(np.hypot(xyz[:, 0], xyz[:, 1]), 7e-4, rtol=1e-6)


def test_vtk_reads_every_step_of_the_pvd_series(tmp_path, capsys):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    pvd, _ = _track(tmp_path, capsys)
    reader = vtk.vtkXMLPolyDataReader()
    for t, file in read_pvd(pvd):
        reader.SetFileName(str(file))
        reader.Update()
        data = reader.GetOutput()
        mine = read_vtp(file)
        assert data.GetNumberOfPoints() == len(mine.points) > 0
        point_data, cell_data = data.GetPointData(), data.GetCellData()
        assert {point_data.GetArrayName(i) for i in range(point_data.GetNumberOfArrays())} == POINT_ARRAYS
        assert {cell_data.GetArrayName(i) for i in range(cell_data.GetNumberOfArrays())} == CELL_ARRAYS
        assert vtk_to_numpy(data.GetFieldData().GetArray("TimeValue")).tolist() == [t]
        assert np.array_equal(vtk_to_numpy(cell_data.GetArray("tension")), mine.cell_data["tension"])
