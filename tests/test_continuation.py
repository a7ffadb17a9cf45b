"""Continuation under loads without a potential, where the load stepping gives up.

Dead moments make the equilibria of a compressed trunk non-unique and its equilibrium path can
reach a limit point, beyond which no equilibrium continues (the trunk would snap through). The
solve then continues from its last equilibrium in fine load increments and, where the path ends,
says why instead of stopping at an iteration limit. These tests check the reason against the
mathematics with an independent implementation: the tangent by central differences of the
gradient along the retraction, its singular values and the path's tangent ``(dx, dλ)`` (the null
vector of ``[K, −∂r/∂λ]``) by a dense SVD.
"""

from __future__ import annotations

import re

import numpy as np

from vertebra.solver import globalise, newton
from vertebra.solver.potential import tangent
from vertebra.solver.state import kinematics, retract
from test_dead_moments import _compressed, _loads, _trunk

# a compressed eight-beam trunk (1.3 × its Euler load) under a dead tip moment: the equilibrium
# path from rest reaches a limit point at about 0.58 of the load (from a seeded search of
# random compressed trunks; three of 150 end at a limit point)
FOLDING = ([-0.4886285016049321, -1.458271088079009, -1.781147802339567],
           [-0.046995492039611377, 0.004174768577849455, -0.13656639116079403])
# the same trunk at 3.7 × its Euler load under another dead tip moment: its load stepping needs
# ~940 iterations (about the default budget of 1,000: whether it finishes within it depends on the
# rounding of the numpy/BLAS build), so the test gives it half that budget, which it cannot finish
# in; continuation from its last equilibrium then reaches the full load (same search)
CONTINUED = ([-0.32568086361975346, 0.03441864378526213, -2.79276189902246],
             [-0.07546551251558918, 0.047001081438564477, -0.05846182362875951])


def _dense(model, state, scale):
    """The tangent ``K`` (central differences of the gradient along the retraction, step 1e-6 in
    the rest stiffness's metric) and the load's derivative ``∂r/∂λ`` at ``state``, both in that
    metric (``S K S`` and ``S ∂r/∂λ``, ``S = diag(stiffness)^{-1/2}``)."""
    gradient = model.evaluate(state, scale=scale).gradient[1:].reshape(-1)
    n = gradient.size
    S = 1.0 / np.sqrt(model.trunk.rest.stiffness)
    links = kinematics(state)
    K = np.empty((n, n))
    for j in range(n):
        step = np.zeros(n)
        step[j] = 1e-6 * S[j]
        plus = model.evaluate(retract(state, step, links), scale=scale).gradient[1:].reshape(-1)
        minus = model.evaluate(retract(state, -step, links), scale=scale).gradient[1:].reshape(-1)
        K[:, j] = (plus - minus) / (2e-6 * S[j])
    load = (model.evaluate(state, scale=0.0).gradient[1:].reshape(-1) - gradient) / scale
    return S[:, None] * K * S[None, :], S * load


def _path_slope(model, state, scale) -> float:
    """``|dλ| / |(dx, dλ)|`` of the equilibrium path's tangent at ``state`` (in the metric): 0 where
    the path turns back in the load factor."""
    K, load = _dense(model, state, scale)
    tangent_of_path = np.linalg.svd(np.hstack([K, -load[:, None]]))[2][-1]
    return abs(tangent_of_path[-1]) / np.linalg.norm(tangent_of_path)


def test_the_smallest_singular_value_agrees_with_a_dense_svd():
    """Inverse iteration with the banded LU factor against the dense SVD of the difference
    tangent, at an equilibrium under a dead moment (relative 1e-5: the differences' error)."""
    model = _trunk(*FOLDING)
    result = _trunk(*(np.array(FOLDING) * 0.3)).solve()
    ev = model.evaluate(result.state, scale=0.3)
    sigma, u = globalise.smallest_singular_value(tangent(model.trunk, ev), model.trunk.rest.stiffness)
    K, _ = _dense(model, result.state, 0.3)
    U, s, _ = np.linalg.svd(K)
    assert abs(sigma - s[-1]) <= 1e-5 * s[-1]
    assert abs(abs(float(u @ U[:, -1])) - 1.0) <= 1e-6        # the left singular vector, up to its sign


