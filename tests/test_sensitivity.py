"""Sensitivities from the converged tangent against central differences of full re-solves.

Every column is checked the same way: the parameter moves by ±h, the model is re-solved warm
from the equilibrium to a tolerance of 1e-12 (Newton converges quadratically: the state is then
at its rounding floor), and the central difference of every output is compared with the
analytic derivative. h is 1e-4 of the parameter's scale: the difference's truncation error is
then ~1e-8 relative and its rounding (~1e-15 of a pose over h) ~1e-11, so a tolerance of 1e-6
relative to the column's largest derivative of that output leaves two orders of margin and still
catches a missing term (the smallest term checked here is ~1e-3 of its column).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fitted_energies import with_energy
from test_solver_actuation import synthetic_entry
from vertebra import solver
from vertebra.core.errors import OptionError
from vertebra.core.lie import qconj, qlog, qmatrix, qmul

TOLERANCE = 1e-6
STEP = 1e-4
ROUNDING = 1e3 * np.finfo(float).eps
E, NU, R_ROD, LINK = 54e9, 0.3, 0.0007, 0.02


def rod(count=5, elements=2, density=0.0, mass=0.0, center=(0.0, 0.0, 0.0)):
    return {"type": "beam", "count": count, "length": LINK, "elements": elements, "youngs_modulus": E,
            "poisson_ratio": NU, "section": {"shape": "circle", "radius": R_ROD}, "density": density,
            "vertebra": {"mass": mass, "center_of_mass": list(center)}}


def outputs_at(model, state, actuation):
    """Every output as the sensitivities order it (rotations: the quaternions, differenced below)."""
    strokes = model.cable_lengths(state) - model.trunk.rest_cable_lengths
    n = model.n_cables
    return {"frame_positions": state.positions.reshape(-1).copy(), "frame_rotations": state.quaternions.copy(),
            "effector_positions": model.effector_positions(state).reshape(-1),
            "cable_tensions": model.cable_tensions(state, actuation),
            "cable_strokes": strokes,
            "chamber_volumes": model.chamber_volume_growth(state, actuation[n:])}


def resolve(model, actuation, initial, changes):
    base = model.parameters
    model.set_parameters(**changes)
    try:
        result = model.solve(actuation, initial=initial, tolerance=1e-12)
        return outputs_at(model, result.state, model.actuation(actuation))
    finally:
        model.set_parameters(base)


def differences(model, result, column, h):
    """Central difference of every output in the parameter ``column`` (its name) by ±h."""
    group, _, key = column.partition(":")
    actuation = model.actuation(result.actuation)
    sides = []
    for sign in (1.0, -1.0):
        act, changes = actuation.copy(), {}
        if group == "actuation":
            act[model.actuator_names.index(key)] += sign * h
        elif group == "gravity":
            gravity = np.array(model.parameters.gravity)
            gravity["xyz".index(key)] += sign * h
            changes["gravity"] = gravity
        elif group in ("dead", "follower"):
            vertebra, component = key.split(":")
            wrench = np.array(getattr(model.parameters, group))
            wrench[model.vertebra_frames[int(vertebra)], solver.sensitivity.WRENCH.index(component)] += sign * h
            changes[group] = wrench
        elif group == "stiffness_scale":
            changes[group] = {int(key): model.parameters.stiffness_scale[int(key)] + sign * h}
        else:
            index = model.actuator_names.index(key)
            changes[group] = {key: getattr(model.parameters, group)[index] + sign * h}
        sides.append(resolve(model, act, result.state, changes))
    plus, minus = sides
    numeric = {name: (plus[name] - minus[name]) / (2 * h) for name in plus if name != "frame_rotations"}
    turn = qlog(qmul(plus["frame_rotations"], qconj(minus["frame_rotations"])))     # exp(2h ω) to O(h³)
    numeric["frame_rotations"] = turn.reshape(-1) / (2 * h)
    size = {name: np.abs(plus[name]).max(initial=0.0) for name in plus}
    size["frame_rotations"] = math.pi
    return numeric, size


def check(model, result, steps, *, outputs=solver.sensitivity.OUTPUTS):
    """Every column of ``steps`` (parameter name → h) against central differences."""
    sens = model.sensitivities(result, wrt=tuple(steps), outputs=outputs, method="direct")
    assert sens.parameters == tuple(steps)
    worst = 0.0
    for j, (column, h) in enumerate(steps.items()):
        numeric, size = differences(model, result, column, h)
        for name in outputs:
            exact = sens[name][:, j]
            scale = np.abs(exact).max(initial=0.0)
            error = np.abs(numeric[name] - exact).max(initial=0.0)
            # below the re-solves' rounding (1000 ε of the output over h) a derivative is zero
            rounding = ROUNDING * size[name] / h
            if scale <= rounding:
                assert error <= rounding, (column, name, error)
                continue
            worst = max(worst, error / scale)
            assert error <= TOLERANCE * scale, (column, name, error / scale)
    # the adjoint route gives the same numbers without dq
    adjoint = model.sensitivities(result, wrt=tuple(steps), outputs=outputs, method="adjoint")
    assert adjoint.dq is None and adjoint.method == "adjoint"
    for name in outputs:
        scale = np.abs(sens[name]).max(initial=0.0)
        assert np.abs(adjoint[name] - sens[name]).max(initial=0.0) <= 1e-9 * max(scale, 1e-300)
    return sens, worst


# ------------------------------------------------------------------ beams
def test_beam_cantilever_with_a_tip_load_gravity_and_a_dead_moment():
    # two beam segments with mass under gravity (vertebrae whose centres of mass lie off the axis:
    # the weight's moments turn with them), a tip force and a dead moment (the tangent is
    # unsymmetric: LU, and the adjoint solves with its transpose)
    scene = {"segment": [rod(3, density=7800.0, mass=0.002, center=(0.004, -0.002, 0.001)),
                         rod(2, elements=3, density=2700.0, mass=0.001, center=(0.0, 0.003, 0.0))],
             "gravity": {"vector": [0.0, 0.0, -9.81]},
             "load": [{"vertebra": -1, "force": [0.3, -0.1, 0.0], "moment": [0.0, 0.004, 0.001]}],
             "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.005, 0.0]},
                          {"name": "mid", "vertebra": 2},
                          {"name": "heading", "vertebra": -1, "axis": [1.0, 0.0, 0.0]}]}
    model = solver.build_model(solver.parse_scene(scene))
    assert model.has_dead_moments
    result = model.solve(tolerance=1e-12)
    steps = {"gravity:x": STEP * 9.81, "gravity:z": STEP * 9.81, "dead:5:fx": STEP * 0.3, "dead:3:fz": STEP * 0.3,
             "dead:5:mx": STEP * 0.004, "dead:4:my": STEP * 0.004, "stiffness_scale:0": STEP,
             "stiffness_scale:1": STEP}
    sens, worst = check(model, result, steps, outputs=("frame_positions", "frame_rotations", "effector_positions"))
    # the tip force's derivative of the tip position is the tip's compliance: positive along it
    assert sens["effector_positions"][0, sens.column("dead:5:fx")] > 0.0
    assert sens.effector_jacobian(["mid"]).shape == (3, len(steps))


def test_a_tip_force_on_a_straight_cantilever_gives_the_timoshenko_compliance():
    # at rest, the tip deflection per unit lateral tip force is L³/3EI + L/(κGA) (linear theory is
    # exact for the first derivative at the unloaded state)
    model = solver.build_model(solver.parse_scene({"segment": [rod(5, elements=2)],
                                                   "effector": [{"name": "tip", "vertebra": -1}]}))
    result = model.solve()
    sens = model.sensitivities(result, wrt=("dead:-1:fx",), outputs=("effector_positions",))
    L, I, A = 5 * LINK, math.pi * R_ROD ** 4 / 4, math.pi * R_ROD ** 2
    G = E / (2 * (1 + NU))
    kappa = 6 * (1 + NU) / (7 + 6 * NU)
    expected = L ** 3 / (3 * E * I) + L / (kappa * G * A)
    assert sens["effector_positions"][0, 0] == pytest.approx(expected, rel=1e-9)


# ------------------------------------------------------------------ cables
def tendon_scene(cables):
    return {"segment": [rod(6, elements=2)], "cable": [dict(c) for c in cables],
            "effector": [{"name": "tip", "vertebra": -1, "offset": [0.004, 0.0, 0.0]}]}


CABLES = ({"name": "t1", "radius": 0.01, "angle_deg": 0.0, "to": 6, "tension": 2.0},
          {"name": "t2", "radius": 0.008, "angle_deg": 100.0, "to": 4, "tension": 1.5},
          {"name": "t3", "radius": 0.012, "angle_deg": 220.0, "from": 2, "to": 5, "tension": 0.3})
# t1, t2 taut (t2 with its pretension), t3 slack (its stroke pays out more than its elongation),
# t4 tension-driven
TENDONS = ({"name": "t1", "radius": 0.01, "angle_deg": 0.0, "to": 6, "stroke": 0.002, "stiffness": 2000.0,
            "pretension": 0.5},
           {"name": "t2", "radius": 0.009, "angle_deg": 130.0, "to": 4, "stroke": 0.0005, "stiffness": 800.0,
            "pretension": 1.0},
           {"name": "t3", "radius": 0.01, "angle_deg": 250.0, "to": 6, "stroke": -0.004, "stiffness": 1500.0,
            "pretension": 0.2},
           {"name": "t4", "radius": 0.007, "angle_deg": 300.0, "to": 5, "tension": 0.8})


def test_tension_driven_cables_and_their_holes():
    cables = CABLES
    model = solver.build_model(solver.parse_scene(tendon_scene(cables)))
    result = model.solve(tolerance=1e-12)
    steps = {"actuation:t1": STEP * 2.0, "actuation:t2": STEP * 2.0, "actuation:t3": STEP * 2.0,
             "hole_radius:t1": STEP * 0.01, "hole_angle:t1": STEP, "hole_radius:t2": STEP * 0.01,
             "hole_angle:t2": STEP, "hole_angle:t3": STEP, "dead:6:fy": STEP}
    sens, worst = check(model, result, steps)
    assert sens.differenced == ()          # the holes' terms are analytic
    # a tension-driven cable's tension is its input
    assert sens["cable_tensions"][:, :3] == pytest.approx(np.eye(3))


@pytest.mark.parametrize("moment", [False, True], ids=["symmetric", "dead-moment"])
def test_stroke_driven_tendons_slack_and_taut(moment):
    # t1, t2 taut (t2 with its pretension), t3 slack (its stroke pays out more than its elongation),
    # t4 tension-driven; with a dead moment the band is factored by LU and the adjoint solves with
    # the transpose of the band and of the tendons' Woodbury update
    cables = TENDONS
    scene = tendon_scene(cables)
    if moment:
        scene["load"] = [{"vertebra": -1, "force": [0.0, 0.0, 0.0], "moment": [0.002, -0.003, 0.001]}]
    model = solver.build_model(solver.parse_scene(scene))
    assert model.has_dead_moments == moment
    result = model.solve(tolerance=1e-12)
    tensions = model.cable_tensions(result.state)
    assert tensions[0] > 0.5 and tensions[1] > 0.5 and tensions[2] == 0.0
    steps = {"actuation:t1": STEP * 0.002, "actuation:t2": STEP * 0.002, "actuation:t3": STEP * 0.002,
             "actuation:t4": STEP, "cable_stiffness:t1": STEP * 2000.0, "cable_stiffness:t2": STEP * 800.0,
             "cable_stiffness:t3": STEP * 1500.0, "pretension:t1": STEP, "pretension:t2": STEP,
             "pretension:t3": STEP, "hole_radius:t1": STEP * 0.01, "hole_angle:t2": STEP,
             "hole_radius:t3": STEP * 0.01}
    sens, worst = check(model, result, steps)
    # the slack tendon's own parameters move nothing
    for name in ("actuation:t3", "cable_stiffness:t3", "pretension:t3"):
        assert not sens.dq[:, sens.column(name)].any()
    # a taut tendon's tension per unit stroke is below its spring rate (the trunk gives way)
    assert 0.0 < sens["cable_tensions"][0, sens.column("actuation:t1")] < 2000.0


def test_follower_loads_with_tendons_and_a_dead_moment():
    # follower loads (fixed in their vertebra's axes) at the tip and mid-way, beside taut and slack
    # tendons and a dead moment: the tangent is unsymmetric (their turning), factored by LU, and the
    # adjoint solves with its transpose; every follower component's column against re-solves
    cables = [{"name": "t1", "radius": 0.01, "angle_deg": 0.0, "to": 6, "stroke": 0.002, "stiffness": 2000.0,
               "pretension": 0.5},
              {"name": "t2", "radius": 0.01, "angle_deg": 250.0, "to": 6, "stroke": -0.004, "stiffness": 1500.0,
               "pretension": 0.2}]
    scene = tendon_scene(cables)
    scene["load"] = [{"vertebra": -1, "force": [0.3, -0.2, 0.1], "moment": [0.002, 0.001, -0.003], "follower": True},
                     {"vertebra": 3, "force": [0.0, 0.4, 0.0], "follower": True},
                     {"vertebra": -1, "moment": [0.001, 0.0, 0.002]}]
    model = solver.build_model(solver.parse_scene(scene))
    assert model.trunk.loads.unsymmetric and model.trunk.loads.has_follower
    result = model.solve(tolerance=1e-12)
    assert model.cable_tensions(result.state)[1] == 0.0          # t2 slack
    steps = {f"follower:6:{c}": STEP * (1.0 if c[0] == "f" else 0.01) for c in solver.sensitivity.WRENCH}
    steps.update({"follower:3:fy": STEP, "follower:4:mx": STEP * 0.01, "dead:6:fz": STEP,
                  "actuation:t1": STEP * 0.002, "pretension:t1": STEP, "hole_angle:t1": STEP})
    sens, _ = check(model, result, steps)
    # at the equilibrium, a unit follower force along the tip's own x is the world force R_tip e_x:
    # its column is the dead force's columns along that direction (one tangent serves both)
    R_tip = qmatrix(result.state.quaternions[-1:])[0]
    dead = model.sensitivities(result, wrt=("dead:-1",), outputs=("effector_positions",), method="direct")
    expected = dead["effector_positions"][:, :3] @ R_tip[:, 0]
    assert np.allclose(sens["effector_positions"][:, sens.column("follower:6:fx")], expected, rtol=1e-9, atol=0)


# ------------------------------------------------------------------ chambers
CHAMBERS = ({"name": "c0", "cavity": 0, "from": 1, "to": 4, "pressure": 4e4, "max_pressure": 1.4e5},
            {"name": "c1", "cavity": 1, "from": 2, "to": 3, "pressure": 1.5e4, "max_pressure": 1.4e5})


def chamber_model(entry):
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": 4, "vertebra": {"mass": 0.005}}],
            "chamber": [dict(c) for c in CHAMBERS], "gravity": {"vector": [0.0, 0.0, -9.81]},
            "load": [{"vertebra": -1, "force": [1.0, 0.0, 0.0]}],
            "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.004, 0.0]}]}
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


@pytest.mark.parametrize("fitted", [False, True], ids=["linear", "nonlinear"])
def test_chamber_robot(fitted):
    entry = synthetic_entry()
    model = chamber_model(with_energy(entry, strength=0.3) if fitted else entry)
    result = model.solve(tolerance=1e-12)
    steps = {"actuation:c0": STEP * 4e4, "actuation:c1": STEP * 4e4, "gravity:z": STEP * 9.81,
             "gravity:y": STEP * 9.81, "dead:4:fx": STEP, "dead:2:mz": STEP * 0.01}
    sens, worst = check(model, result, steps)
    # stiffness scales apply to segments without cavities only
    assert sens.parameters and not any(p.startswith("stiffness_scale") for p in
                                       model.sensitivities(result, outputs=("effector_positions",)).parameters)
    with pytest.raises(OptionError):
        model.sensitivities(result, wrt=("stiffness_scale:0",))
    assert bool(sens.differenced) == fitted      # the growth's own pressure term: differenced for fits


# ------------------------------------------------------------------ the interface
def test_names_groups_and_errors():
    cables = [{"name": "a", "radius": 0.01, "angle_deg": 0.0, "to": 6, "stroke": 0.001, "stiffness": 2000.0},
              {"name": "b", "radius": 0.01, "angle_deg": 180.0, "to": 6, "tension": 1.0}]
    model = solver.build_model(solver.parse_scene(tendon_scene(cables)))
    result = model.solve()
    sens = model.sensitivities(result)
    n_vertebrae = len(model.vertebra_frames)
    assert sens.parameters[:2] == ("actuation:a", "actuation:b")
    assert "cable_stiffness:a" in sens.parameters and "cable_stiffness:b" not in sens.parameters
    assert sum(p.startswith("dead:") for p in sens.parameters) == 6 * (n_vertebrae - 1)
    assert "dead:6:mz" in sens.parameters and "stiffness_scale:0" in sens.parameters
    assert sens.dq.shape == (model.n_dof, len(sens.parameters))
    assert sens["frame_positions"].shape == (3 * model.n_frames, len(sens.parameters))
    # the base does not move
    assert not sens["frame_positions"][:3].any() and not sens["frame_rotations"][:3].any()
    # few outputs, many parameters: the adjoint route, the same numbers
    few = model.sensitivities(result, outputs=("effector_positions",))
    assert few.method == "adjoint" and few.dq is None
    assert few.effector_jacobian() == pytest.approx(sens.effector_jacobian(), rel=1e-9, abs=1e-15)
    assert model.sensitivities(result, wrt="dead:-1").parameters == tuple(f"dead:6:{c}" for c in
                                                                          ("fx", "fy", "fz", "mx", "my", "mz"))
    for wrong in ("pretension:b", "actuation:zz", "dead:99", "tension", "gravity:w", "hole_radius:q"):
        with pytest.raises(OptionError):
            model.sensitivities(result, wrt=(wrong,))
    with pytest.raises(OptionError):
        model.sensitivities(result, outputs=("volumes",))
    with pytest.raises(OptionError):
        model.sensitivities(result, wrt=("actuation:a", "actuation"))


def test_gravity_sensitivity_of_a_trunk_without_gravity():
    # a scene without gravity still has masses: the derivative with respect to gravity comes from
    # the state's lever arms (none were evaluated for the potential)
    scene = {"segment": [rod(4, density=7800.0, mass=0.003, center=(0.003, 0.002, 0.0))],
             "load": [{"vertebra": -1, "force": [0.2, 0.0, 0.0]}],
             "effector": [{"name": "tip", "vertebra": -1}]}
    model = solver.build_model(solver.parse_scene(scene))
    result = model.solve(tolerance=1e-12)
    check(model, result, {"gravity:x": STEP * 9.81, "gravity:y": STEP * 9.81, "gravity:z": STEP * 9.81},
          outputs=("frame_positions", "frame_rotations", "effector_positions"))


# ------------------------------------------------------------------ many states at once
BATCH_TOLERANCE = 1e-9


def _kind(name: str) -> str:
    """A parameter's kind for the comparison's scale: columns of one kind share their units (a
    dead or follower load's forces and its moments are two kinds)."""
    group, *rest = name.split(":")
    return group + (rest[-1][0] if group in ("dead", "follower") else "")


def check_batch(model, actuations, *, wrt=solver.sensitivity.PARAMETER_GROUPS, outputs=solver.sensitivity.OUTPUTS,
                method="direct", chunk=None, drop=()):
    """``batch_sensitivities`` of the equilibria of ``actuations`` against ``model.sensitivities``
    of each, every output and ``dq``: the batch sums in another order (its band assembly, the
    explicit terms over a sample axis), so they agree to rounding amplified by the tangent's
    condition — a column that nearly cancels in an output (a cable's stroke per unit moment at
    the base) has its rounding relative to the larger columns of its kind, whose scale it is
    compared at (measured ≤ 1.1e-10 on these robots; the tolerance leaves an order above).
    ``drop``: samples given to the batch with non-finite strains and their state instead."""
    results = [model.solve(a, tolerance=1e-12) for a in actuations]
    strains = np.stack([r.state.carried_strains().xi for r in results])
    states = [r.state for r in results]
    for i in drop:
        strains[i] = np.nan
    values = np.array([model.actuation(a) for a in actuations])
    batch = solver.sensitivity.batch_sensitivities(model, strains, values, wrt=wrt, outputs=outputs, method=method,
                                                   states=states, chunk=chunk)
    for i, result in enumerate(results):
        single = model.sensitivities(result, wrt=wrt, outputs=outputs, method=method)
        assert batch.parameters == single.parameters
        kinds = [_kind(p) for p in single.parameters]
        pairs = [(batch[name][i], single[name]) for name in outputs]
        if method == "direct":
            pairs.append((batch.dq[i], single.dq))
        else:
            assert batch.dq is None
        for found, expected in pairs:
            largest = np.abs(expected).max(0) if expected.size else np.zeros(len(kinds))
            scale = np.array([max(largest[j] for j in range(len(kinds)) if kinds[j] == k) for k in kinds])
            assert np.all(np.abs(found - expected) <= BATCH_TOLERANCE * scale + 1e-300)
    return batch


def test_batch_sensitivities_of_beams_under_gravity_are_the_single_ones():
    scene = {"segment": [rod(3, density=7800.0, mass=0.002, center=(0.004, -0.002, 0.001)),
                         rod(2, elements=3, density=2700.0, mass=0.001, center=(0.0, 0.003, 0.0))],
             "gravity": {"vector": [0.0, 0.0, -9.81]},
             "load": [{"vertebra": -1, "force": [0.3, -0.1, 0.0]}],
             "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.005, 0.0]}, {"name": "mid", "vertebra": 2},
                          {"name": "heading", "vertebra": -1, "axis": [1.0, 0.0, 0.0]}]}
    model = solver.build_model(solver.parse_scene(scene))
    batch = check_batch(model, [None, None])
    assert not batch.single.any() and len(batch) == 2
    assert batch.effector_jacobian(["mid"]).shape == (2, 3, len(batch.parameters))
    assert {_kind(p) for p in batch.parameters} >= {"gravity", "deadf", "deadm", "followerf", "followerm",
                                                    "stiffness_scale"}


