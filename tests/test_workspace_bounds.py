"""A sampled workspace counts, flags and (on request) drops the samples whose equilibrium breaks a
bound of the scene that the sampled box does not hold, or leaves an entry's fitted range."""

from __future__ import annotations

import json

import numpy as np

from vertebra import solver
from vertebra.cli.main import main
from vertebra.solver.scene import scene_toml
from vertebra.solver.workspace import sample_workspace, write_points

from test_bounds import robot


def test_samples_beyond_a_stroke_bound_are_counted_flagged_and_dropped_on_request(tmp_path):
    # the tension box [0, 15] N of tendon t1 pulls its path shorter than its min_stroke (−4 mm)
    model = solver.build_model(solver.parse_scene(robot(min_stroke=-0.004)))
    workspace = sample_workspace(model, 64)
    strokes = np.array([model.actuator_displacements(model.solve(a).state, a)[0] for a in workspace.actuations])
    expected = strokes < -0.004 * (1 + 1e-9)
    assert 0 < expected.sum() < 64
    np.testing.assert_array_equal(workspace.beyond_bounds, expected)
    summary = workspace.summary()
    assert summary["beyond_bounds"] == expected.sum() and summary["out_of_range"] == 0
    assert summary["violations"] == {"t1: min_stroke": int(expected.sum())} and summary["dropped"] == 0
    assert summary["effectors"]["tip"]["count"] == 64
    dropped = sample_workspace(model, 64, drop_outside=True)
    assert dropped.summary()["dropped"] == expected.sum()
    assert dropped.summary()["effectors"]["tip"]["count"] == 64 - expected.sum()
    np.testing.assert_array_equal(dropped.cloud("tip").points, workspace.positions[~expected, 0])
    write_points(workspace, tmp_path / "points.csv")
    header = (tmp_path / "points.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(tmp_path / "points.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, header.index("beyond_bounds")], expected)


def test_workspace_cli_reports_and_drops(tmp_path, capsys):
    path = tmp_path / "rod.toml"
    path.write_text(scene_toml(robot(min_stroke=-0.004)))
    assert main(["workspace", str(path), "--samples", "32", "--json", "--drop-outside"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["beyond_bounds"] > 0 and document["dropped"] == document["beyond_bounds"]
    assert document["settings"]["drop_outside"] is True
    assert document["effectors"]["tip"]["count"] == 32 - document["dropped"]
    assert main(["workspace", str(path), "--samples", "32"]) == 0
    out = capsys.readouterr().out
    assert "break a bound of the scene" in out and "t1: min_stroke" in out and "--drop-outside" in out


def test_samples_outside_an_entrys_fitted_range_are_counted():
    # a fitted entry trusted up to 0.05 rad of bending per link, bent by a tip moment and its
    # chambers: the samples whose links bend further are counted by entry and quantity
    from test_solver_fitted import CHAMBERS, FITTED, _model, _narrow

    entry = _narrow(FITTED, 0.05)
    model = _model(entry, loads=({"vertebra": -1, "moment": [0.0, 0.25, 0.0]},),
                   chambers=[dict(c, min_pressure=0.0) for c in CHAMBERS])
    workspace = sample_workspace(model, 16)
    assert workspace.converged.all()
    outside = np.array([bool(model.solve(a).out_of_range) for a in workspace.actuations])
    np.testing.assert_array_equal(workspace.out_of_range, outside)
    summary = workspace.summary()
    assert summary["out_of_range"] == outside.sum() > 0
    assert summary["violations"][f"{entry.name}: bending strain"] == outside.sum()
