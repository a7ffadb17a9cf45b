"""``vertebra invert``: JSON contract, trajectories, plot and exit codes.

Runs the real dispatcher ``cli_main.main`` in-process (its table is narrowed to the
``invert`` subcommand so these tests do not depend on the other subcommands' modules).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import vertebra as vertebra_package
from vertebra.cli import main as cli_main
from vertebra import solver
from vertebra.solver.gallery import load, path
from vertebra.solver.inverse.trajectory import Trajectory, read_trajectory, write_trajectory
from vertebra.core.errors import TrajectoryError


@pytest.fixture
def vertebra(monkeypatch, capsys):
    monkeypatch.setattr(cli_main, "SUBCOMMANDS", {"invert": cli_main.SUBCOMMANDS["invert"]})

    def run(*argv):
        code = cli_main.main(["invert", *map(str, argv)])
        out, err = capsys.readouterr()
        return code, out, err

    return run


def _scene_with_target(tmp_path, name, targets):
    """The gallery scene's TOML with its effector targets replaced (in file order)."""
    text = path(name).read_text()
    values = iter(targets)
    text = re.sub(r"^target = \[.*\]$", lambda m: "target = [%r, %r, %r]" % tuple(float(v) for v in next(values)),
                  text, flags=re.M)
    out = tmp_path / f"{name}.toml"
    out.write_text(text)
    return out


def _forward_tips(name, actuation):
    model = solver.build_model(load(name))
    return model, model.effector_positions(model.solve(np.array(actuation)).state)


def test_reachable_target_exit_0_and_json_contract(tmp_path, vertebra):
    # Target from a forward solution: converged mode reaches it to the 1e-6 m default.
    model, tips = _forward_tips("paper_3v_4t", [2.0, 0.5, 0.0, 1.0])
    scene = _scene_with_target(tmp_path, "paper_3v_4t", tips)
    code, out, err = vertebra(scene, "--json")
    assert code == 0, err
    doc = json.loads(out)  # stdout is one JSON document and nothing else
    assert doc["reached"] is True and doc["converged"] is True and doc["unreached"] == []
    assert doc["vertebra_version"] == vertebra_package.__version__
    step = doc["steps"][0]
    assert set(step["cables"]) == set(model.actuator_names) and step["chambers"] == {}
    tip = step["effectors"]["tip"]
    assert tip["error"] <= 1e-6
    assert np.linalg.norm(np.subtract(tip["position"], tip["target"])) == pytest.approx(tip["error"])
    lo, hi = model.actuator_bounds
    tensions = np.array([step["cables"][n]["tension"] for n in model.actuator_names])
    assert np.all(tensions >= lo) and np.all(tensions <= hi)
    assert doc["timing"]["median_step_s"] > 0


def test_unreachable_target_exit_1_and_json_says_which(tmp_path, vertebra):
    scene = _scene_with_target(tmp_path, "paper_3v_4t", [[0.08, 0.0, 0.03]])
    code, out, _ = vertebra(scene, "--json")
    assert code == 1
    doc = json.loads(out)
    assert doc["reached"] is False
    assert [u["effector"] for u in doc["unreached"]] == ["tip"]
    assert doc["unreached"][0]["error"] > 1e-3
    assert doc["steps"][0]["status"] == "closest_reach"


def test_trajectory_in_tick_mode_with_plot(tmp_path, vertebra):
    # Three nearby targets from forward solutions, one linearise–QP step per tick: the
    # settled error stays within the 1 mm tick default; the plot is a PNG.
    model = solver.build_model(load("paper_5v_16t"))
    targets, state = [], None
    for a in (0.2, 0.4, 0.6):
        lam = np.full(16, 0.1)
        lam[[0, 4, 8, 12]] += a
        state = model.solve(lam, initial=state).state
        targets.append(model.effector_positions(state))
    csv_path = tmp_path / "path.csv"
    write_trajectory(csv_path, Trajectory(np.array(targets), np.array([0.0, 0.1, 0.2])), model.effector_names)
    png = tmp_path / "track.png"
    code, out, err = vertebra(path("paper_5v_16t"), "--trajectory", csv_path, "--mode", "tick",
                              "--json", "--plot", png)
    assert code == 0, err
    doc = json.loads(out)
    assert doc["mode"] == "tick" and len(doc["steps"]) == 3
    assert [s["t"] for s in doc["steps"]] == [0.0, 0.1, 0.2]
    assert set(doc["steps"][0]["effectors"]) == {"mid", "tip"}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("header, row, field", [
    ("t,elbow.x,elbow.y,elbow.z", "0,0,0,0.1", "elbow.x"),  # unknown effector
    ("t,tip.x,tip.y", "0,0,0", "tip.z"),  # incomplete
    ("t,tip.x,tip.y,tip.z", "0,0,zero,0.1", "row 2, column tip.y"),  # not a number
    ("t,tip.x,tip.y,tip.z", "0,0,0,inf", "row 2, column tip.z"),  # not finite
])
def test_bad_trajectory_exit_2_names_file_and_field(tmp_path, vertebra, header, row, field):
    csv_path = tmp_path / "bad.csv"
    csv_path.write_text(f"{header}\n{row}\n")
    code, out, err = vertebra(path("paper_3v_4t"), "--trajectory", csv_path)
    assert code == 2 and out == ""
    assert str(csv_path) in err and field in err


