"""What a user trusts of the inverse: a tick lands where it predicts, the QP takes the least effort
among redundant actuations without trading accuracy, the CLI and the API start alike.

The robot is a typical 9-tendon robot: a nitinol backbone (r = 0.7 mm) of 24 vertebrae 15 mm
apart under gravity, three sections of three tendons each (ending at vertebrae 8, 16, 24; 120°
apart, turned 40° per section), tensions in [0, 15] N. Its tip follows a reachable circle 3 cm
from rest in tick mode from rest.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.solver.inverse import InverseController, InverseSettings, invert
from vertebra.solver.inverse.qp import solve_constraint_problem
from vertebra.solver.inverse.space import ConstraintProblem, ConstraintSpace
from vertebra.solver.scene import scene_toml

from robots import reachable_circle


def nine_tendon_scene(tension: float = 2.0) -> dict:
    """The module's robot; the first tendon of each section carries ``tension`` in the scene."""
    cables = [{"name": f"s{s + 1}-{j}", "radius": 0.008, "angle_deg": 120.0 * j + 40.0 * s, "from": 1, "to": last,
               "tension": tension if j == 0 else 0.0, "min_tension": 0.0, "max_tension": 15.0}
              for s, last in enumerate((8, 16, 24)) for j in range(3)]
    return {"name": "tendon_three_section", "gravity": {"vector": [0.0, 0.0, -9.81]},
            "segment": [{"type": "beam", "count": 24, "length": 0.015, "elements": 2, "youngs_modulus": 54e9,
                         "poisson_ratio": 0.33, "section": {"shape": "circle", "radius": 0.0007},
                         "density": 6450.0, "vertebra": {"mass": 0.0005}}],
            "cable": cables, "effector": [{"name": "tip", "vertebra": -1}]}


@pytest.fixture(scope="module")
def robot():
    scene = nine_tendon_scene()
    model = solver.build_model(solver.parse_scene(scene))
    return scene, model, reachable_circle(model, scene, 0.03, 40)


def _tick_circle(model, loop, **start):
    """Every tick of ``loop`` from rest: (prediction miss at the settled equilibrium, settled
    error, tensions) per tick."""
    controller = InverseController(model, InverseSettings(mode="tick"), **start)
    misses, errors, tensions = [], [], []
    for target in loop:
        step = controller.settled(controller.step(target))
        assert step.equilibrium
        misses.append(float(step.prediction_miss.max()))
        errors.append(float(step.errors.max()))
        tensions.append(step.actuation)
    return np.array(misses), np.array(errors), np.array(tensions)


def test_the_first_tick_from_rest_lands_where_it_predicts(robot):
    # The first target lies 30 mm from the tip at rest. The tick's prediction (the controller's
    # own state) and the equilibrium its tensions reach differed by 10 mm from zero tensions
    # and by 449 mm from the scene's tensions (the controller then started off equilibrium, at
    # the rest pose); a tick now starts from the equilibrium of its start and is cut back when
    # its prediction fails: within the tick tolerance (1 mm) from zero, and within the scene
    # start's own first move (the robot starts bent by the scene's tensions: 2 N per section).
    scene, model, loop = robot
    rest = model.effector_positions(model.solve(np.zeros(9)).state)
    assert np.linalg.norm(loop[0] - rest) == pytest.approx(0.03, rel=1e-6)
    misses, errors, _ = _tick_circle(model, loop)
    assert misses[0] <= 1e-3 and errors[0] <= 1e-3
    assert misses.max() <= 1e-3 and np.median(errors) <= 1e-4
    misses, _, _ = _tick_circle(model, loop[:3], actuation=model.default_actuation)
    assert misses.max() <= 1e-2


def test_ticks_do_not_co_contract(robot):
    # Started from the scene's tensions (as the command line did), every tendon used to climb to
    # the per-tick cap and stay co-contracted (the smallest of the nine at 2.1 N on average, 8.9
    # of 9 above 0.5 N); the least-effort QP releases the tendons it does not need.
    scene, model, loop = robot
    _, _, tensions = _tick_circle(model, loop, actuation=model.default_actuation)
    assert tensions[10:].min(axis=1).max() <= 1e-6
    assert (tensions[10:] > 0.5).sum(axis=1).mean() <= 3


