"""Calibration (vertebra.solver.calibration, `vertebra calibrate`): the tendon law at
equilibrium, the analytic derivatives against re-solved differences, the mapping file's
errors, the synthetic recovery of known parameters within their standard errors, and the
command line end to end. A small robot (one section of four vertebrae, three tendons) keeps
every test fast."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.core.errors import InputError, OptionError
from vertebra.solver.calibration import (MappingError, Samples, calibrate, load_samples, parse_mapping,
                                         parse_parameters)
from vertebra.solver.calibration.backend import RuntimePredictor
from vertebra.solver.calibration.data import lag, play, transmission
from vertebra.solver.calibration.tension_play import march

SCENE = """name = "small tendon robot"
[solver]
tolerance = 1e-10
[[segment]]
type = "beam"
count = 4
length = 0.02
youngs_modulus = 50e9
poisson_ratio = 0.3
section = { shape = "circle", radius = 0.0005 }
[[cable]]
name = "a"
radius = 0.004
angle_deg = 0.0
to = 4
stroke = 0.0
stiffness = 3000.0
[[cable]]
name = "b"
radius = 0.004
angle_deg = 120.0
to = 4
stroke = 0.0
stiffness = 3000.0
[[cable]]
name = "c"
radius = 0.004
angle_deg = 240.0
to = 4
stroke = 0.0
stiffness = 3000.0
"""

MAPPING = {
    "data": {"pattern": "pattern"},
    "actuator": [{"column": f"servo_{n}", "cable": n, "unit": "mm"} for n in "abc"],
    "marker": [{"name": "tip", "columns": ["x", "y", "z"], "unit": "mm", "vertebra": -1, "offset": [0.0, 0.0, 5.0]}],
    "frame": {"unit": "mm", "position": [0.0, 0.0, 0.0]},
}

# the truth of the synthetic data: tendon stiffness, pretensions, one hole-angle error, the frame
TRUTH = {"cable_stiffness": 2400.0, "pretension.a": 0.6, "pretension.b": -1.5, "angle.b": 0.06,
         "frame.x": 0.0015, "frame.z": -0.004}
FIT = ["cable_stiffness", "pretension.a", "pretension.b", "pretension.c", "angle.b", "frame.x", "frame.z"]


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibration")
    path = root / "scene.toml"
    path.write_text(SCENE)
    return solver.load_scene(path), parse_mapping(MAPPING, "map.toml"), root


def _commands():
    """Single pulls of a and b and their combinations; c stays slack (5 mm released): its
    pretension cannot be seen."""
    rows = []
    for u in np.linspace(0.0, 3.0, 6):
        rows += [(u, -2.0, -5.0), (-2.0, u, -5.0), (u, 0.8 * u, -5.0), (0.5 * u, 1.5, -5.0)]
    return 1e-3 * np.array(rows)


def _truth_values(robot):
    scene, mapping, _ = robot
    ps = parse_parameters(FIT, scene, mapping, solver.build_model(scene))
    x = ps.initial.copy()
    for i, name in enumerate(ps.names):
        x[i] = TRUTH.get(name, x[i])
    return ps, x


def _noisy_markers(scene, mapping, values, noise: float, seed: int) -> Samples:
    """The predicted markers of the commands of :func:`_commands` at ``values``, with Gaussian noise
    of ``noise`` m (seeded by ``seed``)."""
    commands = _commands()
    empty = Samples(commands, np.zeros((len(commands), 1, 3)), ("pulls",) * len(commands), "synthetic")
    markers = RuntimePredictor(scene, mapping).predict(values, empty).markers
    rng = np.random.default_rng(seed)
    return Samples(commands, markers + noise * rng.standard_normal(markers.shape), empty.patterns, "synthetic")


def _synthetic(robot, noise: float, seed: int) -> Samples:
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    return _noisy_markers(scene, mapping, ps.values(x), noise, seed)


def test_prediction_is_the_scenes_equilibrium(robot):
    """A prediction is the forward solve of the scene with the parameters set, the strokes of
    the commands (a negative pretension shortening the stroke by its slack) and the marker
    moved into the measurement frame."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x)
    samples = _synthetic(robot, 0.0, 0).take([20, 21])
    predicted = RuntimePredictor(scene, mapping).predict(values, samples).markers
    model = solver.build_model(scene)
    k = values.cable_stiffness
    model.set_parameters(cable_stiffness=k, pretension=np.maximum(values.pretension, 0.0),
                         hole_angle=[c.angle + d for c, d in zip(scene.cables, values.angle)])
    for command, marker in zip(samples.commands, predicted):
        result = model.solve(command + np.minimum(values.pretension, 0.0) / k)
        tension = model.cable_tensions(result.state, result.actuation)
        assert tension[:2].max() > 0.5 and tension[2] == 0.0      # a or b taut, c slack
        R = _rotation(result.state.quaternions[-1])
        tip = result.state.positions[-1] + R @ np.array([0.0, 0.0, 0.005]) + values.frame[:3]
        np.testing.assert_allclose(marker[0], tip, atol=1e-12)


