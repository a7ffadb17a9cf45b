"""Effector compliance ``J K⁻¹ Jᵀ`` at an equilibrium, against finite differences of forward
solves and the closed-form Timoshenko cantilever."""

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vertebra import solver
from vertebra.solver.timoshenko import Section, timoshenko_compliance
from vertebra.solver.compliance import effector_compliance
from vertebra.solver.scene import LoadSpec

E, NU, RADIUS, LENGTH = 54e9, 0.33, 0.001, 0.03


def bent_robot(moment=None) -> dict:
    """Three vertebrae on a nitinol rod under gravity, two tendons bending it by ~25° in two
    planes; effectors off the axis, on the axis and an axis (direction) effector."""
    data = {
        "name": "compliance robot",
        "solver": {"tolerance": 1e-13},
        "gravity": {"vector": [0.0, 0.0, -9.81]},
        "segment": [{"type": "beam", "count": 3, "length": LENGTH, "elements": 2, "youngs_modulus": E,
                     "poisson_ratio": NU, "section": {"shape": "circle", "radius": RADIUS},
                     "density": 6450.0, "vertebra": {"mass": 0.005}}],
        "cable": [{"name": "t1", "radius": 0.01, "angle_deg": 0.0, "from": 1, "to": 3, "tension": 15.0},
                  {"name": "t2", "radius": 0.01, "angle_deg": 90.0, "from": 1, "to": 2, "tension": 8.0}],
        "effector": [{"name": "tip", "vertebra": -1, "offset": [0.006, -0.003, 0.012]},
                     {"name": "mid", "vertebra": 2},
                     {"name": "tip_axis", "vertebra": -1, "axis": [0.0, 0.0, 1.0]}],
    }
    if moment is not None:   # a dead moment: the tangent is unsymmetric (banded LU)
        data["load"] = [{"vertebra": 2, "moment": moment}]
    return data


def _pose(model, state, k):
    """World point and rotation of effector k: its point, or an axis effector's frame origin."""
    frame = model.effector_frames[k]
    point = state.positions[frame] if model.effector_is_axis[k] else model.effector_positions(state)[k]
    q = state.quaternions[frame]
    return point, Rotation.from_quat([q[1], q[2], q[3], q[0]])


def finite_difference_compliance(scene, model, result, k, force_step, moment_step):
    """Central differences of forward solves with a small dead force or moment added at
    effector k's point (a force at the point = the force at the frame origin plus its constant
    moment about the origin: the moment arm's turning is second order in the step)."""
    vertebra = scene.effectors[k].vertebra
    point, _ = _pose(model, result.state, k)
    arm = point - result.state.positions[model.effector_frames[k]]
    C = np.zeros((6, 6))
    for column in range(6):
        steps = []
        for sign in (1.0, -1.0):
            unit = np.zeros(3)
            unit[column % 3] = sign * (force_step if column < 3 else moment_step)
            force, moment = (unit, np.cross(arm, unit)) if column < 3 else (np.zeros(3), unit)
            perturbed = dataclasses.replace(scene, loads=scene.loads + (LoadSpec(vertebra, tuple(force), tuple(moment)),))
            m = solver.build_model(perturbed)
            r = m.solve(result.actuation, initial=result.state)
            assert r.converged
            steps.append(_pose(m, r.state, k))
        (p_plus, R_plus), (p_minus, R_minus) = steps
        h = 2.0 * (force_step if column < 3 else moment_step)
        C[:3, column] = (p_plus - p_minus) / h
        C[3:, column] = (R_plus * R_minus.inv()).as_rotvec() / h
    return C


def _unit_consistent(C, length):
    """D C D with D = diag(1, 1, 1, L, L, L): every block in m/N, comparable entry by entry."""
    d = np.r_[np.ones(3), np.full(3, length)]
    return d[:, None] * C * d[None, :]


