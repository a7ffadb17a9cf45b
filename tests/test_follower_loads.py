"""Follower loads: a force and moment fixed in a vertebra's own axes, turning with it.

They have no potential, so the forward solve meets them with their consistent (unsymmetric)
tangent, banded LU and an energy-like merit. Checked here: the tangent against differences of
the gradient, the equilibrium against the dead load the follower is at that equilibrium (a
fixed point: the same state must balance both), pure bending by a follower moment against the
closed-form arc, Newton's quadratic convergence, and the scene field's errors. The sensitivities
of follower loads are checked against re-solves in test_sensitivity.py, their run-time change
against a compiled scene in test_parameters.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.core.errors import SceneError
from vertebra.core.lie import qmatrix
from vertebra.solver.potential import tangent

E, NU, R_ROD, LINK = 54e9, 0.3, 0.0007, 0.02
I_ROD = math.pi * R_ROD ** 4 / 4


def rod(count=6, elements=2):
    return {"type": "beam", "count": count, "length": LINK, "elements": elements, "youngs_modulus": E,
            "poisson_ratio": NU, "section": {"shape": "circle", "radius": R_ROD}}


def model_with(loads, count=6, elements=2, tolerance=1e-12):
    return solver.build_model(solver.parse_scene({"solver": {"tolerance": tolerance},
                                                  "segment": [rod(count, elements)], "load": loads,
                                                  "cable": [{"name": "t", "radius": 0.008, "angle_deg": 30.0,
                                                             "to": count, "tension": 0.5}]}))


FOLLOWER = [{"vertebra": -1, "force": [0.4, -0.3, 0.2], "moment": [0.003, 0.002, -0.004], "follower": True},
            {"vertebra": 3, "force": [0.0, 0.5, 0.0], "moment": [0.002, 0.0, 0.0], "follower": True}]


def test_the_tangent_is_the_derivative_of_the_gradient():
    # at a state away from equilibrium, the follower loads' part of the tangent (the tangent with
    # them less the tangent without them) times dq against central differences of their part of
    # the gradient along dq (the chart's step: x + dx, exp(dφ) R): isolated so that the elastic
    # terms, 1e7 times larger, cannot hide an error in it
    model = model_with(FOLLOWER)
    state = model.solve().state
    rng = np.random.default_rng(3)
    moved = model.step(state, 3e-3 * model.length_scale * rng.normal(size=model.n_dof))
    n = model.n_dof

    def dense_tangent(parameters):
        model.set_parameters(parameters)
        factor, _ = tangent(model.trunk, model.evaluate(moved)).factor(0.0, symmetric=False)
        return np.linalg.inv(factor.solve(np.eye(n)))      # K from its LU factor (exact to rounding)

    def follower_gradient(at):
        model.set_parameters(loaded)
        with_them = model.evaluate(at).gradient[1:].reshape(-1)
        model.set_parameters(unloaded)
        return with_them - model.evaluate(at).gradient[1:].reshape(-1)

    loaded = model.parameters
    unloaded = loaded.replace(follower=np.zeros_like(loaded.follower))
    part = dense_tangent(loaded) - dense_tangent(unloaded)
    assert np.abs(part - part.T).max() > 0.1          # unsymmetric: |R f| ~ 0.5 N, and no mirror term
    h = 1e-6
    for _ in range(4):
        dq = rng.normal(size=n) * np.tile([model.length_scale] * 3 + [1.0] * 3, n // 6)
        numeric = (follower_gradient(model.step(moved, h * dq)) - follower_gradient(model.step(moved, -h * dq))) / (2 * h)
        exact = part @ dq
        # O(h²) truncation; the elastic parts (~1e7 N per m of dq) cancel only to their rounding,
        # ~1e-16 · 1e7 / h = 1e-3 at worst (5e-6 relative seen): a missing or wrong term is O(1)
        assert np.abs(numeric - exact).max() <= 1e-4 * np.abs(exact).max()
        assert np.abs(exact).max() > 0.1


def test_the_equilibrium_balances_the_dead_load_the_follower_is_there():
    # under follower loads the tip settles where the world wrench [R f; R m] balances it: the
    # same state is the equilibrium of those world wrenches as dead loads
    model = model_with(FOLLOWER)
    result = model.solve()
    assert result.converged and result.factorization in ("lu", "lu+shifted-lu", "shifted-lu")
    state = result.state
    dead = []
    for load in FOLLOWER:
        frame = model.vertebra_frames[load["vertebra"]]
        R = qmatrix(state.quaternions[frame:frame + 1])[0]
        dead.append({"vertebra": load["vertebra"], "force": (R @ load["force"]).tolist(),
                     "moment": (R @ load["moment"]).tolist()})
    reference = model_with(dead).solve(initial=state)
    length = model.length_scale
    assert np.abs(reference.state.positions - state.positions).max() <= 1e-9 * length
    # and the follower loads did turn: the same vectors as dead loads give another shape
    fixed = model_with([{k: v for k, v in load.items() if k != "follower"} for load in FOLLOWER]).solve()
    assert np.abs(fixed.state.positions - state.positions).max() > 1e-3 * length


def test_a_follower_moment_bends_a_cantilever_into_the_arc_of_a_dead_one():
    # pure bending in a plane: the moment's axis (local y) never turns, so the follower moment is
    # the dead one and the rod is a circular arc of curvature M/EI (tip angle M L / EI)
    count, M = 10, 0.2 * E * I_ROD / (10 * LINK)
    follower = solver.build_model(solver.parse_scene({"solver": {"tolerance": 1e-12}, "segment": [rod(count, 4)],
                                                      "load": [{"vertebra": -1, "moment": [0.0, M, 0.0],
                                                                "follower": True}]}))
    result = follower.solve()
    R = qmatrix(result.state.quaternions[-1:])[0]
    angle = math.atan2(R[0, 2], R[2, 2])
    assert angle == pytest.approx(M * count * LINK / (E * I_ROD), rel=1e-9)


def test_newton_converges_quadratically_with_follower_loads():
    model = model_with(FOLLOWER)
    result = model.solve()
    history = result.residual_history
    assert result.iterations <= 10
    # near the solution a step squares the residual (a tangent without the loads' turning would
    # only shrink it by a constant factor)
    close = [(a, b) for a, b in zip(history, history[1:]) if 1e-8 < a < 1e-3]
    assert close and all(b <= 10.0 * a * a for a, b in close), history


def test_a_follower_load_must_say_true_or_false():
    data = {"segment": [rod()], "load": [{"vertebra": -1, "force": [1.0, 0.0, 0.0], "follower": "yes"}]}
    with pytest.raises(SceneError, match="follower"):
        solver.parse_scene(data)
