"""Rotations and the SE(3) logarithm of the runtime (vertebra.core.lie) against finite
differences and Barfoot's formulas, the complex-step reference against finite differences, the
closed-form cable kernel against it, and banded solves against dense ones."""

import numpy as np
import pytest

import reference.complex_step as reference
from reference.complex_step import cable_gradient, link_gradient, pair_tangent
from vertebra.solver.assembly import BandAssembler
from vertebra.solver.banded import factor_cholesky, factor_lu
from vertebra.solver.cables import CablePieces
from vertebra.core.lie import qexp, qlog, qmatrix, qmul, qrotate, se3_exp, se3_log

RNG = np.random.default_rng(20261122)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.1, 1.0, 2.5, np.pi - 1e-6])
def test_quaternion_exp_log_round_trip(angle):
    # exp/log must be inverse to rounding across the series/exact branch switch and near π
    axis = RNG.normal(size=3)
    phi = angle * axis / np.linalg.norm(axis)
    assert np.allclose(qlog(qexp(phi)), phi, rtol=0, atol=1e-14)
    R = qmatrix(qexp(phi))
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-15)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 1e-3, 0.05, 0.3, 1.0, 2.5, 3.1, 3.14159])
def test_se3_log_and_exp_equal_barfoots_closed_forms(angle):
    # the runtime's series kernel against the term-by-term closed forms (Barfoot eqs. 7.86, 7.95)
    # of the reference: the same functions rounded differently, measured ≤ 2e-15 relative
    rng = np.random.default_rng([20261122, int(angle * 1e6)])
    axes = rng.normal(size=(6, 3))
    phi = angle * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    p = rng.normal(size=(6, 3))
    xi, Jl_inv = se3_log(qexp(phi), p)
    xi_ref, Jl_inv_ref = reference.se3_log(reference.qexp(phi), p)
    assert np.abs(xi - xi_ref).max() <= 1e-14 * np.abs(xi_ref).max()
    assert np.abs(Jl_inv - Jl_inv_ref).max() <= 1e-14 * np.abs(Jl_inv_ref).max()
    q, t = se3_exp(xi_ref)
    q_ref, t_ref = reference.se3_exp(xi_ref)
    assert np.abs(q - q_ref).max() <= 1e-14 and np.abs(t - t_ref).max() <= 1e-14 * np.abs(t_ref).max()
    # one pose alone gives the batch's numbers (the series may sum fewer terms: ≤ a few ulps)
    xi0, Jl_inv0 = se3_log(qexp(phi[0]), p[0])
    assert xi0.shape == (6,) and Jl_inv0.shape == (6, 6)
    assert np.abs(xi0 - xi[0]).max() <= 1e-15 * np.abs(xi[0]).max()
    assert np.abs(Jl_inv0 - Jl_inv[0]).max() <= 1e-15 * np.abs(Jl_inv[0]).max()


@pytest.mark.parametrize("angle", [0.0, 1e-6, 0.05, 0.2, 1.5, 3.0])
def test_se3_log_inverse_jacobian_matches_finite_differences(angle):
    # d log(exp(ζ)T)/dζ = J_l⁻¹(ξ); central differences with h = 1e-6 are accurate to ~1e-9
    axis = RNG.normal(size=3)
    q = qexp(angle * axis / np.linalg.norm(axis))
    p = RNG.normal(size=3)
    xi, Jinv = se3_log(q, p)
    q2, p2 = se3_exp(xi)
    assert np.allclose(qmatrix(q2), qmatrix(q), atol=1e-14) and np.allclose(p2, p, atol=1e-14)
    h = 1e-6
    numeric = np.zeros((6, 6))
    for k in range(6):
        z = np.zeros(6)
        z[k] = h
        qp, pp = se3_exp(z)
        qm, pm = se3_exp(-z)
        plus = se3_log(qmul(qp, q), qrotate(qp, p) + pp)[0]
        minus = se3_log(qmul(qm, q), qrotate(qm, p) + pm)[0]
        numeric[:, k] = (plus - minus) / (2 * h)
    assert np.abs(numeric - Jinv).max() < 1e-8


def _random_pair(n, straight=False):
    qa = qexp(RNG.normal(size=(n, 3)))
    qb = qa.copy() if straight else qmul(qa, qexp(0.4 * RNG.normal(size=(n, 3))))
    xa = RNG.normal(size=(n, 3))
    xb = xa + 0.1 * RNG.normal(size=(n, 3))
    return qa, xa, qb, xb


def _finite_difference_tangent(gradient, qa, xa, qb, xb, *args, h=1e-7):
    """Central differences of the gradient along the Newton chart (x + dx, exp(dφ) R)."""
    n = qa.shape[0]
    H = np.zeros((n, 12, 12))
    for k in range(12):
        d = np.zeros((n, 12))
        d[:, k] = h
        grads = []
        for sign in (1, -1):
            dd = sign * d
            qa2 = qmul(qexp(dd[:, 3:6]), qa)
            qb2 = qmul(qexp(dd[:, 9:12]), qb)
            grads.append(gradient(qa2, xa + dd[:, :3], qb2, xb + dd[:, 6:9], *args)[0])
        H[:, :, k] = (grads[0] - grads[1]) / (2 * h)
    return H