@pytest.mark.parametrize("method", ["direct", "adjoint"])
def test_batch_sensitivities_of_cables_and_tendons_are_the_single_ones(method):
    rng = np.random.default_rng(3)
    cables = CABLES
    model = solver.build_model(solver.parse_scene(tendon_scene(cables)))
    assert not check_batch(model, [rng.uniform(0.0, 3.0, 3) for _ in range(4)] + [np.zeros(3)],
                           method=method).single.any()
    # taut and slack stroke-driven tendons beside a tension-driven cable; chunks of two samples
    cables = TENDONS
    model = solver.build_model(solver.parse_scene(tendon_scene(cables)))
    actuations = [np.array([0.002, 0.0005, -0.004, 0.8])] + [
        np.concatenate([rng.uniform(-0.003, 0.003, 3), rng.uniform(0.0, 1.0, 1)]) for _ in range(5)]
    tensions = np.array([model.cable_tensions(model.solve(a).state, a) for a in actuations])
    assert np.any(tensions[:, :3] == 0.0) and np.any(tensions[:, :3] > 0.0)
    batch = check_batch(model, actuations, method=method, chunk=2, drop=(3,))
    assert batch.single.tolist() == [False, False, False, True, False, False]
    assert batch.why[3] == "strains not finite"
    # a dead moment makes the tangent unsymmetric: every sample by the single route, the same numbers
    scene = tendon_scene(cables)
    scene["load"] = [{"vertebra": -1, "moment": [0.002, -0.003, 0.001]}]
    model = solver.build_model(solver.parse_scene(scene))
    assert check_batch(model, actuations[:2], method=method).single.all()


