"""Workspace sampling: actuations within bounds, solve orders, warm-started solves that agree
with cold ones, failures recorded, hulls, files and the ``vertebra workspace`` command."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver import gallery
from vertebra.solver.hull import affine_dimension, convex_hull
from vertebra.solver.workspace import (ORDERINGS, SolveOrder, response_coordinates,
                                       sample_actuations, sample_workspace, write_points)
from vertebra.core.errors import OptionError, SceneError


@pytest.fixture(scope="module")
def robot():
    return solver.build_model(solver.load_scene("gallery:paper_3v_4t"))


def gallery_data(name: str) -> dict:
    return tomllib.loads(gallery.path(name).read_text())


def test_actuations_lie_within_bounds_and_depend_on_the_seed(robot):
    lower, upper = robot.actuator_bounds
    for method in ("sobol", "halton"):
        a = sample_actuations(robot, 200, method=method, seed=3)
        assert a.shape == (200, 4) and np.all(a >= lower) and np.all(a <= upper)
        assert np.array_equal(a, sample_actuations(robot, 200, method=method, seed=3))
        assert not np.array_equal(a, sample_actuations(robot, 200, method=method, seed=4))
        # quasi-random: every quarter of every actuator's range is hit (a fair sample is not enough)
        quarters = np.floor(4 * (a - lower) / (upper - lower)).astype(int)
        assert all(set(quarters[:, k]) == {0, 1, 2, 3} for k in range(4))
    with pytest.raises(OptionError, match="sampler"):
        sample_actuations(robot, 10, method="random")


def test_unbounded_actuator_is_a_scene_error_naming_the_field():
    data = gallery_data("paper_3v_4t")
    del data["cable"][2]["max_tension"]
    model = solver.build_model(solver.parse_scene(data, source="robot.toml"))
    with pytest.raises(SceneError, match=r"robot.toml: cable\[2\].max_tension"):
        sample_workspace(model, 4)


@pytest.mark.parametrize("ordering", sorted(ORDERINGS))
def test_orders_visit_every_sample_once_after_its_parent(robot, ordering):
    coordinates = response_coordinates(robot, sample_actuations(robot, 300))
    plan = ORDERINGS[ordering](coordinates)          # SolveOrder checks both on construction
    assert plan.order.shape == (300,) and np.sum(plan.parent < 0) >= 1
    with pytest.raises(ValueError, match="parent"):
        SolveOrder(plan.order[::-1].copy(), plan.parent)   # reversed: children before parents


def test_tree_edges_are_shorter_than_the_sampled_order(robot):
    # the spanning tree takes the shortest edges available; the chain's leftovers jump far
    coordinates = response_coordinates(robot, sample_actuations(robot, 500))

    def mean_edge(plan):
        has = plan.parent >= 0
        return np.linalg.norm(coordinates[has] - coordinates[plan.parent[has]], axis=1).mean()

    tree, chain, sampled = (mean_edge(ORDERINGS[name](coordinates)) for name in ("tree", "chain", "sampled"))
    assert tree <= chain < sampled


def test_warm_started_samples_match_cold_solves(robot):
    # each sample solved from its tree parent's predicted state reaches the same equilibrium as a
    # solve from rest: both stop at scaled residual ≤ 1e-9, i.e. within ~1e-9 of the deflection
    # (~1 cm) of each other — 1e-9 m bounds it with margin
    workspace = sample_workspace(robot, 40, seed=2)
    assert workspace.converged.all() and not workspace.failures
    assert workspace.warm.sum() == 39 and workspace.predicted.sum() == 39   # all but the root
    cold_iterations = []
    for i in range(40):
        cold = robot.solve(workspace.actuations[i])
        cold_iterations.append(cold.iterations)
        assert np.abs(robot.effector_positions(cold.state) - workspace.positions[i]).max() <= 1e-9
    # the Euler predictor saves Newton iterations over solving from rest
    assert workspace.iterations.mean() < np.mean(cold_iterations)


def test_failed_solves_are_recorded_and_their_children_start_from_rest():
    # one Newton iteration per load stage cannot solve 5 N tendon pulls; unloaded samples and a
    # micro-newton pull still converge
    data = gallery_data("paper_3v_4t")
    data["solver"] = {"max_iterations": 1}
    model = solver.build_model(solver.parse_scene(data))
    actuations = np.zeros((10, 4))
    actuations[1::2, 0] = 5.0
    actuations[3] = [0.0, 1e-6, 0.0, 0.0]
    workspace = sample_workspace(model, actuations=actuations, ordering="sampled")
    failed = [f["sample"] for f in workspace.failures]
    assert failed == [1, 5, 7, 9] and all(f["error"] == "ConvergenceError" for f in workspace.failures)
    assert np.isnan(workspace.positions[failed]).all() and not np.isnan(workspace.positions[~np.isin(np.arange(10), failed)]).any()
    assert not workspace.warm[[2, 6, 8]].any()          # their parents failed: started from rest
    summary = workspace.summary()
    assert summary["failed"] == 4 and summary["effectors"]["tip"]["count"] == 6
    json.dumps(summary, allow_nan=False)


def test_worker_processes_and_dask_give_the_same_clouds(robot):
    # each generation is cut into parts of 16 samples solved by two processes (or dask workers):
    # the same starts as in one process, so the same equilibria (to rounding: a batch's
    # composition changes only the order of sums)
    serial = sample_workspace(robot, 40, seed=5)
    parallel = sample_workspace(robot, 40, seed=5, workers=2, chunk=16)
    assert parallel.converged.all() and serial.converged.all()
    assert np.abs(parallel.positions - serial.positions).max() <= 1e-12
    assert np.array_equal(parallel.warm, serial.warm) and np.array_equal(parallel.iterations, serial.iterations)
    assert parallel.settings["workers"] == 2


@pytest.mark.slow
def test_dask_executor_gives_the_same_clouds(robot):
    pytest.importorskip("dask.distributed")
    serial = sample_workspace(robot, 40, seed=5)
    dask = sample_workspace(robot, 40, seed=5, workers=2, chunk=16, executor="dask")
    assert dask.converged.all() and dask.settings["executor"] == "dask"
    assert np.abs(dask.positions - serial.positions).max() <= 1e-12


def test_generations_solve_each_sample_after_its_parent(robot):
    from vertebra.solver.workspace_order import generations

    # every 512th from rest; every 64th from those; every 8th from the nearest of both; the others
    # from the nearest of all (a sample whose nearest is an earlier start is in an earlier generation)
    coordinates = response_coordinates(robot, sample_actuations(robot, 1100))
    depth = generations(ORDERINGS["levels"](coordinates))
    assert np.flatnonzero(depth == 0).tolist() == [0, 512, 1024] and depth.max() == 3
    assert np.all(depth[np.arange(0, 1100, 64)] <= 1) and np.all(depth[np.arange(0, 1100, 8)] <= 2)
    assert np.count_nonzero(depth == 3) > 500
    tree = ORDERINGS["tree"](coordinates)
    depth = generations(tree)
    has = tree.parent >= 0
    assert np.all(depth[has] == depth[tree.parent[has]] + 1) and np.all(depth[~has] == 0)
    # the tree's generations reach the same equilibria as the levels' batches
    actuations = sample_actuations(robot, 60, seed=1)
    a = sample_workspace(robot, actuations=actuations, ordering="tree")
    b = sample_workspace(robot, actuations=actuations)
    assert a.converged.all() and b.converged.all()
    assert np.abs(a.positions - b.positions).max() <= 1e-9


def test_convex_hull_of_known_clouds():
    rng = np.random.default_rng(7)
    cube = np.vstack([np.array(np.meshgrid([0, 1], [0, 2], [0, 3])).reshape(3, -1).T, rng.random((50, 3))])
    hull = convex_hull(cube)
    assert hull.dimension == 3 and np.isclose(hull.volume, 6.0, rtol=1e-12) and np.isclose(hull.area, 22.0)
    plane = np.column_stack([rng.random((40, 2)), np.zeros(40)]) @ np.array([[1, 0, 0], [0, 0.6, 0.8], [0, -0.8, 0.6]])
    plane = np.vstack([plane, [[0, 0, 0], [1, 0, 0], [0, 0.6, 0.8], [1, 0.6, 0.8]]])
    flat = convex_hull(plane)
    assert flat.dimension == 2 and flat.volume is None and np.isclose(flat.area, 1.0, rtol=1e-12)
    line = np.outer(np.linspace(0, 1, 9), [1.0, 2.0, 3.0])
    assert affine_dimension(line) == 1 and convex_hull(line).area is None


def test_points_files_round_trip(robot, tmp_path):
    workspace = sample_workspace(robot, 12)
    write_points(workspace, tmp_path / "p.csv")
    table = np.genfromtxt(tmp_path / "p.csv", delimiter=",", names=True)
    assert table.dtype.names[:5] == ("t1", "t2", "t3", "t4", "tipx")
    assert np.allclose(table["tipz"], workspace.positions[:, 0, 2], rtol=1e-15)
    write_points(workspace, tmp_path / "p.npz")
    stored = np.load(tmp_path / "p.npz")
    assert np.array_equal(stored["actuations"], workspace.actuations) and list(stored["effector_names"]) == ["tip"]
    with pytest.raises(OptionError, match="--points"):
        write_points(workspace, tmp_path / "p.txt")


def test_workspace_command(tmp_path, capsys):
    from vertebra.cli.main import main

    plot, points = tmp_path / "w.png", tmp_path / "w.csv"
    assert main(["workspace", "gallery:paper_3v_4t", "--samples", "32", "--json", "--plot", str(plot),
                 "--points", str(points)]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["vertebra_version"] and document["samples"] == document["converged"] == 32
    tip = document["effectors"]["tip"]
    assert tip["hull"]["dimension"] == 3 and tip["hull"]["volume"] > 0
    assert document["actuators"]["t1"] == {"lower": 0.0, "upper": 20.0}
    assert plot.stat().st_size > 0 and len(points.read_text().splitlines()) == 33


def test_workspace_command_checks_outputs_before_solving(tmp_path, capsys):
    from vertebra.cli.main import main

    for option, value in (("--plot", "w.vtu"), ("--points", "w.txt"), ("--plot", str(tmp_path / "no" / "w.png")),
                          ("--processes", "0")):
        assert main(["workspace", "gallery:paper_3v_4t", "--samples", "100000", option, value]) == 2
        assert option in capsys.readouterr().err      # refused at once, no 100,000 solves


def test_workspace_command_maps_the_tip_when_the_scene_has_no_effector(tmp_path, capsys):
    from vertebra.cli.main import main
    from vertebra.solver.scene import scene_toml

    data = gallery_data("paper_3v_4t")
    del data["effector"]
    path = tmp_path / "robot.toml"
    path.write_text(scene_toml(data))
    assert main(["workspace", str(path), "--samples", "8", "--json"]) == 0
    captured = capsys.readouterr()
    assert "tip" in json.loads(captured.out)["effectors"] and "no [[effector]]" in captured.err


def test_given_actuations_need_no_finite_bounds():
    data = gallery_data("paper_3v_4t")
    del data["cable"][2]["max_tension"]
    model = solver.build_model(solver.parse_scene(data))
    workspace = sample_workspace(model, actuations=[[1.0, 0.0, 30.0, 0.0], [0.0, 2.0, 0.0, 0.0]])
    assert workspace.converged.all() and workspace.settings["method"] == "given"
    assert workspace.summary()["actuators"]["t3"]["upper"] is None     # JSON null, not inf


def test_workspace_command_prepares_design_segments(tmp_path, capsys):
    # a scene of one designed rod and one tendon: --prepare designs the entry first, then maps
    from test_prepare import rod, scene_dict, write

    from vertebra.cli.main import main

    data = scene_dict(rod(0.004), catalogue=None)
    data["cable"] = [{"name": "pull", "radius": 0.003, "to": 1, "max_tension": 0.01}]
    path = write(tmp_path / "rods.toml", data)
    catalogue = tmp_path / "rods.h5"
    assert main(["workspace", str(path), "--samples", "6", "--json", "--prepare", "--catalogue", str(catalogue),
                 "--executor", "serial", "--no-accuracy"]) == 0
    captured = capsys.readouterr()
    assert catalogue.exists() and "1 designed" in captured.err
    document = json.loads(captured.out)
    assert document["converged"] == 6 and document["effectors"]["tip"]["upper"][0] > 0   # pushed towards +x


def test_strain_paths_are_the_path_tangents_in_strain_space(robot):
    from vertebra.solver.batch import path_tangents, predicted_strains, strain_paths

    actuations = sample_actuations(robot, 6, seed=4)
    batch = robot.solve_batch(actuations)
    paths, has = path_tangents(robot, batch.strains, actuations)
    xi_paths, xi_has = strain_paths(robot, batch.strains, actuations)
    assert has.all() and xi_has.all()
    change = np.random.default_rng(0).normal(0.0, 0.1, actuations.shape)
    # ξ + dξ/dλ Δλ is the Euler predictor q ⊕ K⁻¹B Δλ taken in strain space
    euler = predicted_strains(robot, batch.strains, paths, change)
    assert np.abs(batch.strains + (xi_paths @ change[:, None, :, None])[..., 0] - euler).max() <= 1e-14


def test_the_second_order_predictor_starts_nearer_than_the_euler_predictor():
    # parents spread over the box, children near them: the curvature term estimated from the
    # neighbours' path tangents brings the starts nearer the children's equilibria than the
    # Euler predictor ξ_p + ξ'_p Δλ alone (an error of order Δλ² against one of order Δλ³)
    from vertebra.solver.batch import strain_paths
    from vertebra.solver.workspace import predicted_starts

    model = solver.build_model(solver.load_scene("gallery:paper_5v_16t"))
    actuations = sample_actuations(model, 160, seed=1)
    parents, children = np.arange(0, 160, 4), np.setdiff1d(np.arange(160), np.arange(0, 160, 4))
    coordinates = response_coordinates(model, actuations)
    near = np.argmin(((coordinates[children, None] - coordinates[None, parents]) ** 2).sum(2), 1)
    solved = model.solve_batch(actuations[parents])
    truth = model.solve_batch(actuations[children])
    assert solved.converged.all() and truth.converged.all()
    paths, has = strain_paths(model, solved.strains, actuations[parents])
    change = actuations[children] - actuations[parents[near]]
    second = predicted_starts(solved.strains, paths, has, actuations[parents], coordinates[parents],
                              np.ptp(actuations, 0), near, change)
    euler = solved.strains[near] + (paths[near] @ change[:, None, :, None])[..., 0]
    error = {name: np.abs(start - truth.strains).reshape(len(children), -1).max(1)
             for name, start in (("euler", euler), ("second", second))}
    assert np.median(error["second"] / error["euler"]) < 0.5
    assert np.mean(error["second"] < error["euler"]) > 0.8


def test_parents_at_one_actuation_give_the_euler_predictor():
    # neighbours that coincide with the parent carry no curvature (no secant): the children get
    # the Euler step ξ_p + ξ'_p Δλ, and no singular least-squares system is solved
    from vertebra.solver.workspace import predicted_starts

    rng = np.random.default_rng(2)
    strains, paths = rng.normal(size=(5, 3, 6)), rng.normal(size=(5, 3, 6, 2))
    change = np.array([[0.1, -0.2], [0.3, 0.05]])
    starts = predicted_starts(strains, paths, np.ones(5, bool), np.ones((5, 2)), np.zeros((5, 2)), np.ones(2),
                              np.array([0, 3]), change)
    euler = strains[[0, 3]] + np.einsum("bnia,ba->bni", paths[[0, 3]], change)
    assert np.abs(starts - euler).max() <= 1e-15
