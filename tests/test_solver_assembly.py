"""Tangent assembly paths (vertebra.solver.assembly): the per-pair cable sum against the general
gather-sum-scatter, the symmetric band gathered from the link tangents against the block
assembly, and the stability check on the assembled tangent."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.energy import tangent
from vertebra.solver.gallery import load
from vertebra.solver.newton import is_stable


def _tensioned(name, seed):
    model = solver.build_model(load(name))
    rng = np.random.default_rng(seed)
    actuation = rng.uniform(0.5, 3.0, len(model.actuator_names))
    return model, actuation, model.solve(actuation).state


@pytest.mark.parametrize("name", ["paper_3v_4t", "paper_5v_16t", "tendon_two_section"])
def test_cable_tangent_summed_per_pair_equals_the_general_scatter(name):
    model, actuation, state = _tensioned(name, 3)
    assembler, cables = model.trunk.assembler, model.trunk.cables
    assert assembler.cable_scatter is None        # consecutive vertebrae: the per-pair path is used
    grouped = tangent(model.trunk, model.evaluate(state, actuation), model.memo).extra.copy()  # cables, gravity
    assembler.cable_scatter = assembler.cable_scatter_map(cables.piece_a, cables.piece_b)   # the general path
    general = tangent(model.trunk, model.evaluate(state, actuation), model.memo).extra
    # the same sums in another order: rounding only (measured ≤ 1.7e-16 of the largest entry)
    assert np.abs(grouped - general).max() <= 1e-14 * np.abs(general).max()
    assert np.abs(general).max() > 0


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
    # The straight compressed column is an equilibrium at any load (no lateral imperfection);
    # its tangent is positive definite below the Euler load and indefinite above it (measured:
    # the 20-link chain's tangent loses definiteness at 0.9999956 × π²EI/4L²).
    model = _column(ratio)
    result = model.solve()
    positions = result.state.positions
    assert result.converged and np.abs(positions[:, :2]).max() == 0.0      # still straight
    ev = model.evaluate(result.state)
    assert is_stable(model.trunk, ev, model.memo) is stable


@pytest.mark.parametrize("name", ["cantilever", "paper_5v_16t", "tendon_two_section"])
def test_symmetric_band_from_the_link_tangents_equals_the_block_assembly(name):
    # the Cholesky path gathers the links' part of the band straight from their tangents; the
    # LU and shifted paths assemble every block: both must give the same symmetric part
    model = solver.build_model(load(name))
    actuation = np.random.default_rng(5).uniform(0.5, 3.0, len(model.actuator_names))
    state = model.solve(actuation).state
    matrix = tangent(model.trunk, model.evaluate(state, actuation), model.memo)
    direct = matrix.symmetric_band()
    assembled = model.trunk.assembler.symmetric_from_storage(matrix.storage())
    # the same terms summed in another order: rounding only (measured ≤ 1.7e-16 of the largest)
    assert np.abs(direct - assembled).max() <= 1e-14 * np.abs(assembled).max()
