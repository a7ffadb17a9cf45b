"""Tendon friction at the holes (solver/friction.py, docs/friction.md): the capstan law, sticking,
the hysteresis of a pull and a release, the work it dissipates, and μ = 0 as today's solver."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver import friction

E, NU, R_ROD, LINK, N = 54e9, 0.3, 0.0007, 0.02, 10
EI = E * math.pi * R_ROD ** 4 / 4


def rod():
    return {"type": "beam", "count": N, "length": LINK, "elements": 1, "youngs_modulus": E,
            "poisson_ratio": NU, "section": {"shape": "circle", "radius": R_ROD}}


def build(cable, loads=()):
    return solver.build_model(solver.parse_scene({"segment": [rod()], "cable": [cable], "load": list(loads),
                                                   "effector": [{"name": "tip", "vertebra": -1}]}))


def pulled(mu, **extra):
    return {"name": "t", "radius": 0.01, "to": N, "tension": 0.0, "friction": mu, **extra}


def servo(mu, pretension=0.0):
    return {"name": "t", "radius": 0.01, "to": N, "stroke": 0.0, "stiffness": 2000.0, "pretension": pretension,
            "friction": mu}


def route_of(model):
    return friction.routes(model.trunk.cables).pieces[0]


def test_capstan_ratio_on_a_constant_curvature_bend_is_exact():
    # a pure end moment bends the rod into a constant-curvature arc (every link turns by the same
    # φ = M ℓ/EI); a cable pulled over it slides at every hole: distal/proximal = e^(−μΘ), Θ = 9φ
    mu, moment = 0.25, 0.02
    model = build(pulled(mu), loads=[{"vertebra": N, "moment": [0.0, moment, 0.0]}])
    bent = solver.build_model(
        solver.parse_scene({"segment": [rod()], "load": [{"vertebra": N, "moment": [0.0, moment, 0.0]}]})).solve()
    turns = np.linalg.norm(bent.state.strains.xi[:, 3:], axis=1)
    phi = moment * LINK / EI
    assert np.allclose(turns, phi, rtol=1e-9, atol=0)
    lengths, angles = friction.geometry(model.trunk, bent.state)
    route = route_of(model)
    assert np.allclose(angles[route[1:]], phi, rtol=1e-9)
    pull = friction.transmission(model.trunk, friction.FrictionState.rest(model.trunk), np.array([4.0]),
                                 lengths, angles)
    tension = pull.tension[route]
    assert (pull.slip[route[1:]] == 1).all()
    assert tension[-1] / tension[0] == pytest.approx(math.exp(-mu * (N - 1) * phi), rel=1e-10, abs=0)
    assert np.allclose(tension[1:] / tension[:-1], math.exp(-mu * phi), rtol=1e-12, atol=0)


@pytest.mark.parametrize("mu", [0.1, 0.3])
def test_a_pull_from_rest_slides_everywhere_and_meets_the_capstan_law_at_its_own_shape(mu):
    model = build(pulled(mu))
    result = model.solve({"t": 3.0})
    assert result.converged and result.friction is not None
    route = route_of(model)
    _, angles = friction.geometry(model.trunk, result.state)
    tension = result.friction.tension[route]
    assert (result.friction.slip[route[1:]] == 1).all()
    assert tension[0] == 3.0
    assert tension[-1] / tension[0] == pytest.approx(math.exp(-mu * angles[route].sum()), rel=1e-10, abs=0)
    frictionless = build(pulled(0.0)).solve({"t": 3.0})
    tip, free_tip = result.state.positions[-1], frictionless.state.positions[-1]
    assert tip[0] < free_tip[0]                 # less tension reaches the distal vertebrae: less bending


@pytest.mark.parametrize("cable, values", [(pulled, [1.0, 3.0, 2.0, 0.5]), (servo, [0.001, 0.002, 0.0005, -0.001])])
def test_zero_friction_is_todays_solver(cable, values):
    today = build({k: v for k, v in cable(0.0).items() if k != "friction"})
    model = build(cable(0.0))
    # a scene's friction = 0 takes today's path; a sequence runs the friction rounds with every factor 1
    single = model.solve({"t": values[0]})
    assert np.array_equal(single.state.positions, today.solve({"t": values[0]}).state.positions)
    sequence = model.solve_sequence([{"t": v} for v in values])
    state = None
    for value, result in zip(values, sequence):
        reference = today.solve({"t": value}, state)
        state = reference.state
        assert np.abs(result.state.positions - reference.state.positions).max() <= 1e-12
        assert np.abs(result.state.quaternions - reference.state.quaternions).max() <= 1e-12
        route = route_of(model)
        tensions = result.friction.tension[route]
        assert np.abs(tensions - today.cable_tensions(reference.state, {"t": value})[0]).max() <= 1e-12 * max(1.0, tensions.max())


def loop(model, top, steps):
    """Tip x over a pull 0 → top and a release back to 0 in ``steps`` increments each."""
    up = np.linspace(0.0, top, steps + 1)
    commands = list(up[1:]) + list(up[::-1][1:])
    results = model.solve_sequence([{"t": v} for v in commands])
    tip = np.array([r.state.positions[-1, 0] for r in results])
    pull = np.r_[0.0, tip[:steps]]
    release = np.r_[tip[steps:][::-1], tip[steps - 1]]       # at up[0..steps]
    release[-1] = pull[-1]
    return up, pull, release, results


@pytest.mark.parametrize("cable, top", [(pulled, 3.0), (servo, 0.002)])
def test_the_pull_release_loop_widens_with_friction_and_closes_without(cable, top):
    widths = []
    for mu in (0.0, 0.1, 0.2):
        _, pull, release, _ = loop(build(cable(mu)), top, 6)
        widths.append(np.abs(release - pull).max())
        if mu and cable is pulled:
            assert (release[1:-1] > pull[1:-1]).all()      # on the way back the stuck spans hold the bend
    assert widths[0] <= 1e-9
    assert widths[0] < 1e-3 * widths[1] and widths[1] < widths[2]


def test_a_reversal_moves_the_distal_tension_only_after_the_base_tension_fell_by_e_to_2_mu_theta():
    # from the peak of a pull the distal span keeps its tension while the slip front runs from the
    # base: it moves once T₀ < T_peak e^(−μ(Θ_peak + Θ_now)) — e^(−2μΘ) on a bend that keeps its shape
    mu, peak = 0.2, 3.0
    model = build(pulled(mu))
    top = model.solve({"t": peak})
    route = route_of(model)
    distal = top.friction.tension[route[-1]]
    theta_peak = friction.geometry(model.trunk, top.state)[1][route].sum()
    guess = peak * math.exp(-2.0 * mu * theta_peak)
    thresholds = []
    for factor in (1.02, 0.98):
        result = model.solve({"t": guess * factor}, history=top.friction)
        theta = friction.geometry(model.trunk, result.state)[1][route].sum()
        threshold = peak * math.exp(-mu * (theta_peak + theta))
        thresholds.append(threshold)
        stuck = result.friction.slip[route[1:]] == 0
        if guess * factor > threshold:
            assert result.friction.tension[route[-1]] == distal and stuck[-1]
        else:
            assert result.friction.tension[route[-1]] < distal and not stuck.any()
            assert (result.friction.slip[route[1:]] == -1).all()
    assert guess * 1.02 > thresholds[0] and guess * 0.98 < thresholds[1]


def dissipation(model, steps):
    """Work of the servo's base tension ∮ T₀ ds and the friction work Σ (T_in − T_out) · slide over
    a closed stroke loop 0 → 2 mm → −1 mm (slack: the trunk back at rest, every span unloaded)."""
    up = np.linspace(0.0, 0.002, steps + 1)
    down = np.linspace(0.002, -0.001, int(1.5 * steps) + 1)
    commands = np.r_[up[1:], down[1:]]
    results = model.solve_sequence([{"t": v} for v in commands])
    route = route_of(model)
    states = [friction.FrictionState.rest(model.trunk)] + [r.friction for r in results]
    stroke = np.r_[0.0, commands]
    work = drop_work = 0.0
    for before, after, ds in zip(states[:-1], states[1:], np.diff(stroke)):
        work += 0.5 * (before.tension[route[0]] + after.tension[route[0]]) * ds
        slide = np.cumsum((before.material[route] - after.material[route])[::-1])[::-1][1:]   # through hole k, towards the base
        drop = 0.5 * ((before.tension[route[:-1]] - before.tension[route[1:]])
                      + (after.tension[route[:-1]] - after.tension[route[1:]]))
        drop_work += float(drop @ slide)
    assert not results[-1].friction.tension.any()
    return work, drop_work


def test_the_work_of_the_base_tension_over_a_closed_loop_is_the_friction_work():
    model = build(servo(0.2))
    coarse = dissipation(model, 8)
    fine = dissipation(model, 16)
    for work, dissipated in (coarse, fine):
        assert work > 0.0 and dissipated > 0.0
    error = [abs(w - d) / w for w, d in (coarse, fine)]
    assert max(error) < 1e-4            # measured: 6.3e-6 (8 steps per pull), 3.3e-6 (16)
    frictionless = dissipation(build(servo(0.0)), 8)
    assert abs(frictionless[0]) < 1e-3 * coarse[0] and abs(frictionless[1]) <= 1e-12


def scene_file(tmp_path, cable):
    from vertebra.solver.scene import scene_toml
    path = tmp_path / "section.toml"
    path.write_text(scene_toml({"name": "section", "segment": [rod()], "cable": [cable],
                                "effector": [{"name": "tip", "vertebra": -1}]}))
    return path


def test_json_carries_route_span_tensions_and_stick_and_the_cli_runs_sequences(tmp_path, capsys):
    import json
    from vertebra.cli.main import main
    path = scene_file(tmp_path, pulled(0.2))
    assert main(["simulate", str(path), "--json", "--sequence", "t=1,3,2.5"]) == 0
    steps = json.loads(capsys.readouterr().out)["sequence"]
    assert len(steps) == 3
    model = build(pulled(0.2))
    expected = model.solve_sequence([{"t": v} for v in (1.0, 3.0, 2.5)])
    for document, result in zip(steps, expected):
        cable = document["cables"]["t"]
        route = np.array(cable["route"])
        assert route.shape == (N + 1, 3) and len(cable["tensions"]) == N and len(cable["stick"]) == N - 1
        assert np.allclose(route[0], [0.01, 0.0, 0.0])                   # the base hole first
        assert np.allclose(cable["tensions"], result.friction.tension[route_of(model)], rtol=1e-12, atol=0)
        assert cable["tension"] == cable["tensions"][0]
    assert not any(steps[1]["cables"]["t"]["stick"])                      # a pull slides everywhere
    assert any(steps[2]["cables"]["t"]["stick"]) and not all(steps[2]["cables"]["t"]["stick"])
    # frictionless: one tension along the cable, nothing sticks
    plain = scene_file(tmp_path, {k: v for k, v in pulled(0.0).items() if k != "friction"})
    assert main(["simulate", str(plain), "--json"]) == 0
    cable = json.loads(capsys.readouterr().out)["cables"]["t"]
    assert cable["tensions"] == [0.0] * N and cable["stick"] == [False] * (N - 1)
    # text output and bad sequences
    assert main(["simulate", str(path), "--sequence", "t=1,0"]) == 0
    assert "step 1: t=0: converged" in capsys.readouterr().out
    for bad in ("x=1", "t=1,a", "t"):
        assert main(["simulate", str(path), "--sequence", bad]) == 2
        assert "--sequence" in capsys.readouterr().err


def test_friction_must_not_be_negative(tmp_path, capsys):
    from vertebra.cli.main import main
    assert main(["simulate", str(scene_file(tmp_path, pulled(-0.1)))]) == 2
    err = capsys.readouterr().err
    assert "friction" in err and "Traceback" not in err
    with pytest.raises(Exception, match="friction"):
        build(pulled(0.0)).with_parameters(friction={"t": -1.0})


@pytest.mark.slow
def test_the_inverse_sees_the_frictional_transmission_and_its_answers_reach_the_targets():
    # 20 random reachable targets of the 16-tendon gallery robot with μ = 0.2: the QP's actuator
    # forces are the spans' forces per unit base tension of a pull (capstan factors), and the
    # forward solve from rest of the inverse's answer puts both effectors on their targets
    import dataclasses
    from vertebra.solver.gallery import load
    from vertebra.solver.inverse.controller import InverseController, InverseSettings
    scene = load("paper_5v_16t")
    scene = dataclasses.replace(scene, cables=tuple(dataclasses.replace(c, friction=0.2) for c in scene.cables))
    model = solver.build_model(scene)
    rng = np.random.default_rng(23)
    worst = 0.0
    for _ in range(20):
        actuation = rng.uniform(0.0, 3.0, 16) * (rng.random(16) < 0.4)
        targets = model.effector_positions(model.solve(actuation).state)
        step = InverseController(model, InverseSettings(mode="converged")).step(targets)
        assert step.reached and step.equilibrium
        check = model.solve(step.actuation)
        worst = max(worst, float(np.linalg.norm(model.effector_positions(check.state) - targets, axis=1).max()))
    assert worst <= 1e-6
    # the transmission itself: a pulled cable's actuator force is Σ g_j ∂L_j/∂q with g the capstan factors
    state = model.solve(actuation).state
    lin = model.linearise(state, actuation)
    plain = solver.build_model(load("paper_5v_16t")).linearise(state, actuation)
    c = int(np.argmax(actuation))
    assert not np.allclose(lin.actuator_forces[:, c], plain.actuator_forces[:, c])
    lengths, angles = friction.geometry(model.trunk, state)
    route = friction.routes(model.trunk.cables).pieces[c]
    ratio = np.exp(-0.2 * np.cumsum(angles[route]))
    pieces = model.trunk.cables.pieces(state.positions, friction.qmatrix(state.quaternions))
    expected = np.zeros((model.n_frames, 6))
    for piece, g in zip(route, ratio):
        a, b = model.trunk.cables.piece_a[piece], model.trunk.cables.piece_b[piece]
        expected[a] += g * pieces.unit[piece, :6]
        expected[b] += g * pieces.unit[piece, 6:]
    assert np.allclose(lin.actuator_forces[:, c], -expected[1:].reshape(-1), rtol=1e-12, atol=1e-15)


@pytest.mark.slow
def test_calibration_fits_friction_from_a_time_ordered_pull_release_sequence(tmp_path):
    # synthetic data: a small three-tendon robot pulled and released in turn, predicted as one
    # sequence with μ = 0.15; `friction` (one μ shared by the driven tendons) is fitted back
    import sys
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from test_calibration import MAPPING, SCENE
    from vertebra.solver.calibration import Samples, calibrate, parse_mapping, parse_parameters
    from vertebra.solver.calibration.backend import RuntimePredictor
    from vertebra.solver.calibration.sequence import SequencePredictor
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    scene, mapping = solver.load_scene(path), parse_mapping(MAPPING, "map.toml")
    up = np.linspace(0.0, 3.0, 5)
    loop = np.r_[up, up[::-1][1:]]
    commands = 1e-3 * np.array([(u, -1.0, -1.0) for u in loop] + [(-1.0, u, 0.5 * u - 1.0) for u in loop])
    empty = Samples(commands, np.zeros((len(commands), 1, 3)), ("a",) * len(loop) + ("b",) * len(loop), "synthetic")
    ps = parse_parameters(["friction"], scene, mapping, solver.build_model(scene))
    assert ps.names == ("friction",) and len(ps.elements[0]) == 3
    predictor = SequencePredictor(scene, mapping)
    frictionless = predictor.predict(ps.values([0.0]), empty).markers
    assert np.array_equal(frictionless, RuntimePredictor(scene, mapping).predict(ps.values([0.0]), empty).markers)
    truth = predictor.predict(ps.values([0.15]), empty).markers
    gap = np.linalg.norm(truth[3, 0] - truth[5, 0])             # the same command on the pull and the release
    assert gap > 1e-5 and np.linalg.norm(frictionless[3, 0] - frictionless[5, 0]) < 1e-9
    samples = Samples(commands, truth, empty.patterns, "synthetic")
    derivative = predictor.predict(ps.values([0.05]), samples, [e for e in ps.elements[0]]).derivatives
    assert np.abs(derivative).max() > 0.0
    cal = calibrate(scene, mapping, samples, fit=["friction"])    # from μ = 0.05 (the scene has none)
    before = np.sqrt(np.mean(np.sum((frictionless - truth) ** 2, -1)))
    assert cal.x[0] == pytest.approx(0.15, abs=1e-3)                # the optimiser's tolerances (1e-6)
    assert cal.train["rmse_m"] < 1e-2 * before


def test_paraview_carries_span_tensions_and_stick(tmp_path):
    from vertebra.solver.paraview import CABLE, trunk_polydata, write_vtp
    model = build(pulled(0.2))
    pull, release = model.solve_sequence([{"t": 3.0}, {"t": 2.5}])
    data = trunk_polydata(model, release.state, release.actuation, friction=release.friction)
    cable = data.cell_data["part"] == CABLE
    assert np.array_equal(data.cell_data["tension"][cable], release.friction.tension[route_of(model)])
    stick = data.point_data["stick"][data.point_data["cable"] == 0]
    assert stick[0] == 0 and stick[-1] == 0
    assert np.array_equal(stick[1:-1].astype(bool), release.friction.slip[route_of(model)[1:]] == 0)
    assert stick[1:-1].any() and not stick[1:-1].all()
    write_vtp(str(tmp_path / "release.vtp"), data)
    assert "stick" not in trunk_polydata(model, pull.state, pull.actuation).point_data


def test_sensitivities_to_friction_are_differences_of_the_whole_sequence():
    model = build(pulled(0.2))
    commands = [{"t": 3.0}, {"t": 2.0}]
    derivative = friction.sensitivities(model, commands)
    assert derivative["names"] == ["friction:t"]
    assert model.parameters.friction[0] == 0.2                      # restored
    tip_x = derivative["effector_positions"][:, 0, 0]
    assert tip_x[0] < 0.0                                           # more friction: less of the pull reaches the tip
    coarse = friction.sensitivities(model, commands, step=1e-3)["effector_positions"][:, 0, 0]
    assert np.allclose(tip_x, coarse, rtol=1e-3)
    route = route_of(model)
    top = model.solve_sequence(commands)[0]
    theta = friction.geometry(model.trunk, top.state)[1][route].sum()
    # a pull's distal tension T₀ e^(−μΘ): ∂/∂μ = −T₀ e^(−μΘ) (Θ + μ ∂Θ/∂μ), Θ barely moving
    assert derivative["span_tensions"][0, route[-1], 0] == pytest.approx(-3.0 * math.exp(-0.2 * theta) * theta, rel=0.05)


# ---------------------------------------------------------------- the inverse's tick and steps with friction
def outside(mu, servo=False, **cable):
    """The 16-tendon robot outside the gallery of benchmarks/bench_tick.py, every cable with μ
    (``servo``: stroke-driven tendons, k = 2000 N/m, pretension 1 N, strokes −1 … 3 mm)."""
    drive = ({"stroke": 0.0, "stiffness": 2000.0, "pretension": 1.0, "min_stroke": -0.001, "max_stroke": 0.003}
             if servo else {"tension": 0.0, "min_tension": 0.0, "max_tension": 12.0})
    return solver.build_model(solver.parse_scene({
        "gravity": {"vector": [0.0, -9.81, 0.0]},
        "segment": [{"type": "beam", "count": 6, "length": 0.022, "elements": 3, "youngs_modulus": 40e9,
                     "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 0.0008}, "density": 6450.0,
                     "vertebra": {"mass": 0.003}}],
        "cable": [{"name": f"t{4 * g + j + 1}", "radius": 0.007 + 0.002 * g, "angle_deg": 90.0 * j + 22.5 * g,
                   "from": 1, "to": end, **drive, "friction": mu, **cable}
                  for g, end in enumerate((2, 3, 5, 6)) for j in range(4)],
        "effector": [{"name": "mid", "vertebra": 3}, {"name": "tip", "vertebra": -1}]}))


def circle_ticks(model, ticks, value=0.3):
    """A tick controller from the equilibrium under ``value`` on every tendon (with friction: a pull from
    rest), the targets on a 1 mm circle (100 ticks a turn); the plant solves each tick's command from
    its own last equilibrium and friction state. Yields (controller, previous actuation, step, plant)."""
    from vertebra.solver.inverse.controller import InverseController, InverseSettings
    lam = np.full(model.n_cables, value)
    start = model.solve(lam)
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=start.state,
                                   history=start.friction)
    centre = model.effector_positions(start.state)
    plant = start
    for k in range(ticks):
        target = centre + 1e-3 * np.array([math.cos(0.02 * math.pi * k), math.sin(0.02 * math.pi * k), 0.0])
        previous, history = controller.actuation, controller.history
        step = controller.step(target)
        assert step.history is history and step.friction is controller.history
        plant = model.solve(step.actuation, initial=plant.state, history=plant.friction)
        yield controller, previous, step, plant


def test_the_tick_carries_the_friction_state_and_the_frictional_robot_follows_its_commands():
    # μ = 0.2, per-tick changes of 0.2 N: every tick is applied, within the bounds and the per-tick
    # change, its friction state is the plant's (the tick's command applied to the state the last
    # one left, solved to equilibrium, lands where the plant does), and the plant — the robot
    # under the commands in order, with its hysteresis — follows the circle (without the friction
    # state the ticks were not applied: the robot stayed 1 mm from the targets)
    model = outside(0.2, max_tension_change=0.2)
    lower, upper = model.actuator_bounds
    errors, stuck = [], 0
    for controller, previous, step, plant in circle_ticks(model, 40):
        assert step.status == "tick" and step.fraction == 1.0
        assert np.all(step.actuation >= lower) and np.all(step.actuation <= upper)
        assert np.all(np.abs(step.actuation - previous) <= 0.2 * (1 + 1e-12))
        settled = controller.settled(step)
        assert settled.equilibrium
        assert np.abs(settled.positions - model.effector_positions(plant.state)).max() <= 1e-6
        assert np.abs(settled.friction.tension - plant.friction.tension).max() <= 1e-3
        errors.append(float(np.linalg.norm(model.effector_positions(plant.state) - step.targets, axis=1).max()))
        stuck += sum(len(holes) for holes in step.stuck(model).values())
    assert max(errors[10:]) <= 0.4e-3
    assert stuck > 0                # the circle reverses cables: their holes stick


def test_the_tick_without_friction_runs_no_friction_code(monkeypatch):
    # μ = 0: the tick is today's frictionless one — not a line of solver/friction.py runs
    model = outside(0.0)
    def refuse(*args, **kwargs):
        raise AssertionError("friction code ran without friction")
    for name in ("transmission", "linearise", "geometry", "piecewise", "solve", "_ratios", "_tendon_spans"):
        monkeypatch.setattr(friction, name, refuse)
    for _, _, step, _ in circle_ticks(model, 5):
        assert step.status == "tick" and step.history is None and step.friction is None and step.stuck(model) == {}


def test_the_tick_with_friction_on_stroke_driven_tendons():
    # tendons driven by servo strokes (k = 2000 N/m, pretension 1 N), μ = 0.15: the tick carries the
    # tendons' span materials and statuses (a tick's runs of sliding spans make its tangent); the
    # ticks are applied, the friction state is the plant's and the plant follows
    model = outside(0.15, servo=True)
    errors, applied = [], 0
    for controller, previous, step, plant in circle_ticks(model, 30, 0.0003):
        applied += step.fraction > 0.0
        # (a tick commits the friction state of its predicted state, not of an equilibrium: a
        # tendon's stuck spans keep the materials of the prediction — measured within 5.1e-6 m of the plant's,
        # its effectors within 2.3e-5 m; the ticks' own misses ≤ 2.3e-4 m)
        settled = controller.settled(step)
        assert np.abs(settled.positions - model.effector_positions(plant.state)).max() <= 3e-5
        assert np.nanmax(np.abs(settled.friction.material - plant.friction.material)) <= 1e-5
        errors.append(float(np.linalg.norm(model.effector_positions(plant.state) - step.targets, axis=1).max()))
    assert applied >= 27
    assert max(errors[10:]) <= 0.4e-3


def test_the_converged_inverse_releases_from_a_pulled_state_and_reports_where_the_cable_sticks():
    # the 10-link section pulled to 3 N (μ = 0.2); the target is where a release to 2.8 N leaves the
    # tip. The inverse started from the pulled state (its friction state) finds that release: the
    # command applied to the pulled state reaches the target, the cable sticks at the slip front
    # (the holes before it slide out, those beyond still hold the pull's tensions), and the
    # report (invert --json) carries each cable's span tensions, its stick flags and the stuck holes
    from vertebra.solver.inverse.controller import InverseController, InverseSettings
    from vertebra.solver.report import inverse_report
    model = build(pulled(0.2))
    pull = model.solve([3.0])
    release = model.solve([2.8], history=pull.friction)
    targets = model.effector_positions(release.state)
    from_rest = model.effector_positions(model.solve([2.8]).state)
    assert np.linalg.norm(from_rest - targets) > 1e-3              # the hysteresis: a pull to 2.8 N lands elsewhere
    controller = InverseController(model, InverseSettings(mode="converged"), actuation=[3.0], state=pull.state,
                                   history=pull.friction)
    step = controller.step(targets)
    assert step.reached and step.equilibrium
    assert step.history.actuation[0] == 3.0 and np.allclose(step.history.tension, pull.friction.tension, rtol=1e-9)
    assert step.actuation[0] == pytest.approx(2.8, abs=1e-4)
    check = model.solve(step.actuation, history=pull.friction)
    assert np.linalg.norm(model.effector_positions(check.state) - targets) <= 1e-6
    stuck = step.stuck(model)["t"]
    assert stuck and stuck == (np.flatnonzero(release.friction.slip[route_of(model)[1:]] == 0) + 1).tolist()
    document = inverse_report(model, [step], [0.0], scene="rod", mode="converged", backend="x", tolerance=1e-6)
    row = document["steps"][0]
    assert row["stuck"] == {"t": stuck}
    cable = row["cables"]["t"]
    assert len(cable["tensions"]) == N and len(cable["stick"]) == N - 1
    assert [k + 1 for k, flag in enumerate(cable["stick"]) if flag] == stuck
    assert cable["tensions"][0] == pytest.approx(2.8, abs=1e-4)
    assert np.allclose(cable["tensions"], release.friction.tension[route_of(model)], atol=1e-4)
    # frictionless: neither key
    plain = build({"name": "t", "radius": 0.01, "to": N, "tension": 0.0})
    row = inverse_report(plain, [InverseController(plain).step(targets)], [0.0], scene="rod", mode="converged",
                         backend="x", tolerance=1e-6)["steps"][0]
    assert "stuck" not in row and "stick" not in row["cables"]["t"]


def test_friction_with_disc_contact_pull_release_converges_complementary_with_hysteresis():
    # a 4-vertebra trunk with discs (tests/test_contact.py's disc trunk) whose cable has μ = 0.2:
    # pulled until every pair of discs presses rim to face, then released. Every command converges,
    # every contact is complementary, the discs press at the top, and the loop is open at 4 N
    # (contact-free there) while it closes without friction
    SPACING, DISC, THICK, HOLE = 0.01, 0.015, 0.002, 0.008
    def trunk(mu):
        disc = {"disc_radius": DISC, "disc_thickness": THICK}
        return solver.build_model(solver.parse_scene({
            "segment": [{"type": "beam", "count": 4, "length": SPACING, "youngs_modulus": 1e9,
                         "section": {"area": 1e-3, "Ixx": 1e-12, "Iyy": 1e-12, "J": 2e-12}, "vertebra": disc}],
            "base": disc,
            "cable": [{"name": "c", "radius": HOLE, "to": 4, "tension": 0.0, "friction": mu}],
            "effector": [{"name": "tip", "vertebra": -1}]}))
    commands = [2.0, 4.0, 8.0, 15.0, 30.0, 15.0, 8.0, 4.0, 2.0, 0.0]
    widths = {}
    for mu in (0.0, 0.2):
        model = trunk(mu)
        results = model.solve_sequence([[v] for v in commands])
        for value, result in zip(commands, results):
            assert result.converged and result.contacts
            for c in result.contacts:
                assert c.force >= 0.0 and c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12, c
            if value == 30.0:
                assert sum(c.force > 0.0 for c in result.contacts) == 4
                spans = result.friction.tension[route_of(model)]
                assert np.all(np.diff(spans) < 0.0) if mu else np.all(spans == 30.0)    # capstan along the pull
        tips = [model.effector_positions(r.state)[0] for r in results]
        widths[mu] = float(np.linalg.norm(tips[commands.index(4.0)] - tips[len(commands) - 1 - commands[::-1].index(4.0)]))
    assert widths[0.0] <= 1e-9 and widths[0.2] >= 1e-3


def test_exact_friction_sensitivities_of_an_equilibrium_match_differences_where_the_statuses_hold():
    # the implicit-function derivatives by μ (the capstan factors' change with the shape included)
    # against differences of solves from the same history (tight tolerance, started at the
    # equilibrium): a pull from rest, a pull on from 3 N and a release that slides every hole —
    # central differences (statuses the same on both sides); a release that leaves the cable stuck
    # at its slip front with the distal holes at incipient slip — the one-sided difference on the
    # side where they keep sliding (more friction sticks them: there the derivative has a kink)
    model = build(pulled(0.2))
    rest = friction.FrictionState.rest(model.trunk)
    pull = model.solve([3.0])

    def solved(command, history, mu, initial=None):
        model.set_parameters(friction=np.array([mu]))
        result = model.solve([command], history=history, initial=initial, tolerance=1e-14)
        return result, model.effector_positions(result.state).reshape(-1)

    for command, history in ((3.0, rest), (3.5, pull.friction), (2.4, pull.friction), (2.6, pull.friction)):
        result, p0 = solved(command, history, 0.2)
        exact = friction.equilibrium_sensitivities(model, result, history)
        assert exact["names"] == ["friction:t"]
        h = 1e-5
        (above, p_above), (below, p_below) = (solved(command, history, 0.2 + h, result.state),
                                              solved(command, history, 0.2 - h, result.state))
        if command == 2.6:
            assert not np.array_equal(above.friction.slip, result.friction.slip)
            assert np.array_equal(below.friction.slip, result.friction.slip)
            difference = (p0 - p_below) / h
            tensions = (result.friction.tension - below.friction.tension) / h
            tolerance = 1e-4                   # one-sided: O(h) against the central differences' O(h²)
        else:
            assert np.array_equal(above.friction.slip, result.friction.slip)
            assert np.array_equal(below.friction.slip, result.friction.slip)
            difference = (p_above - p_below) / (2 * h)
            tensions = (above.friction.tension - below.friction.tension) / (2 * h)
            tolerance = 1e-6
        assert np.abs(exact["effector_positions"][:, 0] - difference).max() <= tolerance * np.abs(difference).max()
        assert np.abs(exact["span_tensions"][:, 0] - tensions).max() <= tolerance * np.abs(tensions).max()


def test_exact_friction_sensitivities_of_stroke_driven_tendons_match_central_differences():
    # a tendon's runs keep their material: T_j = g_j τ, τ = (Σ L − M)/Σ c g, the capstan factors
    # g changing with μ and the shape. Against central differences of solves from the same
    # history (statuses the same on both sides): a pull from rest, a pull on, a release that pays
    # out at every hole, releases whose holes slide both ways (the solve held some at incipient
    # slip: the sensitivities hold them too) — measured 5e-10 … 5e-8
    model = build(servo(0.2, pretension=0.5))
    rest = friction.FrictionState.rest(model.trunk)
    pull = model.solve([0.002])

    def solved(command, history, mu, initial=None):
        model.set_parameters(friction=np.array([mu]))
        result = model.solve([command], history=history, initial=initial, tolerance=1e-14)
        return result, model.effector_positions(result.state).reshape(-1)

    for command, history in ((0.002, rest), (0.0025, pull.friction), (0.0017, pull.friction),
                             (0.00195, pull.friction), (0.00198, pull.friction)):
        result, p0 = solved(command, history, 0.2)
        exact = friction.equilibrium_sensitivities(model, result, history)
        h = 1e-4
        (above, p_above), (below, p_below) = (solved(command, history, 0.2 + h, result.state),
                                              solved(command, history, 0.2 - h, result.state))
        assert np.array_equal(above.friction.slip, result.friction.slip)
        assert np.array_equal(below.friction.slip, result.friction.slip)
        difference = (p_above - p_below) / (2 * h)
        tensions = (above.friction.tension - below.friction.tension) / (2 * h)
        assert np.abs(exact["effector_positions"][:, 0] - difference).max() <= 1e-6 * np.abs(difference).max()
        assert np.abs(exact["span_tensions"][:, 0] - tensions).max() <= 1e-6 * np.abs(tensions).max()
    assert np.any(friction.equilibrium_sensitivities(model, solved(0.00195, pull.friction, 0.2)[0],
                                                     pull.friction)["span_tensions"] != 0.0)


def test_sequence_sensitivities_carry_the_history_forward_and_match_differences_of_the_sequence():
    # forward mode along a pull/release sequence: each equilibrium's derivative with those of the
    # friction state the one before left (stuck spans' committed tensions, tendons' materials);
    # against central differences of the whole sequence (tight tolerance, statuses the same on
    # both sides): measured ≤ 1e-8 (tension-driven), ≤ 2e-7 (stroke-driven)
    for cable, commands in ((pulled(0.2), [3.0, 3.5, 2.4, 2.6, 3.2, 1.0]),
                            (servo(0.2, pretension=0.5), [0.002, 0.0025, 0.0017, 0.00195, 0.0021, 0.0005])):
        model = build(cable)

        def run(mu):
            model.set_parameters(friction=np.array([mu]))
            results, history = [], friction.FrictionState.rest(model.trunk)
            for command in commands:
                results.append(model.solve([command], history=history, tolerance=1e-14))
                history = results[-1].friction
            return results

        results = run(0.2)
        exact = friction.sequence_sensitivities(model, results)
        h = 1e-4
        above, below = run(0.2 + h), run(0.2 - h)
        for i, result in enumerate(results):
            assert np.array_equal(above[i].friction.slip, result.friction.slip)
            assert np.array_equal(below[i].friction.slip, result.friction.slip)
            difference = (model.effector_positions(above[i].state) - model.effector_positions(below[i].state)) / (2 * h)
            tensions = (above[i].friction.tension - below[i].friction.tension) / (2 * h)
            assert np.abs(exact["effector_positions"][i][:, 0] - difference.reshape(-1)).max() \
                <= 1e-6 * np.abs(difference).max()
            assert np.abs(exact["span_tensions"][i][:, 0] - tensions).max() <= 1e-6 * np.abs(tensions).max()
        if "tension" in cable:     # held history: the 2.6 N release misses what its stuck spans owe the past
            held = friction.equilibrium_sensitivities(model, results[3], results[2].friction)
            assert np.abs(held["effector_positions"][:, 0] - exact["effector_positions"][3][:, 0]).max() > 1e-3 * \
                np.abs(exact["effector_positions"][3]).max()


def test_calibration_derivatives_by_friction_are_exact_along_the_sequence():
    # SequencePredictor's μ columns: forward mode along the samples (no sequence per μ) against
    # central differences of the whole sequence (h = 1e-3): measured 6e-8
    import sys
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from test_calibration import MAPPING, SCENE
    from vertebra.solver.calibration import Samples, parse_mapping, parse_parameters
    from vertebra.solver.calibration.sequence import SequencePredictor
    scene = solver.parse_scene(__import__("tomllib").loads(SCENE))
    mapping = parse_mapping(MAPPING, "map.toml")
    up = np.linspace(0.0, 3.0, 5)
    loop = np.r_[up, up[::-1][1:]]
    commands = 1e-3 * np.array([(u, -1.0, -1.0) for u in loop] + [(-1.0, u, 0.5 * u - 1.0) for u in loop])
    samples = Samples(commands, np.zeros((len(commands), 1, 3)), ("a",) * len(loop) + ("b",) * len(loop), "synthetic")
    ps = parse_parameters(["friction.*"], scene, mapping, solver.build_model(scene))
    predictor = SequencePredictor(scene, mapping)
    values = ps.values(np.full(len(ps.names), 0.1))
    elements = [e for es in ps.elements for e in es]
    solved = []
    predictor._difference = lambda *args: solved.append(args) or 1 / 0      # no sequence per μ
    exact = predictor.predict(values, samples, elements).derivatives
    assert not solved
    h = 1e-3
    difference = np.stack([(predictor._sequence(values.with_elements([(e, values.get(*e) + h)]), samples, keep=False)[0]
                            - predictor._sequence(values.with_elements([(e, values.get(*e) - h)]), samples, keep=False)[0])
                           / (2 * h) for e in elements], -1)
    assert np.abs(exact - difference).max() <= 1e-6 * np.abs(difference).max()