def _rotation(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_derivatives_match_resolved_differences(robot):
    """Each element's analytic derivative against central differences of re-solved
    predictions; the differences' own error (step² and the solves' tolerance) is below 1e-4
    of the largest derivative."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x)
    samples = _synthetic(robot, 0.0, 0).take(np.arange(0, 24, 3))
    predictor = RuntimePredictor(scene, mapping)
    wrt = [("stiffness", 0), ("angle", 1), ("radius", 0), ("cable_stiffness", 0), ("pretension", 1),
           ("frame", 1), ("frame", 4), ("marker", (0, 2))]
    steps = {"stiffness": 1e-4, "angle": 1e-5, "radius": 1e-7, "cable_stiffness": 0.1, "pretension": 1e-3,
             "frame": 1e-6, "marker": 1e-6}
    analytic = predictor.predict(values, samples, wrt).derivatives
    for j, (kind, index) in enumerate(wrt):
        h = steps[kind]
        plus = predictor.predict(values.with_elements([((kind, index), values.get(kind, index) + h)]), samples)
        minus = predictor.predict(values.with_elements([((kind, index), values.get(kind, index) - h)]), samples)
        numeric = (plus.markers - minus.markers) / (2 * h)
        scale = np.abs(numeric).max()
        assert scale > 0.0, kind
        assert np.abs(analytic[..., j] - numeric).max() <= 1e-4 * scale, (kind, index)


def test_recovery_within_standard_errors(robot):
    """Twenty noise draws (0.2 mm per coordinate): every identifiable parameter within three
    standard errors of the truth in every draw, the standardised errors' spread near one (the
    standard errors are neither optimistic nor pessimistic), and the pretension of the tendon
    that is never pulled reported unidentifiable."""
    scene, mapping, _ = robot
    ps, truth = _truth_values(robot)
    z = []
    for seed in range(20):
        cal = calibrate(scene, mapping, _synthetic(robot, 2e-4, seed), fit=FIT)
        names = list(cal.parameters.names)
        assert not cal.identifiable[names.index("pretension.c")]
        ok = cal.identifiable
        assert ok.sum() == len(names) - 1
        scores = (cal.x[ok] - truth[ok]) / cal.standard_errors[ok]
        assert np.all(np.abs(scores) <= 3.0), dict(zip(np.array(names)[ok], scores))
        z.extend(scores)
    spread = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 <= spread <= 1.5, spread


def test_mapping_errors_name_file_field_and_reason(robot, tmp_path):
    scene, mapping, _ = robot
    model = solver.build_model(scene)
    bad = dict(MAPPING, actuator=[dict(MAPPING["actuator"][0], sign=2)])
    with pytest.raises(MappingError, match=r"map.toml: actuator\[0\].sign: must be \+1"):
        parse_mapping(bad, "map.toml")
    bad = dict(MAPPING, marker=[dict(MAPPING["marker"][0], unit="inch")])
    with pytest.raises(MappingError, match=r"marker\[0\].unit: must be one of"):
        parse_mapping(bad, "map.toml")
    with pytest.raises(MappingError, match="map.toml: actuators: unknown field"):
        parse_mapping(dict(MAPPING, actuators=[]), "map.toml")
    csv = tmp_path / "data.csv"
    csv.write_text("pattern,servo_a,servo_b,x,y,z\np,1,2,3,4,5\n")
    with pytest.raises(MappingError, match=r"data.csv: servo_c: column 'servo_c'"):
        load_samples(csv, mapping)
    csv.write_text("pattern,servo_a,servo_b,servo_c,x,y,z\np,1,oops,3,4,5,6\n")
    with pytest.raises(MappingError, match=r"row 2, column servo_b: expected a number"):
        load_samples(csv, mapping)
    with pytest.raises(OptionError, match="unknown angle member"):
        parse_parameters(["angle.zz"], scene, mapping, model)
    with pytest.raises(OptionError, match="lower bound"):
        parse_parameters(["stiffness=2:1"], scene, mapping, model)
    with pytest.raises(OptionError, match="already fitted"):
        parse_parameters(["pretension.a+b", "pretension.*"], scene, mapping, model)
    shared = parse_parameters(["pretension.a+b=-2:2"], scene, mapping, model)
    assert shared.names == ("pretension.a+b",) and shared.elements == ((("pretension", 0), ("pretension", 1)),)
    assert (shared.lower[0], shared.upper[0]) == (-2.0, 2.0)
    assert issubclass(MappingError, InputError)


def _write_csv(path, samples):
    lines = ["pattern,servo_a,servo_b,servo_c,x,y,z"]
    for c, m, p in zip(samples.commands, samples.markers, samples.patterns):
        lines.append(",".join([p] + [f"{1e3 * v:.9f}" for v in c] + [f"{1e3 * v:.9f}" for v in m[0]]))
    path.write_text("\n".join(lines) + "\n")


def test_command_line_end_to_end(robot, tmp_path, capsys):
    """`vertebra calibrate … --json` prints one document whose held-out RMSE is the one the
    API computes; the calibrated scene reproduces the fitted markers when simulated."""
    scene, _, root = robot
    data = _synthetic(robot, 1e-4, 7)
    steps = np.arange(24) // 4                     # every pattern at alternate pull levels
    _write_csv(tmp_path / "train.csv", data.take(np.flatnonzero(steps % 2 == 0)))
    _write_csv(tmp_path / "val.csv", data.take(np.flatnonzero(steps % 2 == 1)))
    (tmp_path / "map.toml").write_text(
        '[data]\npattern = "pattern"\n'
        + "".join(f'[[actuator]]\ncolumn = "servo_{n}"\ncable = "{n}"\nunit = "mm"\n' for n in "abc")
        + '[[marker]]\nname = "tip"\ncolumns = ["x", "y", "z"]\nunit = "mm"\noffset = [0.0, 0.0, 5.0]\n'
        + '[fit]\nparameters = ["cable_stiffness", "pretension.a", "pretension.b", "angle.b", "frame.x", "frame.z"]\n')
    code = main(["calibrate", str(root / "scene.toml"),
        "--data", str(tmp_path / "train.csv"), "--holdout", str(tmp_path / "val.csv"),
        "--map", str(tmp_path / "map.toml"), "--json", "--output", str(tmp_path / "calibrated.toml"),
        "--report", str(tmp_path / "report.md")])
    assert code == 0
    document = json.loads(capsys.readouterr().out)
    assert document["holdout"]["rmse_m"] < 3e-4            # noise 0.1 mm per coordinate: 0.17 mm expected
    assert math.isclose(document["holdout"]["rmse_pct_length"], 100 * document["holdout"]["rmse_m"] / 0.08)
    assert [p["name"] for p in document["parameters"]] == ["cable_stiffness", "pretension.a", "pretension.b",
                                                           "angle.b", "frame.x", "frame.z"]
    assert (tmp_path / "report_plots" / "markers_3d.png").exists()
    assert "## Tip error" in (tmp_path / "report.md").read_text()
    calibrated = solver.load_scene(tmp_path / "calibrated.toml")
    assert calibrated.effectors[-1].name == "tip"
    assert calibrated.base_position[0] == pytest.approx(document["values"]["frame"]["position"][0])


def test_shipped_example_reads_and_predicts():
    """The v4 example's scene, mapping and data load together; before calibration its scene
    predicts the first pulls within 3 cm (the nominal geometry is close; the calibration's
    acceptance run is in docs/calibration.md, minutes long)."""
    from pathlib import Path

    from vertebra.solver.calibration import load_mapping

    root = Path(__file__).resolve().parents[1] / "examples" / "calibration" / "ftdcr_v4"
    scene = solver.load_scene(root / "scene.toml")
    mapping = load_mapping(root / "map.toml")
    train = load_samples(root / "tdcr_sysid_20260511-183002_train.csv", mapping)
    holdout = load_samples(root / "tdcr_sysid_20260511-183002_val.csv", mapping)
    assert (len(train), len(holdout)) == (1620, 443)
    assert train.patterns[0] == "tendon0_id4_pull"          # the mapping's pattern_strip applied
    predictor = RuntimePredictor(scene, mapping)
    ps = parse_parameters(list(mapping.fit), scene, mapping, predictor.model)
    first = train.take(np.arange(12))
    error = np.linalg.norm(predictor.predict(ps.values(ps.initial), first).markers - first.markers, axis=-1)
    assert error.max() < 0.03


def test_lm_and_trf_agree_on_exact_data(robot):
    """On noise-free data both methods land on the truth (to the solves' resolution, far below
    a micrometre), and with a robust loss too: nothing there is an outlier."""
    scene, mapping, _ = robot
    ps, truth = _truth_values(robot)
    data = _synthetic(robot, 0.0, 0)
    fit = [f for f in FIT if f != "pretension.c"]
    keep = [list(ps.names).index(f) for f in fit]
    for options in ({"method": "trf"}, {"method": "lm"}, {"method": "trf", "loss": "soft_l1"}):
        cal = calibrate(scene, mapping, data, fit=fit, **options)
        assert cal.train["max_m"] < 1e-7, options
        np.testing.assert_allclose(cal.x, truth[keep], rtol=1e-4, atol=1e-7)


def test_worker_processes_and_warm_starts(robot):
    """Two worker processes predict what the calling process does (markers and derivatives, to
    the solves' tolerance), and after a Jacobian a nearby evaluation starts every sample from its
    equilibrium moved to first order: fewer Newton iterations than from the equilibrium as it was."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x)
    samples = _synthetic(robot, 0.0, 0)
    wrt = [("stiffness", 0), ("angle", 1), ("cable_stiffness", 0), ("pretension", 0), ("frame", 4)]
    alone = RuntimePredictor(scene, mapping)
    here = alone.predict(values, samples, wrt)
    with RuntimePredictor(scene, mapping, workers=2) as pool:
        there = pool.predict(values, samples, wrt)
        processes = pool._pool.processes
        assert len(processes) == 2 and all(p.is_alive() for p in processes)
    assert not any(p.is_alive() for p in processes)          # ended with the predictor
    # equilibria to the scene's tolerance (1e-10) from different warm starts: far below a nanometre
    assert np.abs(there.markers - here.markers).max() <= 1e-9
    assert np.abs(there.derivatives - here.derivatives).max() <= 1e-6 * np.abs(here.derivatives).max()
    moved = ps.values(x + 0.01 * ps.typical)
    predicted = alone.predict(moved, samples).iterations
    plain = RuntimePredictor(scene, mapping)                 # its states carry no derivatives
    plain.predict(values, samples)
    unpredicted = plain.predict(moved, samples).iterations
    assert predicted <= 0.8 * unpredicted           # (39 against 57 at the scene's tolerance of 1e-10)



def test_play_lags_a_rising_command_and_leads_a_falling_one():
    commands = np.array([[0.0, 0.0], [1.0, -1.0], [2.0, -0.92], [1.5, -1.6], [0.5, -1.6], [1.0, 0.0]])
    strokes, slopes = play(commands, np.array([0.3, 0.05]))
    np.testing.assert_allclose(strokes[:, 0], [0.0, 0.7, 1.7, 1.7, 0.8, 0.8])
    np.testing.assert_allclose(slopes[:, 0], [0.0, -1.0, -1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(strokes[:, 1], [0.0, -0.95, -0.95, -1.55, -1.55, -0.05])
    np.testing.assert_allclose(slopes[:, 1], [0.0, 1.0, 1.0, 1.0, 1.0, -1.0])
    h = 1e-7
    numeric = (play(commands, np.array([0.3 + h, 0.05 + h]))[0] - play(commands, np.array([0.3 - h, 0.05 - h]))[0])
    np.testing.assert_allclose(numeric / (2 * h), slopes, atol=1e-6)
    assert np.array_equal(play(commands, np.zeros(2))[0], commands)


def _played(robot, width: float, noise: float, seed: int):
    """Synthetic samples of a transmission with play ``width`` on every tendon (the truth's other
    values as in TRUTH)."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x).with_elements([(("backlash", i), width) for i in range(3)])
    return values, _noisy_markers(scene, mapping, values, noise, seed)


def test_backlash_derivatives_match_resolved_differences_and_a_play_is_recovered(robot):
    """The markers' derivative with respect to a tendon's play (the actuator's exact sensitivity
    times the stroke's slope) against central differences of re-solved sequences (no command of
    the sequence sits exactly at the edge of the play, where the derivative jumps); and a play of
    0.13 mm in the synthetic data recovered within three standard errors, with the other
    parameters, from noisy markers."""
    scene, mapping, _ = robot
    values, samples = _played(robot, 1.3e-4, 0.0, 0)
    predictor = RuntimePredictor(scene, mapping)
    wrt = [("backlash", 0), ("backlash", 1), ("stiffness", 0)]
    analytic = predictor.predict(values, samples, wrt).derivatives
    assert_matches_differences(lambda v: predictor.predict(v, samples).markers, values, analytic, wrt[:2],
                               lambda kind: 1e-7, tolerance=1e-4)
    truth, noisy = _played(robot, 1.3e-4, 5e-5, 1)
    cal = calibrate(scene, mapping, noisy, fit=FIT + ["backlash.a+b"])
    names = list(cal.parameters.names)
    i = names.index("backlash.a+b")
    assert cal.identifiable[i]
    assert abs(cal.x[i] - 1.3e-4) <= 3.0 * cal.standard_errors[i], (cal.x[i], cal.standard_errors[i])
    assert cal.standard_errors[i] < 5e-5


def test_lag_relaxes_towards_the_command_with_exact_derivatives():
    """A first-order lag between the samples' times: the stroke covers ``1 − exp(−Δt/τ)`` of its
    way to the command at each row; its derivatives by τ and by a play before it (carried through
    the lag) against central differences to 1e-6; τ = 0 passes the commands on unchanged."""
    commands = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [3.0, -1.0], [2.0, -1.0], [2.5, 0.5]])
    times = np.array([0.0, 0.5, 1.0, 1.2, 2.0, 2.0])
    strokes, d_tau, _ = lag(commands, times, np.array([0.5, 0.0]))
    a = math.exp(-1.0)
    assert strokes[1, 0] == pytest.approx(1.0 - a) and strokes[2, 0] == pytest.approx(1.0 - a * a)
    assert strokes[5, 0] == strokes[4, 0]                         # no time between them: no move
    assert np.array_equal(strokes[:, 1], commands[:, 1])          # τ = 0: no lag
    width, tau = np.array([0.3, 0.05]), np.array([0.4, 0.7])
    _, derivatives = transmission(commands, times, width, tau)
    for kind, base in (("backlash", width), ("lag", tau)):
        for j in range(2):
            h = np.zeros(2)
            h[j] = 1e-6
            moved = [transmission(commands, times, *((base + sign * h, tau) if kind == "backlash" else
                                                    (width, base + sign * h)))[0] for sign in (1.0, -1.0)]
            numeric = (moved[0] - moved[1])[:, j] / 2e-6
            assert np.abs(numeric).max() > 0.1
            assert np.abs(derivatives[kind][:, j] - numeric).max() <= 1e-6 * np.abs(numeric).max(), (kind, j)
    for width in (np.zeros(2), np.array([0.3, 0.05])):
        assert np.array_equal(transmission(commands, times, width, np.zeros(2))[0], play(commands, width)[0])


def _lagged(robot, tau: float, noise: float, seed: int):
    """Synthetic samples 0.6 s apart (one pause of 5 s) whose strokes follow the commands with a
    lag of time constant ``tau`` on every tendon (the truth's other values as in TRUTH)."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x).with_elements([(("lag", i), tau) for i in range(3)])
    commands = _commands()
    times = 0.6 * np.arange(len(commands)) + 5.0 * (np.arange(len(commands)) >= len(commands) // 2)
    empty = Samples(commands, np.zeros((len(commands), 1, 3)), ("pulls",) * len(commands), "synthetic",
                    times=times)
    markers = RuntimePredictor(scene, mapping).predict(values, empty).markers
    rng = np.random.default_rng(seed)
    return values, Samples(commands, markers + noise * rng.standard_normal(markers.shape), empty.patterns,
                           "synthetic", times=times)


def test_lag_derivatives_match_resolved_differences_and_a_lag_is_recovered(robot, tmp_path):
    """The markers' derivative by a tendon's time constant and by a play before the lag (the
    actuator's exact sensitivity times the stroke's derivative) against central differences of
    re-solved sequences to 1e-6 of the largest (the equilibria solved to 1e-13 for the
    differences: at the scene's 1e-10 they carry 2e-6); a lag of 0 gives today's predictions
    exactly; and a time constant of 0.3 s in the synthetic data recovered within three standard
    errors, with the other parameters, from noisy markers."""
    scene, mapping, _ = robot
    (tmp_path / "tight.toml").write_text(SCENE.replace("tolerance = 1e-10", "tolerance = 1e-13"))
    values, samples = _lagged(robot, 0.3, 0.0, 0)
    predictor = RuntimePredictor(solver.load_scene(tmp_path / "tight.toml"), mapping)
    wrt = [("lag", 0), ("lag", 1), ("backlash", 0), ("stiffness", 0)]
    played = values.with_elements([(("backlash", 0), 1e-4)])
    analytic = predictor.predict(played, samples, wrt).derivatives
    assert_matches_differences(lambda v: predictor.predict(v, samples).markers, played, analytic, wrt[:3],
                               lambda kind: 3e-5 if kind == "lag" else 3e-8)
    untimed = Samples(samples.commands, samples.markers, samples.patterns, "synthetic")
    still = values.with_elements([(("lag", i), 0.0) for i in range(3)])
    assert np.array_equal(RuntimePredictor(scene, mapping).predict(still, samples).markers,
                          RuntimePredictor(scene, mapping).predict(still, untimed).markers)
    with pytest.raises(OptionError, match="a lag needs each sample's time"):
        RuntimePredictor(scene, mapping).predict(values, untimed)
    _, noisy = _lagged(robot, 0.3, 5e-5, 1)
    cal = calibrate(scene, mapping, noisy, fit=FIT + ["lag.a+b"])
    names = list(cal.parameters.names)
    i = names.index("lag.a+b")
    assert cal.identifiable[i]
    assert abs(cal.x[i] - 0.3) <= 3.0 * cal.standard_errors[i], (cal.x[i], cal.standard_errors[i])
    assert cal.standard_errors[i] < 0.05


def test_march_is_the_play_at_zero_rate_and_solves_the_linearised_play():
    """Without growth (b1 = 0) the march is the plain play, exactly; with a tension linear in
    the strokes it meets the implicit relation ``s = c ∓ (b0 + b1 T(s))`` on every moving row."""
    rng = np.random.default_rng(5)
    commands = np.cumsum(rng.normal(scale=0.4, size=(40, 3)), axis=0)
    b0 = np.array([0.1, 0.05, 0.2])
    G = np.array([[2.0, -0.3, 0.1], [-0.3, 1.5, 0.0], [0.1, 0.0, 1.0]])
    tension = np.zeros((40, 3))
    strokes, status = march(commands, b0, np.zeros(3), tension, np.broadcast_to(G, (40, 3, 3)), commands)
    assert np.array_equal(strokes, play(commands, b0)[0])
    b1 = np.array([0.05, 0.1, 0.02])
    at = commands.copy()
    offset = np.full(3, 4.0)                         # T(s) = 4 + G (s − at): positive on these rows
    strokes, status = march(commands, b0, b1, offset + tension, np.broadcast_to(G, (40, 3, 3)), at)
    T = offset + np.einsum("ij,kj->ki", G, strokes - at)
    assert (status != 0).sum() > 40 and (status == 0).sum() > 5
    w = b0 + b1 * T
    moving = status != 0
    np.testing.assert_allclose(strokes[moving], (commands - status * w)[moving], atol=1e-12)
    assert np.array_equal(strokes[1:][~moving[1:]], strokes[:-1][~moving[1:]])
    assert np.all(np.abs(strokes[1:] - commands[1:])[~moving[1:]] <= w[1:][~moving[1:]] + 1e-12)


def _tension_played(robot, b0: float, b1: float, noise: float, seed: int, hold: float = 0.0):
    """Synthetic samples through a play of ``b0 + b1·T`` on every tendon and an entry friction
    ``hold`` (the truth's other values as in TRUTH)."""
    scene, mapping, _ = robot
    ps, x = _truth_values(robot)
    values = ps.values(x).with_elements([(("backlash", i), b0) for i in range(3)]
                                        + [(("backlash_rate", i), b1) for i in range(3)]
                                        + [(("entry_friction", i), hold) for i in range(3)])
    return values, _noisy_markers(scene, mapping, values, noise, seed)


def test_tension_play_derivatives_match_resolved_differences_and_a_rate_is_recovered(robot, tmp_path):
    """A play that grows with the tension: the strokes meet the implicit relation at the solved
    tensions; the markers' derivatives by the rate, the play and model parameters (carried
    through the strokes' recursion) against central differences of re-solved sequences to 1e-6
    (equilibria to 1e-13); a rate of 0 gives the plain play's predictions; a rate of 0.1 mm/N in
    the synthetic data recovered within three standard errors with the play and the others."""
    scene, mapping, _ = robot
    (tmp_path / "tight.toml").write_text(SCENE.replace("tolerance = 1e-10", "tolerance = 1e-13"))
    tight = solver.load_scene(tmp_path / "tight.toml")
    values, samples = _tension_played(robot, 5e-5, 1e-4, 0.0, 0)
    wrt = [("backlash_rate", 0), ("backlash_rate", 1), ("backlash", 0), ("stiffness", 0), ("cable_stiffness", 1),
           ("frame", 0)]
    predictor = RuntimePredictor(tight, mapping)
    analytic = predictor.predict(values, samples, wrt).derivatives
    # the strokes found are consistent with the equilibria's tensions
    strokes = predictor._tension_state[next(iter(predictor._tension_state))][1]
    model = predictor.model
    tensions = []
    for command in strokes:
        result = model.solve(command)
        tensions.append(model.cable_tensions(result.state, result.actuation))
    tensions = np.array(tensions)
    assert tensions.max() > 1.0
    again, status = march(samples.commands, np.full(3, 5e-5), np.full(3, 1e-4), tensions,
                          np.zeros((len(strokes), 3, 3)), strokes)
    assert (status != 0).sum() > 10
    assert np.abs(again - strokes).max() <= 1e-12
    size = {"backlash_rate": 1e-4, "backlash": 5e-5, "stiffness": 1.0, "cable_stiffness": 3000.0}
    assert_matches_differences(lambda v: RuntimePredictor(tight, mapping).predict(v, samples).markers, values,
                               analytic, wrt[:-1], lambda kind: 1e-4 * size[kind])
    still = values.with_elements([(("backlash_rate", i), 0.0) for i in range(3)])
    plain = RuntimePredictor(scene, mapping).predict(still, samples).markers
    implicit = RuntimePredictor(scene, mapping).predict(still, samples, [("backlash_rate", 0)]).markers
    assert np.abs(implicit - plain).max() <= 1e-12
    _, noisy = _tension_played(robot, 5e-5, 1e-4, 5e-5, 1)
    cal = calibrate(scene, mapping, noisy, fit=FIT + ["backlash.a+b", "backlash_rate.a+b"])
    names = list(cal.parameters.names)
    for name, truth in (("backlash_rate.a+b", 1e-4), ("backlash.a+b", 5e-5)):
        i = names.index(name)
        assert cal.identifiable[i], name
        assert abs(cal.x[i] - truth) <= 3.0 * cal.standard_errors[i], (name, cal.x[i], cal.standard_errors[i])
    assert cal.standard_errors[names.index("backlash_rate.a+b")] < 3e-5


def assert_matches_differences(predict, values, analytic, wrt, step, tolerance=1e-6):
    """The markers' derivatives ``analytic`` (…, len(wrt)) by the parameters ``wrt`` against central
    differences of ``predict(values)`` (the markers; step ``step(kind)``), to ``tolerance`` of each
    one's largest entry."""
    for j, (kind, index) in enumerate(wrt):
        h = step(kind)
        moved = [predict(values.with_elements([((kind, index), values.get(kind, index) + sign * h)]))
                 for sign in (1.0, -1.0)]
        numeric = (moved[0] - moved[1]) / (2 * h)
        scale = np.abs(numeric).max()
        assert scale > 0.0, kind
        assert np.abs(analytic[..., j] - numeric).max() <= tolerance * scale, (kind, index)


def test_entry_friction_holds_a_released_tendon_and_is_recovered(robot, tmp_path):
    """Friction at the entry: a tendon released below its slack keeps the tension it can hold
    there (the robot stays bent) — exactly ``hold`` where it slid back in, less where it stopped
    before; the markers' derivatives by it against re-solved differences to 1e-6 (equilibria to
    1e-13); 0.8 N in the synthetic data recovered within three standard errors."""
    scene, mapping, _ = robot
    (tmp_path / "tight.toml").write_text(SCENE.replace("tolerance = 1e-10", "tolerance = 1e-13"))
    tight = solver.load_scene(tmp_path / "tight.toml")
    values, samples = _tension_played(robot, 5e-5, 0.0, 0.0, 0, hold=0.8)
    wrt = [("entry_friction", 0), ("entry_friction", 1), ("backlash", 0)]
    predictor = RuntimePredictor(tight, mapping)
    analytic = predictor.predict(values, samples, wrt).derivatives
    strokes = predictor._tension_state[next(iter(predictor._tension_state))][1]
    model = predictor.model
    released = samples.commands[:, :2] < 0.0            # a and b at −2 mm, after a pull
    tensions = np.array([model.cable_tensions(model.solve(command).state, command) for command in strokes])
    assert released.sum() >= 10
    assert np.all(tensions[:, :2][released] <= 0.8 + 1e-9)
    assert np.sum(np.abs(tensions[:, :2][released] - 0.8) < 1e-9) >= 6
    plain = RuntimePredictor(scene, mapping).predict(values.with_elements(
        [(("entry_friction", i), 0.0) for i in range(3)]), samples).markers
    assert np.abs(predictor.predict(values, samples).markers - plain).max() > 1e-3   # it holds the robot bent
    assert_matches_differences(lambda v: RuntimePredictor(tight, mapping).predict(v, samples).markers, values,
                               analytic, wrt, lambda kind: 1e-4 * (1.0 if kind == "entry_friction" else 5e-5))
    _, noisy = _tension_played(robot, 5e-5, 0.0, 5e-5, 1, hold=0.8)
    cal = calibrate(scene, mapping, noisy, fit=FIT + ["backlash.a+b", "entry_friction.a+b"])
    names = list(cal.parameters.names)
    i = names.index("entry_friction.a+b")
    assert cal.identifiable[i]
    assert abs(cal.x[i] - 0.8) <= 3.0 * cal.standard_errors[i], (cal.x[i], cal.standard_errors[i])
    assert cal.standard_errors[i] < 0.1


def test_memory_terms_that_do_not_combine_are_refused(robot):
    scene, mapping, _ = robot
    values, samples = _lagged(robot, 0.3, 0.0, 0)
    with pytest.raises(OptionError, match="and a lag together are not supported"):
        RuntimePredictor(scene, mapping).predict(values.with_elements([(("entry_friction", 0), 0.5)]), samples)
    with pytest.raises(OptionError, match="and a lag together are not supported"):
        RuntimePredictor(scene, mapping).predict(values, samples, [("backlash_rate", 1)])
    ps = parse_parameters(["lag.a=0:2", "entry_friction.b"], scene, mapping, solver.build_model(scene))
    assert ps.units() == ["s", "N"] and (ps.lower[0], ps.upper[0]) == (0.0, 2.0)
    assert ps.initial[1] > 0.0                      # (started inside its bounds: 0 is the lower one)


def test_time_column_is_read_and_checked(robot, tmp_path):
    scene, mapping, _ = robot
    timed = parse_mapping(dict(MAPPING, data={"pattern": "pattern", "time": "t", "time_unit": "ms"}), "map.toml")
    csv = tmp_path / "data.csv"
    csv.write_text("t,pattern,servo_a,servo_b,servo_c,x,y,z\n0,p,1,2,3,4,5,6\n600,p,1,2,3,4,5,6\n")
    samples = load_samples(csv, timed)
    np.testing.assert_allclose(samples.times, [0.0, 0.6])
    assert samples.take([1]).times.tolist() == [0.6]
    assert load_samples(csv, mapping).times is None
    csv.write_text("t,pattern,servo_a,servo_b,servo_c,x,y,z\n5,p,1,2,3,4,5,6\n4,p,1,2,3,4,5,6\n")
    with pytest.raises(MappingError, match=r"data.csv: row 3, column t: time runs backwards \(5 then 4\)"):
        load_samples(csv, timed)
    with pytest.raises(MappingError, match=r"data.time_unit: must be one of"):
        parse_mapping(dict(MAPPING, data={"time": "t", "time_unit": "hours"}), "map.toml")


def test_the_statistical_stop_measures_the_gauss_newton_step_in_standard_errors():
    from vertebra.solver.calibration.fit import _step_in_standard_errors
    rng = np.random.default_rng(3)
    J = rng.normal(size=(200, 4))
    noise = rng.normal(size=200)
    noise -= J @ np.linalg.lstsq(J, noise, rcond=None)[0]          # the residual at the optimum, ⟂ J
    offset = np.array([0.3, -0.2, 0.1, 0.05])                       # the point is the optimum + offset
    r = noise + J @ offset
    sigma = math.sqrt(float(r @ r) / (200 - 4))
    wide = np.full(4, 10.0)
    # a linear problem: the step is −offset, its size ‖J offset‖/σ, the bound on any one
    # parameter's step in its standard errors
    step = _step_in_standard_errors(J, r, np.zeros(4), -wide, wide)
    assert step == pytest.approx(np.linalg.norm(J @ offset) / sigma, rel=1e-9)
    se = sigma * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    assert np.all(np.abs(offset) / se <= step * (1 + 1e-9))
    # a bound in the way: the step to the bounded minimum, smaller
    lower = np.array([-0.1, -10.0, -10.0, -10.0])
    bounded = _step_in_standard_errors(J, r, np.zeros(4), lower, wide)
    assert 0.0 < bounded < step
    assert _step_in_standard_errors(J, noise, np.zeros(4), -wide, wide) == pytest.approx(0.0, abs=1e-9)