@pytest.mark.parametrize("straight", [False, True])
def test_link_tangent_by_complex_step_matches_finite_differences(straight):
    # the complex-step tangent is exact; finite differences agree to ~1e-7 relative
    n = 5
    qa, xa, qb, xb = _random_pair(n, straight)
    K = RNG.normal(size=(n, 6, 6))
    K = K @ np.swapaxes(K, 1, 2) + np.eye(6)
    rest = 0.05 * RNG.normal(size=(n, 6))
    g, energy, H, geometry = pair_tangent(link_gradient, qa, xa, qb, xb, K, rest)
    g_real, e_real, geometry_real = link_gradient(qa, xa, qb, xb, K, rest)
    assert np.allclose(geometry.twist(), geometry_real.twist(), rtol=0, atol=1e-15)
    assert np.allclose(g, g_real, atol=1e-14) and np.allclose(energy, e_real, atol=1e-14)
    H_fd = _finite_difference_tangent(link_gradient, qa, xa, qb, xb, K, rest)
    assert np.abs(H - H_fd).max() < 1e-6 * np.abs(H).max()


def test_cable_tangent_by_complex_step_matches_finite_differences():
    n = 4
    qa, xa, qb, xb = _random_pair(n)
    holes_a, holes_b, tension = RNG.normal(size=(n, 3)), RNG.normal(size=(n, 3)), RNG.random(n)
    g, energy, H = pair_tangent(cable_gradient, qa, xa, qb, xb, holes_a, holes_b, tension)
    H_fd = _finite_difference_tangent(cable_gradient, qa, xa, qb, xb, holes_a, holes_b, tension)
    assert np.abs(H - H_fd).max() < 1e-6 * np.abs(H).max()


def test_link_gradient_is_objective():
    # a rigid motion of both frames produces no net force and no net moment about the origin
    qa, xa, qb, xb = _random_pair(3)
    K = np.broadcast_to(np.diag([3.0, 3, 5, 1, 1, 2]), (3, 6, 6))
    g, _, _ = link_gradient(qa, xa, qb, xb, K, 0.1 * RNG.normal(size=(3, 6)))
    force = g[:, :3] + g[:, 6:9]
    moment = g[:, 3:6] + g[:, 9:] + np.cross(xa, g[:, :3]) + np.cross(xb, g[:, 6:9])
    assert np.abs(force).max() < 1e-12 * np.abs(g).max()
    assert np.abs(moment).max() < 1e-12 * np.abs(g).max() * (1 + np.abs(xa).max())


@pytest.mark.parametrize("n_blocks,span", [(1, 1), (5, 1), (40, 1), (9, 2), (6, 4)])
def test_banded_solve_equals_dense_solve(n_blocks, span):
    # random SPD block-banded matrices: Cholesky and LU band solves equal numpy's dense solve
    layout = BandAssembler(n_blocks, span)
    storage, blocks = layout.new_storage()
    lower, upper = blocks
    n = 6 * n_blocks
    dense = np.zeros((n, n))
    for c in range(n_blocks):
        for s in range(span + 1):
            if c + s < n_blocks:
                block = RNG.normal(size=(6, 6))
                if s == 0:
                    block = block + block.T
                lower[c, s] = block
                dense[6 * (c + s):6 * (c + s) + 6, 6 * c:6 * c + 6] = block
                if s:
                    upper[c, s] = block.T
                    dense[6 * c:6 * c + 6, 6 * (c + s):6 * (c + s) + 6] = block.T
    shift = 2 * np.abs(np.linalg.eigvalsh(0.5 * (dense + dense.T))).max()
    lower[:, 0] += shift * np.eye(6)
    dense += shift * np.eye(n)
    rhs = RNG.normal(size=(n, 3))
    expected = np.linalg.solve(dense, rhs)
    chol = factor_cholesky(layout.symmetric_from_storage(storage))
    lu = factor_lu(layout.general_band(blocks), layout.kd)
    assert np.abs(chol.solve(rhs) - expected).max() < 1e-12 * np.abs(expected).max()
    assert np.abs(lu.solve(rhs) - expected).max() < 1e-12 * np.abs(expected).max()


def test_cholesky_reports_indefinite_matrices():
    layout = BandAssembler(3, 1)
    storage, blocks = layout.new_storage()
    layout.diagonal(blocks)[:] = -np.eye(6)
    assert factor_cholesky(layout.symmetric_from_storage(storage)) is None


def test_closed_form_cable_tangent_equals_the_complex_step():
    n = 6
    qa, xa, qb, xb = _random_pair(n)
    holes_a, holes_b, tension = RNG.normal(size=(n, 3)), RNG.normal(size=(n, 3)), RNG.random(n)
    pieces = CablePieces.of(qmatrix(qa), xa, qmatrix(qb), xb, holes_a, holes_b)
    closed = tension[:, None] * pieces.unit, tension * pieces.length, pieces.tangent(tension)
    stepped = pair_tangent(cable_gradient, qa, xa, qb, xb, holes_a, holes_b, tension)
    for a, b in zip(closed, stepped):
        assert np.abs(a - b).max() <= 1e-14 * max(1.0, np.abs(b).max())