def test_a_limit_point_under_dead_loads_is_named_not_an_iteration_limit():
    """The load stepping gives up on this trunk after its 1,000 iterations; continuation follows
    the path to where it turns back and says so. What it returns is the equilibrium there (in
    balance at the load factor it names); at it the tangent is singular (smallest singular value
    below 1e-2 of its value at rest) and the path's tangent is vertical in the load factor (its λ
    share below a tenth of its value at half the load factor) — a limit point, not a bifurcation
    and not a stall. The whole solve stays within 1.5 × its iteration budget."""
    model = _trunk(*FOLDING)
    result = model.solve(raise_on_failure=False)
    assert not result.converged
    assert "turns back there (a limit point" in result.message, result.message
    assert result.iterations <= 1.5 * newton.BUDGET * model.scene.solver.max_iterations
    scale = float(re.search(r"past load factor ([0-9.]+)", result.message).group(1))
    reached = model.evaluate(result.state, scale=scale).gradient[1:]
    weights = np.array([1.0] * 3 + [1.0 / model.trunk.frames.length_scale] * 3)
    full = np.abs(model.evaluate(model.trunk.rest_state).gradient[1:] * weights).max()
    # in balance to the intermediate stages' 1e-6 (5e-4: the message rounds the factor to 4 digits)
    assert np.abs(reached * weights).max() <= 5e-4 * full
    K, _ = _dense(model, result.state, scale)
    rest, _ = _dense(model, model.trunk.rest_state, 1.0)
    assert np.linalg.svd(K, compute_uv=False)[-1] < 1e-2 * np.linalg.svd(rest, compute_uv=False)[-1]
    half = _trunk(*(np.array(FOLDING) * 0.5 * scale)).solve()
    assert _path_slope(model, result.state, scale) < 0.1 * _path_slope(model, half.state, 0.5 * scale)


def test_continuation_reaches_the_full_load_where_the_stepping_gave_up(monkeypatch):
    """The stepping spends its budget (here 500 iterations, half the default: it needs ~940 on
    this trunk) without reaching the full load; continuation from its last equilibrium
    converges, and the state returned is in balance under the full load."""
    monkeypatch.setattr(newton, "BUDGET", newton.BUDGET // 2)
    continued = []
    original = newton._continuation

    def spy(*args, **kwargs):
        continued.append(original(*args, **kwargs))
        return continued[-1]

    monkeypatch.setattr(newton, "_continuation", spy)
    model = _trunk(*CONTINUED)
    result = model.solve()
    budget = newton.BUDGET * model.scene.solver.max_iterations
    assert len(continued) == 1 and continued[0].converged       # the stepping gave up; continuation finished
    assert budget < result.iterations <= 1.5 * budget
    weights = np.array([1.0] * 3 + [1.0 / model.trunk.frames.length_scale] * 3)
    full = np.abs(model.evaluate(model.trunk.rest_state).gradient[1:] * weights).max()
    assert np.abs(model.evaluate(result.state).gradient[1:] * weights).max() <= 10 * model.scene.solver.tolerance * full


def test_solves_that_the_load_stepping_finishes_never_continue(monkeypatch):
    """Continuation starts only where the stepping gave up, so a solve the stepping finishes is
    what it was, iteration for iteration: the dead-moment tests' trunks (links turning 25–95°,
    compressed trunks past their Euler load) converge without it."""
    def refused(*args, **kwargs):
        raise AssertionError("continuation ran on a solve the load stepping finishes")

    monkeypatch.setattr(newton, "_continuation", refused)
    for force, moment in [*_loads(0, 8), *_compressed(0, 4)]:
        assert _trunk(force, moment).solve().converged