@pytest.mark.parametrize("moment", [None, [0.0, 0.02, 0.01]], ids=["conservative", "dead-moment"])
def test_compliance_matches_finite_differences_of_forward_solves(moment):
    # Steps of 1e-4 N and 1e-6 N m move the tip by ~1e-6 of the robot's length: central
    # differences then carry a truncation error ~(step/1 N)² ≈ 1e-8 and a solver/rounding error
    # ~1e-13 tolerance · deflection / step ≈ 1e-8 (measured: 3e-11 to 6e-11). 1e-6 relative is
    # the acceptance; the rest pose's tangent instead of the loaded one would be 8–15 % off.
    scene = solver.parse_scene(bent_robot(moment))
    model = solver.build_model(scene)
    result = model.solve()
    bend = Rotation.from_quat(np.roll(result.state.quaternions[-1], -1)).magnitude()
    assert bend > np.radians(15)                         # large deflection: the tangent is not the rest one
    compliance = effector_compliance(model, result.state, result.actuation)
    length = 3 * LENGTH
    for k, name in enumerate(model.effector_names):
        numeric = finite_difference_compliance(scene, model, result, k, 1e-4, 1e-6)
        exact, numeric = _unit_consistent(compliance[name], length), _unit_consistent(numeric, length)
        assert np.abs(exact - numeric).max() <= 1e-6 * np.abs(exact).max(), name
    symmetric = np.abs(compliance.full - compliance.full.transpose(0, 2, 1)).max() / np.abs(compliance.full).max()
    if moment is None:
        assert symmetric < 1e-12          # conservative loads: K symmetric, so is J K⁻¹ Jᵀ
    else:
        assert symmetric > 1e-8           # a dead moment's tangent is not symmetric


def test_translational_block_is_je_k_inverse_je_transpose():
    # the 3×3 block of a point effector is exactly Je K⁻¹ Jeᵀ with the linearisation's own Je
    model = solver.build_model(solver.parse_scene(bent_robot()))
    result = model.solve()
    lin = model.linearise(result.state, result.actuation)
    compliance = effector_compliance(model, result.state, result.actuation, linearisation=lin)
    Je = lin.effector_jacobian[:3]                                       # effector "tip"
    expected = Je @ lin.solve(Je.T)
    assert np.allclose(compliance.translational[0], expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())


@pytest.mark.parametrize("elements", [1, 4])
def test_unloaded_cantilever_tip_compliance_is_timoshenko(elements):
    # at the stress-free straight pose the chain of Timoshenko links is exact for a linear beam:
    # the tip's 6×6 compliance is the closed-form cantilever compliance of the whole length
    # (to rounding: relative 1e-10 covers the banded solve's conditioning, ~1e8 here)
    length, elements_total = 0.2, elements
    data = {"segment": [{"type": "beam", "count": 2, "length": length / 2, "elements": elements_total,
                         "youngs_modulus": E, "poisson_ratio": NU,
                         "section": {"shape": "circle", "radius": RADIUS}}],
            "effector": [{"name": "tip", "vertebra": -1}, {"name": "base", "vertebra": 0}]}
    model = solver.build_model(solver.parse_scene(data))
    compliance = effector_compliance(model, model.rest_state, None)
    expected = timoshenko_compliance(length, E, E / (2 * (1 + NU)), Section.circle(RADIUS, NU))
    scaled = _unit_consistent(compliance["tip"], length)
    assert np.abs(scaled - _unit_consistent(expected, length)).max() <= 1e-10 * np.abs(scaled).max()
    assert not compliance["base"].any()                 # the clamped base does not move


def test_simulate_json_reports_each_effector_compliance(tmp_path, capsys):
    from vertebra.cli.main import main
    from vertebra.solver.scene import scene_toml

    path = tmp_path / "robot.toml"
    path.write_text(scene_toml(bent_robot()))
    assert main(["simulate", str(path), "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    model = solver.build_model(solver.load_scene(path))
    result = model.solve()
    expected = effector_compliance(model, result.state, result.actuation)
    for name, entry in document["effectors"].items():
        full = np.array(entry["compliance"]["full"])
        assert full.shape == (6, 6) and np.array(entry["compliance"]["translational"]).shape == (3, 3)
        assert np.allclose(full, expected[name], rtol=1e-9, atol=0)
        assert np.array_equal(np.array(entry["compliance"]["translational"]), full[:3, :3])