def test_batch_sensitivities_of_gallery_and_example_robots_are_the_single_ones():
    from vertebra.solver.scene import load_scene

    rng = np.random.default_rng(4)
    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    check_batch(model, rng.uniform(0.0, 4.0, (4, model.n_cables)),
                wrt=("actuation", "hole_angle", "hole_radius", "dead:-1", "stiffness_scale"),
                outputs=("effector_positions", "cable_strokes"))
    # the calibration example: three sections, nine stroke-driven tendons, some slack
    from pathlib import Path
    example = Path(solver.__file__).parent.parent / "examples" / "calibration" / "ftdcr_v4" / "scene.toml"
    model = solver.build_model(load_scene(example))
    batch = check_batch(model, rng.uniform(-0.001, 0.003, (4, model.n_cables)),
                        wrt=("stiffness_scale", "cable_stiffness", "pretension", "hole_angle", "hole_radius",
                             "actuation"), outputs=("effector_positions", "cable_tensions", "cable_strokes"))
    assert not batch.single.any()


@pytest.mark.parametrize("fitted", [False, True], ids=["linear", "nonlinear"])
def test_batch_sensitivities_of_chamber_robots(fitted):
    entry = synthetic_entry()
    model = chamber_model(with_energy(entry, strength=0.3) if fitted else entry)
    actuations = [None, np.array([2e4, 5e4])]
    assert not check_batch(model, actuations, outputs=("effector_positions", "frame_rotations")).single.any()
    # a chamber's volume growth by its pressure is a difference per sample: the single route's
    batch = check_batch(model, actuations)
    assert batch.single.all() and bool(batch.differenced) == fitted
