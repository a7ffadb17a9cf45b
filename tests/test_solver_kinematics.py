"""Rotations and the SE(3) logarithm of the runtime (vertebra.core.lie) against finite
differences and Barfoot's formulas, its matrix form against the matrix exponential, the
complex-step reference against finite differences, the closed-form cable kernel against it, and
banded solves against dense ones."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

import reference.complex_step as reference
from reference.complex_step import cable_gradient, link_gradient, pair_tangent
from vertebra.solver.assembly import BandAssembler
from vertebra.solver.banded import factor_cholesky, factor_lu
from vertebra.solver.cables import CablePieces
from vertebra.core.lie import (ad, hat, qexp, qfrom_matrix, qlog, qmatrix, qmul, qrotate, se3_exp, se3_exp_matrix,
                               se3_left_jacobian_inverse, se3_log, se3_log_matrix, so3_exp, so3_expm1, so3_log)

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


def _twist_matrix(xi):
    """The 4×4 matrix ``ξ^ = [[φ^, ρ], [0, 0]]`` of a twist."""
    out = np.zeros((4, 4))
    out[:3, :3], out[:3, 3] = hat(xi[3:]), xi[:3]
    return out


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.1, 1.0, 2.5, 3.1])
def test_matrix_form_equals_the_matrix_exponential_and_inverts(angle):
    # R, t of exp(ξ^) against scipy's expm of the 4×4 matrix (Padé: ~1e-15 here); the logarithms
    # invert the exponentials to rounding; expm1 keeps its relative accuracy at small angles
    rng = np.random.default_rng([20261204, int(angle * 1e6)])
    axes = rng.normal(size=(5, 3))
    phi = angle * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    xi = np.concatenate([rng.normal(size=(5, 3)), phi], 1)
    R, t = se3_exp_matrix(xi)
    assert R.shape == (5, 3, 3) and t.shape == (5, 3)
    for k in range(5):
        T = expm(_twist_matrix(xi[k]))
        assert np.abs(R[k] - T[:3, :3]).max() <= 1e-14 and np.abs(t[k] - T[:3, 3]).max() <= 1e-14
    assert np.abs(so3_exp(phi) - R).max() <= 1e-15
    # orthogonal to a few ulps (the determinant's LU adds its own)
    assert np.abs(R @ R.mT - np.eye(3)).max() <= 2e-15 and np.abs(np.linalg.det(R) - 1.0).max() <= 4e-15
    assert np.abs(se3_log_matrix(R, t) - xi).max() <= 1e-14 * np.abs(xi).max()
    assert np.abs(so3_log(R) - phi).max() <= 1e-14
    # exp(φ^) − I = Σ φ^ᵏ/k!: accurate relative to its size, not to 1
    small = so3_expm1(phi)
    assert np.abs(small - (R - np.eye(3))).max() <= 1e-15
    if angle <= 1e-4:
        P = hat(phi)
        P2 = P @ P
        series = P + P2 / 2.0 + P2 @ P / 6.0 + P2 @ P2 / 24.0        # next term θ⁵/120: < 1e-22
        assert np.abs(small - series).max() <= 1e-15 * max(np.abs(series).max(), 1e-300)
    # one transform alone gives the batch's numbers
    R0, t0 = se3_exp_matrix(xi[0])
    assert R0.shape == (3, 3) and t0.shape == (3,) and np.abs(R0 - R[0]).max() <= 1e-15


@pytest.mark.parametrize("axis", range(3))
@pytest.mark.parametrize("angle", [1e-7, 1.0, np.pi - 1e-3, np.pi])
def test_quaternion_of_a_rotation_matrix_at_every_pivot(axis, angle):
    # near π about x, y, z the largest quaternion component is x, y, z (each pivot of the
    # method); scipy's from_matrix is the independent reference (both with w ≥ 0)
    rng = np.random.default_rng([axis, int(angle * 1e6)])
    direction = np.eye(3)[axis] + 0.05 * rng.normal(size=3)
    phi = angle * direction / np.linalg.norm(direction)
    R = Rotation.from_rotvec(phi).as_matrix()
    q = qfrom_matrix(R)
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    expected = np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)
    assert q[0] >= 0 and np.abs(q - expected).max() <= 1e-15
    assert np.abs(qmatrix(q) - R).max() <= 1e-15


def test_ad_is_the_commutator_and_the_twist_jacobian_matches_differences():
    # ad(ξ₁) ξ₂ is the twist of [ξ₁^, ξ₂^]; J_l⁻¹(ξ) = ∂ log(exp(ζ^) exp(ξ^))/∂ζ at ζ = 0 by central
    # differences of the matrix-form exp and log (h = 1e-6: ~1e-9 accurate)
    rng = np.random.default_rng(20261205)
    xi1, xi2 = rng.normal(size=(2, 6))
    A, B = _twist_matrix(xi1), _twist_matrix(xi2)
    C = A @ B - B @ A
    commutator = np.concatenate([C[:3, 3], [C[2, 1], C[0, 2], C[1, 0]]])
    assert np.abs(ad(xi1) @ xi2 - commutator).max() <= 1e-14 * np.abs(commutator).max()
    assert ad(rng.normal(size=(2, 3, 6))).shape == (2, 3, 6, 6)
    xi = np.concatenate([rng.normal(size=3), 2.0 * rng.normal(size=3) / np.sqrt(3)])
    R, t = se3_exp_matrix(xi)
    h = 1e-6
    numeric = np.zeros((6, 6))
    for k in range(6):
        ends = []
        for sign in (1, -1):
            Rz, tz = se3_exp_matrix(sign * h * np.eye(6)[k])
            ends.append(se3_log_matrix(Rz @ R, Rz @ t + tz))
        numeric[:, k] = (ends[0] - ends[1]) / (2 * h)
    Jl_inv = se3_left_jacobian_inverse(xi)
    assert Jl_inv.shape == (6, 6) and np.abs(numeric - Jl_inv).max() < 1e-8
    assert se3_left_jacobian_inverse(np.tile(xi, (2, 3, 1))).shape == (2, 3, 6, 6)


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