def test_missing_trajectory_file_and_bad_options_exit_2(tmp_path, vertebra):
    for argv, where in (((path("paper_3v_4t"), "--trajectory", tmp_path / "none.csv"), "none.csv: file not found"),
                        ((path("paper_3v_4t"), "--backend", "simplex"), "backend: unknown QP backend 'simplex'"),
                        ((path("paper_3v_4t"), "--tolerance", "-1"), "tolerance: must be a positive length"),
                        ((path("paper_3v_4t"), "--regularisation", "nan", "--effort", "penalty"),
                         "regularisation: must be finite"),
                        ((path("paper_3v_4t"), "--regularisation", "1e-3"), "give --effort penalty"),
                        ((path("paper_3v_4t"), "--max-iterations", "0"), "max_iterations: must be ≥ 1")):
        code, out, err = vertebra(*argv)
        assert code == 2 and out == "" and where in err, err


def test_trajectory_csv_round_trip(tmp_path):
    names = ["mid", "tip"]
    rng = np.random.default_rng(0)
    traj = Trajectory(rng.normal(size=(5, 2, 3)), np.linspace(0, 1, 5))
    write_trajectory(tmp_path / "t.csv", traj, names)
    back = read_trajectory(tmp_path / "t.csv", names)
    np.testing.assert_array_equal(back.targets, traj.targets)  # repr() round-trips floats exactly
    np.testing.assert_array_equal(back.times, traj.times)
    # without a t column the step index is the time; missing effectors keep scene targets
    (tmp_path / "u.csv").write_text("tip.x,tip.y,tip.z\n1,2,3\n4,5,6\n")
    back = read_trajectory(tmp_path / "u.csv", names, [[7, 8, 9], [np.nan] * 3])
    np.testing.assert_array_equal(back.times, [0, 1])
    np.testing.assert_array_equal(back.targets[:, 0], [[7, 8, 9], [7, 8, 9]])
    with pytest.raises(TrajectoryError, match="neither columns here nor a target"):
        read_trajectory(tmp_path / "u.csv", ["mid", "tip"])


def test_orientation_target_for_a_vertebra_axis(tmp_path, vertebra):
    # posture with a direction: tip position AND tip axis direction, both from a forward solution
    # under known tensions, are reached by the converged inverse (errors: m and dimensionless)
    import tomllib

    from vertebra.solver.inverse import invert
    from vertebra.core.lie import qrotate
    from vertebra.solver.scene import scene_toml

    data = tomllib.loads(path("tendon_two_section").read_text())
    model = solver.build_model(solver.parse_scene(data))
    known = np.zeros(len(model.actuator_names))
    known[1], known[3] = 4.0, 2.0
    state = model.solve(known).state
    direction = qrotate(state.quaternions[-1], np.array([0.0, 0.0, 1.0]))
    tip = model.effector_positions(state)[model.effector_names.index("tip")]
    data["effector"] = [{"name": "tip", "vertebra": -1, "target": [float(v) for v in tip]},
                        {"name": "tip-axis", "vertebra": -1, "axis": [0.0, 0.0, 1.0],
                         "target": [float(v) for v in direction], "weight": 0.1}]
    model = solver.build_model(solver.parse_scene(data))
    step = invert(model, model.effector_targets)
    assert step.reached and np.all(step.errors <= 1e-6)
    assert np.all(step.actuation >= 0.0)
    scene_path = tmp_path / "axis.toml"
    scene_path.write_text(scene_toml(data))
    code, out, err = vertebra(scene_path, "--json")
    assert code == 0, err
    assert set(json.loads(out)["steps"][-1]["effectors"]["tip-axis"]) == {"target", "direction", "error",
                                                                         "predicted_error", "prediction_miss"}
