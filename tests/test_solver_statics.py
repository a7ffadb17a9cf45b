"""Forward statics against closed forms and independent references (issue 2, item 10)."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.analytic import arc_tip, cantilever_deflection_uniform_load, elastica_tip
from vertebra.solver.timoshenko import Section, timoshenko_compliance
from vertebra.core.lie import qlog
from vertebra.core.errors import ConvergenceError

E, NU, RADIUS, LENGTH = 200e9, 0.3, 1e-3, 0.5
EI = E * math.pi * RADIUS ** 4 / 4


def rod(elements=20, count=1, *, length=LENGTH, youngs=E, radius=RADIUS, loads=(), extra=None):
    data = {"segment": [{"type": "beam", "count": count, "elements": elements, "length": length / count,
                         "youngs_modulus": youngs, "poisson_ratio": NU,
                         "section": {"shape": "circle", "radius": radius}}],
            "load": [{"vertebra": -1, "force": list(f), "moment": list(m)} for f, m in loads]}
    data.update(extra or {})
    return solver.build_model(solver.parse_scene(data))


def tip_displacement(model, state):
    x = state.positions[-1] - model.rest_state.positions[-1]
    return np.concatenate([x, qlog(state.quaternions[-1])])


@pytest.mark.parametrize("direction", range(6))
def test_linear_response_equals_timoshenko_in_all_six_directions(direction):
    # K⁻¹ f of the assembled chain at rest is the linear response; a chain of links whose
    # compliances are exact cantilever compliances reproduces the whole-beam Timoshenko
    # compliance exactly (to rounding: 1e-9 relative covers the condition number ~1e6)
    model = rod(elements=7)
    G = E / (2 * (1 + NU))
    C = timoshenko_compliance(LENGTH, E, G, Section.circle(RADIUS, NU))
    lin = model.linearise(model.rest_state, model.default_actuation)
    load = np.zeros(model.n_dof)
    load[-6 + direction] = 1.0
    response = lin.solve(load)[-6:]
    assert np.allclose(response, C[:, direction], rtol=1e-9, atol=1e-9 * np.abs(C[:, direction]).max())


def test_small_load_newton_matches_linear_theory():
    # a tip force giving PL²/EI = 1e-4: geometric nonlinearity is O(1e-8) of the deflection
    P = 1e-4 * EI / LENGTH ** 2
    model = rod(loads=[((P, 0, 0), (0, 0, 0))])
    result = model.solve()
    expected = timoshenko_compliance(LENGTH, E, E / (2 * (1 + NU)), Section.circle(RADIUS, NU))[:, 0] * P
    assert result.converged
    # the axial shortening (deflection²/L ~ 5e-10 m) is second order: compare it at 1e-4 of the deflection
    assert np.allclose(tip_displacement(model, result.state), expected, rtol=1e-6, atol=1e-4 * abs(expected[0]))


@pytest.mark.parametrize("load_parameter", [0.5, 1.0, 5.0, 10.0])
def test_large_deflection_cantilever_against_elastica(load_parameter):
    # acceptance: 20 links within 0.1 % of the length (the inextensible elastica differs from the
    # extensible, shearable beam by ~1e-5 L here, far below the tolerance)
    P = load_parameter * EI / LENGTH ** 2
    model = rod(elements=20, loads=[((P, 0, 0), (0, 0, 0))])
    result = model.solve()
    tip = result.state.positions[-1]
    reference = elastica_tip(load_parameter, LENGTH)
    error = np.hypot(tip[0] - reference[0], tip[2] - reference[1]) / LENGTH
    assert result.converged and error <= 1e-3
    assert abs(tip[1]) < 1e-12


@pytest.mark.parametrize("load_parameter", [1.0, 10.0])
def test_hundred_links_within_one_hundredth_of_a_percent(load_parameter):
    P = load_parameter * EI / LENGTH ** 2
    model = rod(elements=100, loads=[((P, 0, 0), (0, 0, 0))])
    tip = model.solve().state.positions[-1]
    reference = elastica_tip(load_parameter, LENGTH)
    assert np.hypot(tip[0] - reference[0], tip[2] - reference[1]) / LENGTH <= 1e-4


def test_error_falls_at_fourth_order_with_links():
    # constant-strain links: error vs a fine discretisation of the same model falls as h⁴
    # (FIELD-NOTES measured order 4); halving h must cut it by at least 10 (16 in theory)
    P = 5.0 * EI / LENGTH ** 2
    tips = {n: rod(elements=n, loads=[((P, 0, 0), (0, 0, 0))]).solve().state.positions[-1] for n in (4, 8, 16, 64)}
    errors = [np.linalg.norm(tips[n] - tips[64]) for n in (4, 8, 16)]
    assert errors[0] / errors[1] > 10 and errors[1] / errors[2] > 10


@pytest.mark.parametrize("turns", [0.25, 0.5, 1.0, 1.25])
def test_pure_end_moment_gives_a_circular_arc_including_a_full_coil(turns):
    # constant curvature is exact for constant-strain links; the full coil closes to the base
    angle = 2 * math.pi * turns
    M = angle * EI / LENGTH
    model = rod(elements=40, loads=[((0, 0, 0), (0, M, 0))])
    result = model.solve()
    tip = result.state.positions[-1]
    reference = arc_tip(angle, LENGTH)
    assert result.converged
    assert np.hypot(tip[0] - reference[0], tip[2] - reference[1]) <= 1e-6 * LENGTH
    if turns == 1.0:
        assert np.linalg.norm(tip) <= 1e-6 * LENGTH


def test_objectivity_moving_the_base_moves_the_solution_rigidly():
    # same robot with a rotated and translated base, loads and gravity rotated with it
    from vertebra.core.lie import qexp, qmatrix
    q = qexp(np.array([0.3, -1.1, 0.7]))
    R = qmatrix(q)
    offset = np.array([0.2, -0.4, 1.3])
    force, moment, gravity = np.array([0.4, 0.1, -0.2]), np.array([0.0, 0.02, 0.01]), np.array([0, 0, -9.81])

    def build(base_q, base_x, rot):
        data = {"segment": [{"type": "beam", "count": 4, "elements": 3, "length": 0.1, "youngs_modulus": E,
                             "poisson_ratio": NU, "section": {"shape": "circle", "radius": RADIUS},
                             "density": 7800.0, "vertebra": {"mass": 0.01, "center_of_mass": [0.003, 0, 0]}}],
                "base": {"position": list(base_x), "quaternion": list(base_q)},
                "gravity": {"vector": list(rot @ gravity)},
                "load": [{"vertebra": -1, "force": list(rot @ force), "moment": list(rot @ moment)}],
                "cable": [{"name": "c", "radius": 0.01, "angle_deg": 30.0, "from": 1, "to": 4, "tension": 2.0}]}
        return solver.build_model(solver.parse_scene(data))

    a = build([1.0, 0, 0, 0], [0, 0, 0], np.eye(3)).solve().state
    b = build(q, offset, R).solve().state
    expected = a.positions @ R.T + offset
    assert np.abs(b.positions - expected).max() < 1e-9 * np.abs(a.positions).max()


def test_unit_scaling_invariance_millimetres_and_metres():
    # mm–N–MPa is a consistent unit system: positions scale by 1000 exactly, iterations equal
    P = 2.0 * EI / LENGTH ** 2
    metres = rod(elements=10, loads=[((P, 0, 0), (0, 0, 0.01))]).solve()
    millimetres = rod(elements=10, length=LENGTH * 1e3, youngs=E * 1e-6, radius=RADIUS * 1e3,
                      loads=[((P, 0, 0), (0, 0, 10.0))]).solve()
    assert metres.iterations == millimetres.iterations
    assert np.abs(millimetres.state.positions - 1e3 * metres.state.positions).max() < 1e-9 * 1e3 * LENGTH


def test_tendon_bends_a_uniform_rod_to_curvature_tau_r_over_EI():
    # a tendon at radius r with tension τ through 40 vertebrae ≈ an end moment τr (the cable
    # chords cut the arc: error O(spacing²), ~0.1 % here; the axial compression τL/EA is 1e-6)
    tau, r = 0.5, 0.01
    data = {"segment": [{"type": "beam", "count": 40, "elements": 1, "length": LENGTH / 40, "youngs_modulus": E,
                         "poisson_ratio": NU, "section": {"shape": "circle", "radius": RADIUS}}],
            "cable": [{"name": "t", "radius": r, "angle_deg": 0.0, "from": 1, "to": 40, "tension": tau}]}
    model = solver.build_model(solver.parse_scene(data))
    state = model.solve().state
    tip_angle = np.linalg.norm(qlog(state.quaternions[-1]))
    curvature = tip_angle / LENGTH
    assert abs(curvature - tau * r / EI) / (tau * r / EI) < 5e-3
    # the cable's stroke equals −r·(tip angle) to first order in the spacing
    stroke = model.actuator_displacements(state)[0]
    assert abs(stroke + r * tip_angle) < 5e-3 * r * tip_angle


def test_gravity_acts_at_the_centres_of_mass():
    # a massless rod carrying one vertebra whose centre of mass sits c above the tip frame, with
    # gravity across the rod: the tip sees a force m g and a moment (c e_z) × (m g); the load is
    # lateral (no P-δ) and PL²/EI ~ 1e-3, so the linear response holds to ~1e-6
    m, c = 0.05, 0.02
    data = {"segment": [{"type": "beam", "count": 1, "elements": 4, "length": LENGTH, "youngs_modulus": E,
                         "poisson_ratio": NU, "section": {"shape": "circle", "radius": 5e-3},
                         "vertebra": {"mass": m, "center_of_mass": [0.0, 0.0, c]}}],
            "gravity": {"vector": [-9.81, 0.0, 0.0]}}
    model = solver.build_model(solver.parse_scene(data))
    result = model.solve()
    C = timoshenko_compliance(LENGTH, E, E / (2 * (1 + NU)), Section.circle(5e-3, NU))
    wrench = np.array([-m * 9.81, 0, 0, 0, -m * 9.81 * c, 0])   # (c e_z) × (−mg e_x) = −mgc e_y
    response = tip_displacement(model, result.state)
    # atol: the axial shortening (deflection²/L ≈ 6e-8 m) is second order
    assert np.allclose(response, C @ wrench, rtol=1e-5, atol=1e-4 * np.abs(C @ wrench).max())


def test_distributed_weight_converges_to_qL4_over_8EI():
    # lumped link masses: O(h²) discretisation error, 1 % at 40 links; shear adds ~1e-4
    rho = 7800.0
    data = {"segment": [{"type": "beam", "count": 1, "elements": 40, "length": LENGTH, "youngs_modulus": E,
                         "poisson_ratio": NU, "section": {"shape": "circle", "radius": 5e-3}, "density": rho}],
            "gravity": {"vector": [-9.81, 0.0, 0.0]}}
    model = solver.build_model(solver.parse_scene(data))
    deflection = -model.solve().state.positions[-1, 0]
    q = rho * math.pi * 5e-3 ** 2 * 9.81
    expected = cantilever_deflection_uniform_load(q, LENGTH, E * math.pi * 5e-3 ** 4 / 4)
    assert abs(deflection - expected) / expected < 1e-2


def test_zero_load_is_the_rest_pose_without_iterations():
    model = rod()
    result = model.solve()
    assert result.converged and result.iterations == 0
    assert np.array_equal(result.state.positions, model.rest_state.positions)


def test_warm_start_converges_faster_and_to_the_same_state():
    P = 2.0 * EI / LENGTH ** 2
    model = rod(loads=[((P, 0, 0), (0, 0, 0))])
    cold = model.solve()
    warm = model.solve(initial=cold.state)
    assert warm.iterations <= 1
    assert np.abs(warm.state.positions - cold.state.positions).max() < 1e-12


@pytest.mark.parametrize("load_parameter", [1.0, 5.0])
def test_newton_with_consistent_tangent_needs_few_iterations(load_parameter):
    # from the straight rod in one load step; a wrong tangent (even a symmetric Gauss–Newton
    # approximation) needs dozens of iterations or load steps here
    P = load_parameter * EI / LENGTH ** 2
    result = rod(loads=[((P, 0, 0), (0, 0, 0))]).solve()
    assert result.converged and result.iterations <= 8 and result.load_steps == 1


def test_non_convergence_raises_with_the_partial_result():
    P = 10.0 * EI / LENGTH ** 2
    model = rod(loads=[((P, 0, 0), (0, 0, 0))])
    with pytest.raises(ConvergenceError) as info:
        model.solve(max_iterations=1, load_steps=1)
    assert info.value.result is not None and not info.value.result.converged
    assert np.all(np.isfinite(info.value.result.state.positions))
