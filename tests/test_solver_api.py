"""The Python API as a user meets it: readable reprs, actuation by name, the errors exported with
the solver, poses as 4×4 transforms."""

from __future__ import annotations

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver import gallery
from vertebra.core.lie import qrotate
from vertebra.core import errors


@pytest.fixture(scope="module")
def tendon():
    return solver.build_model(gallery.load("tendon_two_section"))


def test_model_repr_is_one_line_with_its_parts(tendon):
    text = repr(tendon)
    assert "\n" not in text
    assert text == ("<TrunkModel 'tendon_two_section': 41 frames (21 vertebrae), 40 links (beam 40), "
                    "6 cables, 0 chambers, 2 effectors (mid, tip)>")
    assert tendon.scene.name == "tendon_two_section"        # not the last cable's name


def test_static_result_repr_summarises(tendon):
    result = tendon.solve({"s1-0": 2.0})
    text = repr(result)
    assert text.startswith(f"StaticResult(converged=True, iterations={result.iterations}, residual=")
    tip = result.state.positions[-1]
    assert f"tip=[{tip[0]:.6g}, {tip[1]:.6g}, {tip[2]:.6g}] m)" in text
    assert len(text) < 200 and "array" not in text and "array" not in repr(result.state)


def test_actuation_by_name_equals_the_full_vector(tendon):
    by_name = tendon.solve(actuation={"s1-120": 4.0, "s2-60": 2.0})
    vector = tendon.default_actuation.copy()
    vector[tendon.actuator_names.index("s1-120")] = 4.0
    vector[tendon.actuator_names.index("s2-60")] = 2.0
    full = tendon.solve(vector)
    # the same inputs give the same Newton path: bit-identical poses
    assert np.array_equal(by_name.actuation, full.actuation)
    assert np.array_equal(by_name.state.positions, full.state.positions)
    # names not given keep the scene's values
    assert np.array_equal(tendon.actuation({}), tendon.default_actuation)


def test_unknown_actuator_names_and_wrong_counts_are_option_errors(tendon):
    with pytest.raises(solver.OptionError) as caught:
        tendon.solve(actuation={"t1": 5.0, "s1-0": 1.0, "t9": 2.0})
    assert caught.value.field == "actuation" and "'t1', 't9'" in caught.value.reason
    assert "s1-0, s1-120" in caught.value.reason          # the names the model has
    with pytest.raises(solver.InputError, match="3 values for 6 actuators"):
        tendon.solve([1.0, 2.0, 3.0])


def test_errors_are_exported_from_the_solver():
    for name in ("VertebraError", "InputError", "SceneError", "SpecError", "TrajectoryError", "OptionError",
                 "CatalogueError", "ConvergenceError"):
        assert getattr(solver, name) is getattr(errors, name)
        assert name in solver.__all__
    with pytest.raises(solver.ConvergenceError) as caught:
        model = solver.build_model(solver.parse_scene({
            "solver": {"max_iterations": 1},
            "segment": [{"type": "beam", "length": 0.5, "elements": 10, "youngs_modulus": 2e11,
                         "section": {"shape": "circle", "radius": 0.001}}],
            "load": [{"vertebra": -1, "force": [100.0, 0.0, 0.0]}]}))
        model.solve()
    assert not caught.value.result.converged


def test_pose_matrices_map_frame_points_to_the_world(tendon):
    state = tendon.solve({"s1-0": 3.0, "s2-180": 1.0}).state
    T = state.transforms()
    assert T.shape == (tendon.n_frames, 4, 4)
    assert np.array_equal(T[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (tendon.n_frames, 4)))
    # a point given in each frame lands where the quaternion rotation puts it (same arithmetic
    # up to rounding: 1e-15 m on positions of 0.4 m)
    rng = np.random.default_rng(3)
    local = rng.normal(size=(tendon.n_frames, 3)) * 0.01
    world = (T @ np.c_[local, np.ones(tendon.n_frames)][..., None])[:, :3, 0]
    expected = state.positions + qrotate(state.quaternions, local)
    assert np.max(np.abs(world - expected)) < 1e-15
    # rotation blocks are orthonormal with determinant +1
    R = T[:, :3, :3]
    assert np.max(np.abs(R @ R.transpose(0, 2, 1) - np.eye(3))) < 1e-14
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-14)
    assert np.array_equal(solver.pose_matrix(state.positions[5], state.quaternions[5]), T[5])
