"""Tangent assembly paths (vertebra.solver.assembly): the per-pair cable sum against the general
gather-sum-scatter, the symmetric band gathered from the link tangents against the block
assembly, and the stability check on the assembled tangent."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.analytic import column_tip_angle
from vertebra.solver.energy import tangent
from vertebra.solver.gallery import load
from vertebra.solver.lie import qlog
from vertebra.solver.newton import is_stable
from vertebra.solver.state import compose


def _tensioned(name, seed):
    model = solver.build_model(load(name))
    rng = np.random.default_rng(seed)
    actuation = rng.uniform(0.5, 3.0, len(model.actuator_names))
    return model, actuation, model.solve(actuation).state


@pytest.mark.parametrize("name", ["paper_3v_4t", "paper_5v_16t", "tendon_two_section"])
def test_cable_tangent_summed_per_pair_equals_the_general_scatter(name):
    model, actuation, state = _tensioned(name, 3)
    assembler = model.trunk.assembler
    assert assembler.cable_scatter is None        # consecutive vertebrae: the per-pair path is used
    grouped = tangent(model.trunk, model.evaluate(state, actuation), model.memo).extra.copy()  # cables, gravity
    assembler.cable_scatter = assembler.cable_scatter_map(assembler.pair_a, assembler.pair_b)   # the general path
    general = tangent(model.trunk, model.evaluate(state, actuation), model.memo).extra
    # the same sums in another order: rounding only (measured ≤ 1.7e-16 of the largest entry)
    assert np.abs(grouped - general).max() <= 1e-14 * np.abs(general).max()
    assert np.abs(general).max() > 0


@pytest.mark.parametrize("name", ["paper_3v_4t", "paper_5v_16t", "tendon_two_section"])
def test_grouped_cable_tangent_is_the_sum_of_the_pieces(name):
    model, actuation, state = _tensioned(name, 4)
    assembler, ev = model.trunk.assembler, model.evaluate(state, actuation)
    tension = ev.load.piece_tension
    alone = ev.pieces.tangent(tension)                               # (m, 12, 12), one per piece
    grouped = ev.pieces.tangent(tension, assembler.cable_groups)     # (pairs, 12, 12)
    assert grouped.shape == (assembler.pair_a.size, 12, 12)
    m = tension.size
    for pair, pieces in enumerate(assembler.cable_groups):
        pieces = pieces[pieces < m]
        assert pieces.size and (model.trunk.cables.piece_a[pieces] == assembler.pair_a[pair]).all()
        expected = alone[pieces].sum(0)
        assert np.abs(grouped[pair] - expected).max() <= 1e-14 * np.abs(expected).max()


def _column(force_ratio, links=20):
    """A clamped-free steel column under an axial tip force of ``force_ratio`` × the Euler load."""
    length, radius, youngs = 0.5, 1e-3, 200e9
    EI = youngs * math.pi * radius ** 4 / 4
    critical = math.pi ** 2 * EI / (4 * length ** 2)
    return solver.build_model(solver.parse_scene({
        "segment": [{"type": "beam", "count": 1, "length": length, "elements": links,
                     "youngs_modulus": youngs, "poisson_ratio": 0.3,
                     "section": {"shape": "circle", "radius": radius}}],
        "load": [{"vertebra": -1, "force": [0.0, 0.0, -force_ratio * critical]}]}))


@pytest.mark.parametrize("ratio, stable", [(0.5, True), (0.9, True), (1.1, False), (2.0, False)])
def test_stability_check_sees_the_buckling_load(ratio, stable):
    # The straight compressed column is an equilibrium at any load (no lateral imperfection):
    # every link shortened by P/EA. Its tangent is positive definite below the Euler load and
    # indefinite above it (measured: the 20-link chain's tangent loses definiteness at
    # 0.9999956 × π²EI/4L²).
    model = _column(ratio)
    link = model.scene.segments[0]
    P = ratio * math.pi ** 2 * link.youngs_modulus * link.section.Ixx / (4 * 0.5 ** 2)
    xi = model.link_rest.copy()
    xi[:, 2] *= 1.0 - P / (link.youngs_modulus * link.section.area)
    straight = compose(model.rest_state.quaternions[0], model.rest_state.positions[0], xi)
    ev = model.evaluate(straight)
    # an equilibrium to rounding (the out-of-balance force relative to the load)
    assert np.abs(ev.gradient[1:]).max() <= 1e-9 * P
    assert is_stable(model.trunk, ev, model.memo) is stable


@pytest.mark.parametrize("ratio", [0.5, 1.1, 2.0, 4.0])
def test_the_solve_returns_the_stable_column_straight_or_buckled(ratio):
    # Only stable equilibria are answers: below the Euler load the straight column, above it the
    # buckled elastica (the solver leaves the straight saddle along its direction of negative
    # curvature). Its tip rotation against the inextensible elastica: measured ≤ 1.9e-5
    # relative with 20 links (the rest is extensibility and shear); 1e-4 bounds it.
    model = _column(ratio)
    result = model.solve()
    assert result.converged and is_stable(model.trunk, model.evaluate(result.state), model.memo)
    tip = float(np.linalg.norm(qlog(result.state.quaternions[-1:])))
    if ratio < 1.0:
        assert np.abs(result.state.positions[:, :2]).max() == 0.0
    else:
        assert tip == pytest.approx(column_tip_angle(ratio), rel=1e-4)