def test_the_least_effort_qp_keeps_the_best_error_and_spends_less():
    # 16 efforts, 3 effector rows: a 13-dimensional set of efforts reaches the best error. A
    # tick's QP is damped towards the current efforts (4 N each, co-contracted), so alone it
    # stays co-contracted; the two-stage QP keeps the first stage's error (within its slack) and
    # minimises the actuation energy among the efforts reaching it. The penalty QP with a large
    # weight buys less effort with error.
    rng = np.random.default_rng(3)
    W_ea = rng.normal(size=(3, 16)) * 1e-3
    W_aa = W_ea.T @ W_ea + np.diag(rng.uniform(1e-6, 2e-6, 16))
    target = W_ea @ rng.uniform(0.0, 5.0, 16)
    lam0 = np.full(16, 4.0)
    problem = lambda eps: ConstraintProblem(
        ConstraintSpace(16, 3, lambda_lower=0.0, lambda_upper=20.0, regularisation=eps),
        W_ea, -target, W_aa, np.zeros(16), lam0, damping=1e-4)
    first = solve_constraint_problem(problem(1e-8))
    least = solve_constraint_problem(problem(1e-8), slack=1e-9)
    biased = solve_constraint_problem(problem(1e-2))
    energy = lambda sol: float(sol.actuation @ (np.abs(W_aa.diagonal()) * sol.actuation))
    assert least.effector_error <= first.effector_error + np.sqrt(3) * 1e-9      # (the slack on each row)
    assert energy(least) < 0.5 * energy(first)
    assert biased.effector_error > 100 * least.effector_error
    assert np.all(least.actuation >= 0.0) and np.all(least.actuation <= 20.0)


def test_command_line_and_library_start_alike(tmp_path, capsys, robot):
    # One start: no actuation (clipped into the bounds) at its equilibrium, whatever tensions
    # the scene holds; --max-iterations sets the converged inverse's limit.
    scene, model, loop = robot
    data = dict(scene, effector=[{"name": "tip", "vertebra": -1, "target": [float(v) for v in loop[5, 0]]}])
    path = tmp_path / "nine.toml"
    path.write_text(scene_toml(data))
    model = solver.build_model(solver.parse_scene(data))
    api = invert(model, max_iterations=12)
    assert main(["invert", str(path), "--json", "--max-iterations", "12"]) == (0 if api.reached else 1)
    document = json.loads(capsys.readouterr().out)
    step = document["steps"][-1]
    assert step["iterations"] == api.iterations
    np.testing.assert_allclose([step["cables"][name]["tension"] for name in model.actuator_names], api.actuation,
                               rtol=0, atol=1e-9)
    assert api.reached and step["effectors"]["tip"]["error"] <= 1e-6
    assert step["effectors"]["tip"]["predicted_error"] >= 0.0 and step["effectors"]["tip"]["prediction_miss"] >= 0.0
    assert main(["invert", str(path), "--json", "--max-iterations", "1"]) == 1
    assert json.loads(capsys.readouterr().out)["steps"][-1]["iterations"] == 1


def test_a_tick_reports_its_predicted_and_actual_errors(robot):
    scene, model, loop = robot
    controller = InverseController(model, InverseSettings(mode="tick"))
    step = controller.step(loop[0])
    np.testing.assert_allclose(step.predicted_errors, step.errors, rtol=0, atol=0)
    assert np.all(step.prediction_miss == 0.0)
    settled = controller.settled(step)
    np.testing.assert_allclose(settled.predicted_errors, step.errors, rtol=0, atol=0)
    np.testing.assert_allclose(settled.prediction_miss,
                               np.linalg.norm(settled.positions - step.positions, axis=1), rtol=1e-12)
