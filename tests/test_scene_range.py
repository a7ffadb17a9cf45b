"""What a scene asks of its segments: strain, load and pressure ranges for fitted entries.

The CBHA-like pneumatic trunk's ranges (chambers, real entries) are checked in
tests/test_designer_gallery.py, where its catalogue is built once.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.designer.scene_range import (ENLARGE, actuation_box, actuation_corners, estimate_ranges,
                                           group_coordinates)


def test_group_coordinates():
    v = np.array([[3.0, 4.0, -1.0, 0.0, 2.0, -0.5]])
    assert group_coordinates(v).tolist() == [[5.0, -1.0, 2.0, -0.5]]


def test_corners_all_of_them_or_a_deterministic_cover():
    lower, upper = np.array([0.0, 0.0, 1.0]), np.array([1.0, 2.0, 1.0])           # the third is fixed
    corners = actuation_corners(lower, upper)
    assert corners.shape == (4, 3) and set(map(tuple, corners)) == {(0, 0, 1), (0, 2, 1), (1, 0, 1), (1, 2, 1)}
    n = 10
    many = actuation_corners(np.zeros(n), np.ones(n), max_corners=30, seed=3)
    assert many.shape == (30, n) and len(set(map(tuple, many))) == 30
    rows = set(map(tuple, many))
    assert tuple(np.zeros(n)) in rows and tuple(np.ones(n)) in rows
    assert all(tuple(np.eye(n)[i]) in rows and tuple(1 - np.eye(n)[i]) in rows for i in range(n))
    assert np.array_equal(many, actuation_corners(np.zeros(n), np.ones(n), max_corners=30, seed=3))


def test_an_unbounded_actuator_is_taken_at_its_forward_value():
    scene = solver.load_scene("gallery:tendon_two_section")
    cables = tuple(dataclasses.replace(c, max_tension=math.inf) if i == 0 else c for i, c in enumerate(scene.cables))
    model = solver.build_model(dataclasses.replace(scene, cables=cables))
    lower, upper = actuation_box(model)
    assert upper[0] == model.default_actuation[0] == 6.0 and upper[1] == 20.0 and np.all(lower == 0.0)


def test_a_cantilever_under_a_small_tip_load_gives_the_beam_moments():
    """Linear regime (tip deflection ~1e-4 of the length): the load on link k is the tip force and
    the moment F (L − (k + ½) ℓ) about the link's middle, its bending strain that moment × ℓ/EI;
    to 1e-6 relative (the geometric correction is of the order of the rotation, ~1e-4, squared)."""
    scene = solver.load_scene("gallery:cantilever")
    force = 1e-4
    scene = dataclasses.replace(scene, loads=(dataclasses.replace(scene.loads[0], force=(force, 0.0, 0.0)),))
    estimate = estimate_ranges(solver.build_model(scene))
    [segment] = estimate.segments
    L, ell, EI = 0.5, 0.5 / 20, 200e9 * math.pi * 1e-12 / 4
    moment = force * (L - ell / 2)                                   # the base link carries the largest
    assert segment.load_upper[2] == pytest.approx(ENLARGE * moment, rel=1e-6)
    assert segment.load_upper[0] == pytest.approx(ENLARGE * force, rel=1e-6)
    assert segment.strain_upper[2] == pytest.approx(ENLARGE * moment * ell / EI, rel=1e-6)
    assert np.all(segment.load_lower == 0.0) and np.all(segment.strain_lower == 0.0)
    assert segment.pressures == {} and estimate.failed == ()


def test_the_estimate_covers_the_actuations_between_the_corners():
    """Six tendons (64 corners, all solved): the strains and loads of every segment at seeded
    random actuations inside the box stay within the estimate. With enlarge = 1 the extremes
    are attained at the corners themselves."""
    model = solver.build_model(solver.load_scene("gallery:tendon_two_section"))
    estimate = estimate_ranges(model)
    assert len(estimate.actuations) == 1 + 64 and estimate.failed == ()
    [segment] = estimate.segments
    lower, upper = actuation_box(model)
    rng = np.random.default_rng(7)
    for actuation in lower + (upper - lower) * rng.random((6, lower.size)):
        state = model.solve(actuation).state
        evaluation = model.evaluate(state, actuation)
        strain = group_coordinates(evaluation.links.xi - model.link_rest)
        load = group_coordinates(evaluation.w)
        assert np.all(strain >= segment.strain_lower - 1e-15) and np.all(strain <= segment.strain_upper + 1e-15)
        assert np.all(load >= segment.load_lower - 1e-15) and np.all(load <= segment.load_upper + 1e-15)
    exact = estimate_ranges(model, enlarge=1.0).segments[0]
    assert np.allclose(exact.load_upper * ENLARGE, segment.load_upper, rtol=1e-12, atol=0)
    # one section-1 tendon alone at its 20 N bound bends the base link with τ r = 0.16 N m in the
    # straight trunk (0.18 N m solved: the bent trunk and gravity add); the estimate includes it
    assert exact.load_upper[2] >= 20.0 * 0.008


def test_progress_is_reported_after_each_actuation():
    model = solver.build_model(solver.load_scene("gallery:cantilever"))          # no actuator: 2 solves
    calls = []
    estimate = estimate_ranges(model, progress=lambda done, total, s: calls.append((done, total, s)))
    assert [c[:2] for c in calls] == [(k + 1, len(estimate.actuations)) for k in range(len(estimate.actuations))]
    assert all(b[2] >= a[2] >= 0.0 for a, b in zip(calls, calls[1:])) and estimate.seconds >= calls[-1][2]
