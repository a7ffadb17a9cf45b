"""Stroke-driven tendons: a servo stroke instead of a tension, a spring rate, a pretension, slack.

A tendon's tension is ``k·max(0, e)`` with ``e = L(q) − L₀ + s + T₀/k``; its potential
``½ k max(0, e)²`` adds ``k ∂L/∂q ∂L/∂qᵀ`` to the tangent, a dense rank-one term per taut tendon
held beside the band and factored by Sherman–Morrison–Woodbury.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.core.errors import SceneError
from vertebra.solver.potential import cable_tensions, tangent
from vertebra.solver.gallery import load

E, NU, R_ROD, LINK = 54e9, 0.3, 0.0007, 0.02
EA = E * math.pi * R_ROD ** 2


def rod(count=10, elements=2):
    return {"type": "beam", "count": count, "length": LINK, "elements": elements, "youngs_modulus": E,
            "poisson_ratio": NU, "section": {"shape": "circle", "radius": R_ROD}}


def build(cables, loads=()):
    return solver.build_model(solver.parse_scene({"segment": [rod()], "cable": list(cables), "load": list(loads),
                                                   "effector": [{"name": "tip", "vertebra": -1}]}))


def tendon(name, angle, stroke, stiffness=2000.0, pretension=0.5, to=10, radius=0.01):
    return {"name": name, "radius": radius, "angle_deg": angle, "to": to, "stroke": stroke,
            "stiffness": stiffness, "pretension": pretension}


def dense_tangent(model, ev):
    matrix = tangent(model.trunk, ev)
    band = matrix.symmetric_band()
    n = band.shape[1]
    dense = np.zeros((n, n))
    for d in range(band.shape[0]):
        j = np.arange(n - d)
        dense[j + d, j] = band[d, :n - d]
        dense[j, j + d] = band[d, :n - d]
    if matrix.low_rank is not None:
        U, k = matrix.low_rank
        dense += (U * k) @ U.T
    return matrix, dense


def test_a_tendon_on_the_axis_shares_its_pretension_with_the_backbone_in_closed_form():
    # A tendon along the axis, pretensioned by T0 at zero stroke, shortens the backbone by
    # T·L/EA; the tendon's elongation then falls by the same amount: T = k (T0/k − T L/EA),
    # T = T0 / (1 + k L/EA). The links are Timoshenko beams: their axial compliance is L/EA exactly.
    k, T0 = 5.0e4, 3.0
    model = build([tendon("axial", 0.0, 0.0, stiffness=k, pretension=T0, radius=0.0)])
    result = model.solve()
    assert result.converged
    L = 10 * LINK
    expected = T0 / (1.0 + k * L / EA)
    assert model.cable_tensions(result.state)[0] == pytest.approx(expected, rel=1e-9)
    # the tip moved down by T L / EA, the same shortening
    assert result.state.positions[-1, 2] == pytest.approx(L - expected * L / EA, rel=1e-12)


def test_a_stroke_driven_equilibrium_is_the_tension_driven_one_at_its_tensions():
    # Driving by stroke changes the input, not the mechanics: the tensions a stroke-driven solve
    # finds, given as tensions, give the same equilibrium (to the solver's tolerance).
    cables = [tendon("a", 0.0, 0.003), tendon("b", 120.0, 0.001, stiffness=800.0, pretension=0.2),
              {"name": "c", "radius": 0.01, "angle_deg": 240.0, "to": 6, "tension": 0.7}]
    model = build(cables)
    result = model.solve()
    tensions = model.cable_tensions(result.state)
    assert tensions[2] == 0.7 and (tensions[:2] > 0).all()
    as_tensions = build([{k: v for k, v in c.items() if k not in ("stroke", "stiffness", "pretension")}
                         | {"tension": float(t)} for c, t in zip(cables, tensions)])
    other = as_tensions.solve()
    assert np.abs(other.state.positions - result.state.positions).max() <= 1e-9 * model.length_scale


def test_a_slack_tendon_carries_nothing_and_changes_nothing():
    # Released beyond its pretension (stroke < −T0/k minus the path's shortening) a tendon is
    # slack: zero tension, and the equilibrium is that of the robot without it.
    pulled = tendon("a", 0.0, 0.004)
    released = tendon("b", 180.0, -0.01)
    model = build([pulled, released])
    result = model.solve()
    tensions = model.cable_tensions(result.state)
    assert tensions[1] == 0.0 and tensions[0] > 1.0
    alone = build([pulled]).solve()
    assert np.abs(alone.state.positions - result.state.positions).max() <= 1e-9 * model.length_scale


def test_a_negative_pretension_is_a_slack_at_zero_stroke():
    # P < 0 leaves the tendon −P/k too long at zero stroke: the same law as a stroke shortened by it.
    k, P = 2000.0, -0.6
    slack = build([tendon("a", 0.0, 0.003, stiffness=k, pretension=P), tendon("b", 180.0, 0.0)]).solve()
    shifted = build([tendon("a", 0.0, 0.003 + P / k, stiffness=k, pretension=0.0), tendon("b", 180.0, 0.0)]).solve()
    assert np.abs(slack.state.positions - shifted.state.positions).max() <= 1e-12


def test_the_tendons_tangent_is_the_derivative_of_the_gradient_and_its_factor_solves_it():
    model = build([tendon("a", 0.0, 0.004), tendon("b", 180.0, 0.0), tendon("c", 90.0, 0.002, to=5),
                   tendon("d", 270.0, -0.01)], loads=[{"vertebra": -1, "force": [0.0, -0.3, 0.0]}])
    result = model.solve()
    ev = model.evaluate(result.state)
    assert ev.parts.elongation[3] < 0 < ev.parts.elongation[:3].min()       # three taut, one slack
    matrix, dense = dense_tangent(model, ev)
    assert matrix.low_rank[0].shape[1] == 3
    rng = np.random.default_rng(1)
    scale = np.abs(dense).max()
    for _ in range(3):
        v = rng.normal(size=model.n_dof) * np.tile([1.0, 1.0, 1.0, 10.0, 10.0, 10.0], model.n_frames - 1)
        h = 1e-6 * model.length_scale / np.abs(v).max()
        plus = model.evaluate(model.step(result.state, h * v)).gradient[1:].reshape(-1)
        minus = model.evaluate(model.step(result.state, -h * v)).gradient[1:].reshape(-1)
        fd = (plus - minus) / (2.0 * h)
        # central differences: error ~ h² K''' and rounding ~ eps |g| / h
        assert np.abs(fd - dense @ v).max() <= 1e-6 * scale * np.abs(v).max()
    factor, _ = matrix.factor()
    rhs = rng.normal(size=model.n_dof)
    x = factor.solve(rhs)
    # backward stable as a dense LAPACK solve: the residual is rounding of |K| |x|
    assert np.abs(dense @ x - rhs).max() <= 1e-14 * (np.abs(dense) @ np.abs(x)).max()


def test_pulling_and_releasing_through_the_slack_point_converges_quadratically():
    # From taut to slack and back: every solve converges, warm-started from the previous one.
    model = build([tendon("a", 0.0, 0.0), tendon("b", 180.0, 0.0)])
    state = None
    for stroke in np.r_[np.linspace(0.0, 0.006, 7), np.linspace(0.006, -0.004, 11), np.linspace(-0.004, 0.002, 7)]:
        result = model.solve({"a": stroke, "b": -0.5 * stroke}, initial=state)
        assert result.converged and result.residual <= model.scene.solver.tolerance
        state = result.state
        tensions = model.cable_tensions(state, {"a": stroke, "b": -0.5 * stroke})
        assert (tensions >= 0).all()


def test_random_stroke_commands_of_the_16_tendon_robot_converge():
    # The paper's 16-tendon robot with every cable a tendon of spring rate ~ EA/L of a 0.3 mm
    # steel wire: random servo strokes (slack and taut mixed) all converge from rest.
    scene = load("paper_5v_16t")
    model = solver.build_model(_with_tendons(scene))
    # (benchmarks/ runs 200 such commands, and commands up to 200 N per tendon)
    rng = np.random.default_rng(7)
    slack = taut = 0
    for _ in range(20):
        strokes = rng.uniform(-0.0005, 0.0005, model.n_cables)       # tensions 0 … ~25 N
        result = model.solve(strokes, raise_on_failure=False)
        assert result.converged and result.iterations <= 10, result.message
        tensions = model.cable_tensions(result.state, strokes)
        assert (tensions >= 0).all()
        slack, taut = slack + int((tensions == 0).sum()), taut + int((tensions > 0).sum())
    assert slack > 20 and taut > 20


def test_a_band_that_is_not_definite_is_factored_with_its_tendons_when_the_whole_is():
    # A band with negative eigenvalues plus a positive semi-definite dense term: the whole is
    # positive definite or not, and the factor says which (Haynsworth inertia), solving exactly.
    from vertebra.solver.banded import LowRankFactor

    rng = np.random.default_rng(3)
    n, kd = 40, 5
    U = 0.1 * rng.normal(size=(n, 3))
    U[0, 0] += 1.0                   # the dense term reaches the band's negative directions e₀, e₁
    U[1, 1] += 1.0
    d = np.array([50.0, 80.0, 120.0])
    for dip, definite in ((-0.5, True), (-200.0, False)):
        A = np.diag(np.full(n, 4.0))
        for k in range(1, kd + 1):
            v = 0.3 * rng.normal(size=n - k)
            A += np.diag(v, -k) + np.diag(v, k)
        A[0, 0] = A[1, 1] = dip
        lower = np.zeros((kd + 1, n))
        for k in range(kd + 1):
            lower[k, :n - k] = np.diagonal(A, -k)
        whole = A + (U * d) @ U.T
        assert np.linalg.eigvalsh(A).min() < 0
        assert (np.linalg.eigvalsh(whole).min() > 0) == definite
        factor = LowRankFactor.definite(lower, U, d)
        assert (factor is not None) == definite
        if factor is not None:
            rhs = rng.normal(size=n)
            assert np.abs(whole @ factor.solve(rhs) - rhs).max() <= 1e-12


def _with_tendons(scene):
    import dataclasses
    wire = 200e9 * math.pi * 0.00015 ** 2
    cables = tuple(dataclasses.replace(c, stroke=0.0, axial_stiffness=wire, free_length=0.2, pretension=0.5,
                                       min_tension=0.0, max_tension=math.inf, max_tension_change=None)
                   for c in scene.cables)
    return dataclasses.replace(scene, cables=cables)


@pytest.mark.parametrize("fields, message", [
    ({"stroke": 0.001}, "needs exactly one of `stiffness`"),
    ({"stroke": 0.001, "stiffness": 10.0, "axial_stiffness": 1e4}, "needs exactly one of `stiffness`"),
    ({"stroke": 0.001, "tension": 1.0, "stiffness": 10.0}, "either by a `tension` or by a `stroke`"),
    ({"tension": 1.0, "stiffness": 10.0}, "applies to a stroke-driven cable only"),
    ({"stroke": 0.001, "stiffness": 10.0, "free_length": 0.1}, "has no meaning"),
    ({"stroke": 0.001, "stiffness": -10.0}, "stiffness"),
])
def test_stroke_driven_cable_fields_are_checked(fields, message):
    cable = {"name": "a", "radius": 0.01, "to": 10} | fields
    with pytest.raises(SceneError, match=message):
        solver.parse_scene({"segment": [rod()], "cable": [cable]})
