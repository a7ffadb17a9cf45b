"""Robustness on robots the gallery does not contain (seeded generators in ``tests/robots.py``),
on the polymer 16-tendon robot in tick and converged mode, and on states the links cannot
represent. The larger run is ``benchmarks/bench_robustness.py`` (docs/robustness.md)."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest
import robots

from vertebra import solver
from vertebra.solver.gallery import load
from vertebra.solver.gallery.targets import circle
from vertebra.solver.inverse import InverseController, InverseSettings
from vertebra.solver.inverse.trust import LARGEST, ROTATION, TRANSLATION
from vertebra.solver.newton import is_stable
from vertebra.core.errors import ConvergenceError

JUMP = np.array([[0.04, 0.02, 0.13]])      # 4.9 cm from the polymer robot's rest tip


def build(scene: dict):
    return solver.build_model(solver.parse_scene(scene))


def polymer(gravity: bool):
    scene = load("polymer_5v_16t")
    if not gravity:
        import dataclasses
        scene = dataclasses.replace(scene, gravity=None)
    return solver.build_model(scene)


# ---------------------------------------------------------------------------- forward

@pytest.mark.parametrize("seed", range(20))
def test_a_representable_random_robot_converges_to_a_stable_equilibrium(seed):
    # Every draw the independent check accepts (tests/robots.py: the refined robot solved by
    # continuation turns no link beyond 60°, the robot at most 1.5 turns, keeps cable pieces
    # at ≥ 25 %) must converge from rest in one load step to the scene's tolerance, to an
    # equilibrium whose tangent is positive definite.
    scene, check, _ = robots.draw_representable(np.random.default_rng(seed))
    model = build(scene)
    result = model.solve()
    assert result.converged, result.message
    lin = model.linearise(result.state, result.actuation)
    assert model.residual_norm(lin.residual, result.actuation) <= model.scene.solver.tolerance or \
        result.rounding_limited
    assert is_stable(model.trunk, model.evaluate(result.state))
    assert np.isfinite(result.state.positions).all()


def test_a_link_turning_towards_pi_is_reported_with_the_links_it_needs():
    # One full turn of a 2-link cantilever (pure end moment: each link would turn 180°) cannot be
    # represented: the solve says so, and how many links would (a turn at ≤ 60° per link: 6),
    # within a few dozen iterations instead of exhausting its budget; with 6 links it converges.
    def coil(elements):
        EI = 200e9 * math.pi * 1e-12 / 4
        return build({"segment": [{"type": "beam", "elements": elements, "length": 0.5, "youngs_modulus": 200e9,
                                   "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 1e-3}}],
                      "load": [{"vertebra": -1, "moment": [0.0, 2 * math.pi * EI / 0.5, 0.0]}]})
    with pytest.raises(ConvergenceError, match="at least 6 links per repetition") as info:
        coil(2).solve()
    assert info.value.result.iterations <= 50 and np.isfinite(info.value.result.state.positions).all()
    assert coil(6).solve().converged


def test_cable_pieces_whose_holes_meet_are_reported():
    # Tendons at 18 mm on vertebrae 5 mm apart pulling hard enough to bend each gap by ~2 rad:
    # the holes of consecutive vertebrae would meet (their discs collide) — not representable.
    # No step shortens a piece by more than half (measured: the holes meet after 133
    # iterations over 4 load stages), far within the budget of 1000.
    EI = 1e6 * math.pi * (5e-4) ** 4 / 4
    scene = {"segment": [{"type": "beam", "count": 4, "length": 0.005, "elements": 2, "youngs_modulus": 1e6,
                          "poisson_ratio": 0.4, "section": {"shape": "circle", "radius": 5e-4}}],
             "cable": [{"name": "t", "radius": 0.018, "from": 1, "to": 4, "tension": 2.0 / 0.005 * EI / 0.018}]}
    with pytest.raises(ConvergenceError, match="holes of the two vertebrae meet") as info:
        build(scene).solve()
    assert info.value.result.iterations <= 300


@pytest.mark.parametrize("case", ["initial", "actuation", "step", "linearise"])
def test_non_finite_values_are_convergence_errors_naming_the_stage(case):
    model = build({"segment": [{"type": "beam", "count": 3, "elements": 2, "length": 0.03, "youngs_modulus": 2e9,
                                "poisson_ratio": 0.35, "section": {"shape": "circle", "radius": 1e-3}}],
                   "cable": [{"name": "t", "radius": 0.01, "from": 1, "to": 3, "max_tension": 5.0}]})
    broken = model.rest_state.copy()
    broken.positions[2, 0] = np.nan
    calls = {"initial": (lambda: model.solve(initial=broken), "initial state"),
             "actuation": (lambda: model.solve([np.nan]), "actuation"),
             "step": (lambda: model.step(model.rest_state, np.full(model.n_dof, 1e300)), "retraction"),
             "linearise": (lambda: model.linearise(broken), "not finite")}
    call, stage = calls[case]
    with pytest.raises(ConvergenceError, match=stage), np.errstate(over="ignore"):
        call()


# ---------------------------------------------------------------------------- the polymer robot

def _tracks(controller, trajectory, settle_after=10, tolerance=1e-3):
    """Tick along ``trajectory``: every step settled to an equilibrium, the actuation inside its
    bounds and per-tick changes, each tick moving frames by at most the largest trust radii;
    after ``settle_after`` ticks every settled effector within ``tolerance`` (m)."""
    model = controller.model
    lower, upper = model.actuator_bounds
    change = model.actuator_max_change
    largest_move = LARGEST * TRANSLATION * model.length_scale
    for i, target in enumerate(trajectory):
        before, previous = controller.state, controller.actuation
        step = controller.step(target)
        moved = (step.state.positions - before.positions)
        assert np.linalg.norm(moved, axis=1).max() <= largest_move * (1 + 1e-9)
        assert np.all(step.actuation >= lower) and np.all(step.actuation <= upper)
        assert np.all(np.abs(step.actuation - previous) <= change * (1 + 1e-12))
        settled = controller.settled(step)
        assert settled.equilibrium, settled.equilibrium_failure
        if i >= settle_after:
            assert settled.errors.max() <= tolerance, (i, settled.errors)


@pytest.mark.parametrize("gravity", [True, False])
def test_polymer_robot_follows_a_3cm_circle_in_tick_mode(gravity):
    # The 3 cm circle at z = 0.14 m starts 3.2 cm from the rest tip: bounded ticks close the gap
    # (measured: 0.6 mm after 3 ticks, 0.05 mm from the 4th on) and then lag the moving target
    # by ~0.05 mm; 1 mm after 10 ticks is the acceptance bound.
    model = polymer(gravity)
    _tracks(InverseController(model, InverseSettings(mode="tick")), circle([0.0, 0.0, 0.14], 0.03, 60)[:, None])


@pytest.mark.parametrize("gravity", [True, False])
def test_polymer_robot_jumps_4_9cm_in_tick_mode(gravity):
    model = polymer(gravity)
    _tracks(InverseController(model, InverseSettings(mode="tick")), np.repeat(JUMP[None], 20, axis=0))


@pytest.mark.parametrize("gravity", [True, False])
def test_polymer_robot_converged_inverse_reaches_the_jump_and_the_circle(gravity):
    # Converged mode: the 4.9 cm jump from rest and every 6th point of the circle in order,
    # each within the 1e-6 m tolerance, in far fewer outer iterations than the budget.
    model = polymer(gravity)
    controller = InverseController(model, InverseSettings(mode="converged"))
    step = controller.step(JUMP)
    assert step.reached and step.equilibrium and step.iterations <= 20, (step.status, step.errors)
    controller = InverseController(model, InverseSettings(mode="converged"))
    for target in circle([0.0, 0.0, 0.14], 0.03, 60)[::6]:
        step = controller.step(target[None])
        assert step.reached and step.errors.max() <= 1e-6, (step.status, step.errors)


def test_the_time_budget_ends_a_converged_inverse_with_the_closest_reach():
    model = polymer(True)
    step = InverseController(model, InverseSettings(mode="converged", time_budget=1e-9)).step(JUMP)
    assert step.status == "budget" and not step.reached and step.equilibrium


def test_a_tick_that_its_prediction_fails_is_not_applied(monkeypatch):
    # A potential that jumps by 1 MJ wherever a step goes makes each prediction fail: the tick
    # is cut back twice and then not applied (state and actuation unchanged), and the region
    # shrinks.
    model = polymer(True)
    controller = InverseController(model, InverseSettings(mode="tick"))
    state, actuation, scale = controller.state, controller.actuation.copy(), controller.trust.scale
    jump = types.SimpleNamespace(energy=1e6)
    monkeypatch.setattr(model, "potential", lambda s, a=None: jump.energy)
    monkeypatch.setattr(model, "trial", lambda s, a=None: jump)
    step = controller.step(JUMP)
    assert step.status == "not applied" and step.fraction == 0.0
    assert controller.state is state and np.array_equal(controller.actuation, actuation)
    assert controller.trust.scale < scale


# ---------------------------------------------------------------------------- random control robots

@pytest.mark.parametrize("seed", range(4))
def test_random_robot_tracks_a_circle_and_a_jump_in_tick_mode(seed):
    # A robot of a control experiment's size whose tendons could bend it 2–6 rad: a reachable
    # circle whose points lie 3 cm (or 30 % of the length) from rest, then a jump to a reachable
    # point 3–5 cm away, both within 1 mm after 10 ticks, bounds and per-tick changes held.
    rng = np.random.default_rng(seed)
    scene = robots.control_robot(rng, gravity=seed % 2 == 0)
    model = build(scene)
    reach = min(0.03, 0.3 * model.length_scale)
    controller = InverseController(model, InverseSettings(mode="tick"))
    _tracks(controller, robots.reachable_circle(model, scene, reach, 40))
    target, _ = robots.reachable_target(model, scene, rng, min(float(rng.uniform(0.03, 0.05)), 0.4 * model.length_scale))
    _tracks(controller, np.repeat(target[None], 20, axis=0))


@pytest.mark.parametrize("seed", range(4))
def test_random_robot_converged_inverse_reaches_a_far_target(seed):
    rng = np.random.default_rng(100 + seed)
    scene = robots.control_robot(rng, gravity=seed % 2 == 1)
    model = build(scene)
    target, _ = robots.reachable_target(model, scene, rng, min(float(rng.uniform(0.03, 0.05)), 0.4 * model.length_scale))
    step = InverseController(model, InverseSettings(mode="converged")).step(target)
    assert step.reached and step.errors.max() <= 1e-6 and step.iterations <= 30, (step.status, step.errors)


def test_the_trust_radii_start_from_the_robot_size():
    model = polymer(True)
    region = InverseController(model, InverseSettings(mode="tick")).trust
    assert region.translation == pytest.approx(TRANSLATION * 0.15) and region.rotation == ROTATION


def test_per_tick_changes_come_from_the_scene_or_a_quarter_of_the_range():
    from vertebra.core.errors import SceneError
    base = {"segment": [{"type": "beam", "count": 2, "elements": 2, "length": 0.03, "youngs_modulus": 2e9,
                         "poisson_ratio": 0.35, "section": {"shape": "circle", "radius": 1e-3}}]}
    cables = [{"name": "given", "radius": 0.01, "to": 2, "max_tension": 30.0, "max_tension_change": 2.0},
              {"name": "derived", "radius": 0.01, "to": 2, "min_tension": 2.0, "max_tension": 30.0},
              {"name": "unbounded", "radius": 0.01, "to": 2}]
    model = build(dict(base, cable=cables))
    assert model.actuator_max_change.tolist() == [2.0, 7.0, math.inf]
    with pytest.raises(SceneError, match="max_tension_change"):
        build(dict(base, cable=[dict(cables[0], max_tension_change=-1.0)]))


def test_a_solve_whose_steps_stall_below_resolution_is_not_converged(monkeypatch):
    # Trial energies that overflow make every line search fail: the damping grows until the
    # step is below the resolution of the poses, with the trunk still at rest under its load
    # (residual 1). That is a stalled solve, never a converged one: `converged` always means the
    # residual test holds (the tolerance, or what rounding of the poses explains).
    from vertebra.solver import globalise

    model = build({"segment": [{"type": "beam", "elements": 10, "length": 0.5, "youngs_modulus": 200e9,
                                "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 1e-3}}],
                   "load": [{"vertebra": -1, "force": [0.5, 0.0, 0.0]}]})
    assert model.solve().converged
    real = globalise.potential          # what the line search judges a trial by

    def overflowing(trunk, state, load):
        judged = real(trunk, state, load)
        judged.energy = math.inf
        return judged

    monkeypatch.setattr(globalise, "potential", overflowing)
    result = model.solve(raise_on_failure=False)
    assert not result.converged and not result.rounding_limited
    assert "floating-point resolution" in result.message
    with pytest.raises(ConvergenceError, match="floating-point resolution"):
        model.solve()
