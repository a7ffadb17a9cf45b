"""Tangent assembly (vertebra.solver.assembly): the bands gathered from the terms against a dense
assembly written out term by term, the cable tangent summed per pair of frames against the
pieces', and the stability check on the assembled tangent."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.analytic import column_tip_angle
from vertebra.solver.potential import tangent
from vertebra.solver.gallery import load
from vertebra.core.lie import qlog
from vertebra.solver.newton import is_stable
from vertebra.solver.state import compose


def _tensioned(name, seed):
    model = solver.build_model(load(name))
    rng = np.random.default_rng(seed)
    actuation = rng.uniform(0.5, 3.0, len(model.actuator_names))
    return model, actuation, model.solve(actuation).state


def _dense(assembler, terms):
    """The tangent (free frames only) written out from its terms, one term at a time."""
    nb, n = assembler.n_blocks, assembler.n
    full = np.zeros((n + 6, n + 6))            # frame 0 (the clamped base) included, dropped below
    links, cables, turning = assembler.views(terms)
    for k in range(nb):
        dofs = np.r_[6 * k:6 * k + 12]
        full[np.ix_(dofs, dofs)] += links[k]
    for p, (a, b) in enumerate(zip(assembler.pair_a, assembler.pair_b)):
        dofs = np.r_[6 * a:6 * a + 6, 6 * b:6 * b + 6]
        full[np.ix_(dofs, dofs)] += cables[p]
    if turning is not None:          # each free frame's force and moment rows on its rotation
        for j in range(nb):
            full[6 * (j + 1):6 * (j + 1) + 6, 6 * (j + 1) + 3:6 * (j + 1) + 6] += turning[j]
    return full[6:, 6:]


@pytest.mark.parametrize("name", ["paper_3v_4t", "paper_5v_16t", "tendon_two_section", "polymer_5v_16t",
                                  "cantilever"])
def test_bands_gathered_from_the_terms_equal_the_dense_assembly(name):
    model, actuation, state = _tensioned(name, 3)
    assembler = model.trunk.assembler
    # away from equilibrium, where the turning lever arms make the tangent unsymmetric
    moved = model.step(state, 1e-2 * model.length_scale * np.random.default_rng(5).normal(size=model.n_dof))
    matrix = tangent(model.trunk, model.evaluate(moved, actuation))
    dense = _dense(assembler, matrix.terms)
    scale = np.abs(dense).max()
    assert scale > 0 and np.abs(dense - dense.T).max() > 1e-9 * scale    # (≫ rounding)
    kd, n = assembler.kd, assembler.n
    symmetric = 0.5 * (dense + dense.T)
    band = matrix.symmetric_band()
    for d in range(kd + 1):
        assert np.abs(band[d, :n - d] - np.diagonal(symmetric, -d)).max() <= 1e-15 * scale
        assert not band[d, n - d:].any()
    assert (np.abs(np.subtract.outer(np.arange(n), np.arange(n))) <= kd)[dense != 0].all()  # inside the band
    general = assembler.general_band(matrix.blocks())
    for d in range(-kd, kd + 1):                             # ab[2kd + i − j, j] = A[i, j]
        j = np.arange(max(0, -d), min(n, n - d))
        assert np.abs(general[2 * kd + d, j] - dense[j + d, j]).max() <= 1e-15 * scale


@pytest.mark.parametrize("turning", [False, True])
def test_bands_of_overlapping_pairs_and_random_terms_equal_the_dense_assembly(turning):
    # pairs of frames that share frames and blocks (any routing, not only consecutive vertebrae)
    from vertebra.solver.assembly import BandAssembler

    rng = np.random.default_rng(11)
    n_blocks, span = 9, 3
    a = rng.integers(0, n_blocks, 40)
    b = np.minimum(a + rng.integers(1, span + 1, 40), n_blocks)
    order = np.lexsort((b, a))
    assembler = BandAssembler(n_blocks, span, a[order], b[order], turning)
    assert assembler.n_pairs < 40 and np.unique(assembler.pair_a).size < assembler.n_pairs
    terms = rng.normal(size=assembler.terms_size)
    terms[-1] = 0.0
    dense = _dense(assembler, terms)
    kd, n = assembler.kd, assembler.n
    symmetric = 0.5 * (dense + dense.T)
    band = assembler.symmetric_band_of(terms)
    for d in range(kd + 1):
        assert np.abs(band[d, :n - d] - np.diagonal(symmetric, -d)).max() <= 1e-14
    storage = assembler.storage_of(terms)
    general = assembler.general_band(storage[:-1].reshape((2,) + assembler.block_shape))
    for d in range(-kd, kd + 1):
        j = np.arange(max(0, -d), min(n, n - d))
        assert np.abs(general[2 * kd + d, j] - dense[j + d, j]).max() <= 1e-14


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
    assert is_stable(model.trunk, ev) is stable


@pytest.mark.parametrize("ratio", [0.5, 1.1, 2.0, 4.0])
def test_the_solve_returns_the_stable_column_straight_or_buckled(ratio):
    # Only stable equilibria are answers: below the Euler load the straight column, above it the
    # buckled elastica (the solver leaves the straight saddle along its direction of negative
    # curvature). Its tip rotation against the inextensible elastica: measured ≤ 1.9e-5
    # relative with 20 links (the rest is extensibility and shear); 1e-4 bounds it.
    model = _column(ratio)
    result = model.solve()
    assert result.converged and is_stable(model.trunk, model.evaluate(result.state))
    tip = float(np.linalg.norm(qlog(result.state.quaternions[-1:])))
    if ratio < 1.0:
        assert np.abs(result.state.positions[:, :2]).max() == 0.0
    else:
        assert tip == pytest.approx(column_tip_angle(ratio), rel=1e-4)


def test_evenly_spaced_pair_indices_become_slices_that_take_the_same_entries():
    # the batch's band assembly sums the cable pairs of one block offset on views where their
    # blocks are evenly spaced (the usual routing), and by the index arrays otherwise
    from vertebra.solver.assembly import _as_slice

    x = np.arange(40.0).reshape(20, 2)
    for index, sliced in (([], False), ([3], True), ([1, 3, 5, 7], True), ([0, 1, 2], True), ([1, 2, 4], False),
                          ([2, 5, 8, 11], True), ([4, 4], False)):
        index = np.array(index, int)
        taken = _as_slice(index)
        assert isinstance(taken, slice) == sliced
        assert np.array_equal(x[taken], x[index])
