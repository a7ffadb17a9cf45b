"""The runtime's link kernel (vertebra.core.lie, .links, .chain) against independent references:
Barfoot's SE(3) log/exp and the complex-step link tangent (tests/reference/complex_step.py),
finite differences along the solver's chart, a Bernoulli-number series, and the model's strain
carrying.

Tolerances are relative to the quantity's scale and each says why; measured agreement is noted
where it is far below the bound (bounds leave margin for other BLAS builds, not for errors)."""

import math
import zlib
from fractions import Fraction

import numpy as np
import pytest

from reference.complex_step import link_gradient, pair_tangent, qrotate, se3_exp, se3_log
from vertebra import solver
from vertebra.solver.chain import CARRY_ANGLE, chain_poses
from vertebra.core.lie import SERIES, coefficients, hat, qconj, qexp, qmatrix, qmul
from vertebra.core.lie import powers as _powers
from vertebra.solver.links import Links, link_tangent
from vertebra.solver.model import State

EPS = np.finfo(float).eps
ANGLES = [0.0, 1e-12, 1e-6, 1e-3, 0.3, 1.0, 2.5, 3.1]


def _rng(*key):
    """A generator seeded by the test's parameters: each case draws the same numbers however
    the tests are selected or ordered."""
    return np.random.default_rng([20261122, zlib.crc32(repr(key).encode())])


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _pairs(rng, angle, n=6):
    """Random frame poses a, b whose relative rotation turns by ``angle`` about random axes."""
    qa = qexp(rng.normal(size=(n, 3)))
    qb = qmul(qa, qexp(angle * _unit(rng, n)))
    xa = rng.normal(size=(n, 3))
    return qa, xa, qb, xa + rng.normal(size=(n, 3))


def _spd(rng, n):
    M = rng.normal(size=(n, 6, 6))
    return M @ M.mT + 0.5 * np.eye(6)


def _ad(xi):
    """ad(ξ) = [[φ^, ρ^], [0, φ^]] built directly (independent of links' tables)."""
    A = np.zeros(xi.shape[:-1] + (6, 6))
    A[..., :3, :3] = A[..., 3:, 3:] = hat(xi[..., 3:])
    A[..., :3, 3:] = hat(xi[..., :3])
    return A


def _bernoulli_weights(count):
    """a_k = |B_2k| / (2k)! for k = 1..count, exact rationals (Akiyama–Tanigawa), as floats:
    the coefficients of (1 − (θ/2)cot(θ/2))/θ² = Σ a_k θ^(2k−2), independent of scipy's zeta."""
    row, even = [], []
    for m in range(2 * count + 1):
        row.append(Fraction(1, m + 1))
        for j in range(m, 0, -1):
            row[j - 1] = j * (row[j - 1] - row[j])
        if m >= 2 and m % 2 == 0:
            even.append(abs(row[0]) / math.factorial(m))
    return [float(a) for a in even]


_A_K = _bernoulli_weights(60)


def _series(weights, t):
    """Σ weights[i] t^i by Horner (double)."""
    total = np.zeros_like(t)
    for w in reversed(weights):
        total = total * t + w
    return total


def link_forces(links, stiffness, xi_rest):
    """Gradient, energy ½ eᵀKe, w = K e and y = J_l⁻ᵀ w of quadratic links (what the quadratic
    link kind gives the kernel)."""
    e = links.xi - xi_rest
    w = np.einsum("nij,nj->ni", stiffness, e)
    return links.gradient(w), 0.5 * float(np.vdot(e, w)), w, links.transport(w)


# --------------------------------------------------------------------------- Links.of


@pytest.mark.parametrize("angle", ANGLES)
def test_links_of_equals_se3_log_of_the_relative_transform(angle):
    rng = _rng("of", angle)
    qa, xa, qb, xb = _pairs(rng, angle)
    links = Links.of(qa, xa, qb, xb)
    p = np.einsum("nji,nj->ni", qmatrix(qa), xb - xa)          # R_aᵀ (x_b − x_a)
    xi, Jl_inv = se3_log(qmul(qconj(qa), qb), p)
    # both sides start from the same rounded poses; the relative quaternion is formed by different
    # products, so they differ by rounding: measured ≤ 3.4e-16 (ξ), 4.3e-15 (J_l⁻¹) relative
    assert np.abs(links.xi - xi).max() <= 1e-13 * np.abs(xi).max()
    assert np.abs(links.Jl_inv - Jl_inv).max() <= 1e-13 * np.abs(Jl_inv).max()
    # the force map the gradient and tangent use, Zw = diag(R_a, R_a) [−I; Pᵀ] with
    # Pᵀ = [[I, 0], [−p̂, I]], built here from qmatrix and hat (measured ≤ 4e-16 of its size)
    Ra = qmatrix(qa)
    Zw = np.zeros((qa.shape[0], 12, 6))
    Zw[:, :3, :3] = Zw[:, 3:6, 3:] = -Ra
    Zw[:, 6:9, :3] = Zw[:, 9:, 3:] = Ra
    Zw[:, 9:, :3] = -Ra @ hat(p)
    assert np.abs(links.Zw - Zw).max() <= 1e-14 * np.abs(Zw).max()
    assert np.array_equal(links.span, xb - xa)

    # with frame a at the origin the relative transform is exactly (q_b, x_b): then the rotation
    # part is compared relative to its own size, even at 1e-12 rad (measured ≤ 2.7e-16)
    n = qa.shape[0]
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    links0 = Links.of(identity, np.zeros((n, 3)), qb, xb)
    xi0, Jl_inv0 = se3_log(qb, xb)
    phi_scale = np.maximum(np.linalg.norm(xi0[:, 3:], axis=1), 1e-300)[:, None]
    assert np.all(np.abs(links0.xi[:, 3:] - xi0[:, 3:]) <= 1e-13 * phi_scale)
    assert np.abs(links0.xi - xi0).max() <= 1e-13 * np.abs(xi0).max()
    assert np.abs(links0.Jl_inv - Jl_inv0).max() <= 1e-13 * np.abs(Jl_inv0).max()


# --------------------------------------------------------------------------- forces and tangent


def _chart_finite_difference(qa, xa, qb, xb, K, rest, h=1e-6):
    """Central differences of link_forces' gradient along the solver's chart: x + dx, exp(dφ) R
    (world axes), for the 12 DoFs [dx_a, dφ_a, dx_b, dφ_b]."""
    n = qa.shape[0]
    H = np.zeros((n, 12, 12))
    for k in range(12):
        grads = []
        for sign in (1.0, -1.0):
            d = np.zeros((n, 12))
            d[:, k] = sign * h
            links = Links.of(qmul(qexp(d[:, 3:6]), qa), xa + d[:, :3], qmul(qexp(d[:, 9:]), qb), xb + d[:, 6:9])
            grads.append(link_forces(links, K, rest)[0])
        H[:, :, k] = (grads[0] - grads[1]) / (2.0 * h)
    return H


@pytest.mark.parametrize("angle", ANGLES)
def test_link_forces_and_tangent_equal_the_complex_step_reference(angle):
    rng = _rng("tangent", angle)
    n = 6
    qa, xa, qb, xb = _pairs(rng, angle, n)
    K, rest = _spd(rng, n), 0.3 * rng.normal(size=(n, 6))
    links = Links.of(qa, xa, qb, xb)
    g, energy, w, y = link_forces(links, K, rest)
    H = link_tangent(links, w, K, g)
    g_ref, energies_ref, _ = link_gradient(qa, xa, qb, xb, K, rest)
    _, _, H_ref, _ = pair_tangent(link_gradient, qa, xa, qb, xb, K, rest)
    assert g.shape == (n, 12) and H.shape == (n, 12, 12)
    # same physics, different rounding (tables vs term-by-term products): measured ≤ 3.4e-15 (g),
    # 3.9e-16 (energy), 4.1e-14 (tangent; the complex step is exact to rounding)
    assert np.abs(g - g_ref).max() <= 1e-13 * np.abs(g_ref).max()
    assert abs(energy - energies_ref.sum()) <= 1e-13 * abs(energies_ref.sum())
    assert np.abs(H - H_ref).max() <= 1e-12 * np.abs(H_ref).max()
    # w = K e and y = J_l⁻ᵀ w are what the tangent reuses; the gradient is Zw y
    assert np.allclose(w, np.einsum("nij,nj->ni", K, links.xi - rest), rtol=0, atol=1e-14 * np.abs(w).max())
    assert np.abs(y - links.transport(w)).max() <= 1e-15 * np.abs(y).max()       # same products
    assert np.abs(links.generalised_force(y) - g).max() <= 1e-15 * np.abs(g).max()
    # and against finite differences along the chart: h = 1e-6 leaves O(h²) truncation and
    # ~eps/h cancellation, measured ≤ 7.4e-10 relative; 1e-6 is the FD method's resolution
    H_fd = _chart_finite_difference(qa, xa, qb, xb, K, rest)
    assert np.abs(H - H_fd).max() <= 1e-6 * np.abs(H).max()


_SWAP = np.array([3, 4, 5, 0, 1, 2])
CLOSED_FORM_ANGLES = [0.0, 1e-12, 1e-6, 1e-3, 0.5, 2.0, 3.14, math.pi - 1e-6]


@pytest.mark.parametrize("angle", CLOSED_FORM_ANGLES)
def test_transposed_powers_of_ad_are_the_swapped_powers(angle):
    # what the link tangent folds into one product: (Aᵀ)^k = (−1)^k S A^k S (A = ad(ξ), S swaps
    # a twist's halves), against the powers of Aᵀ multiplied out; exact entry by entry for
    # k ≤ 1, the same products in another order beyond (measured ≤ 1.7e-16 of the power's scale)
    rng = _rng("swapped powers", angle)
    xi = np.concatenate([rng.normal(size=(5, 3)), angle * _unit(rng, 5)], 1)
    A = _ad(xi)
    S = np.eye(6)[_SWAP]
    power, transposed = np.broadcast_to(np.eye(6), A.shape), np.broadcast_to(np.eye(6), A.shape)
    for k in range(5):
        swapped = (-1.0) ** k * (S @ power @ S)
        scale = np.abs(transposed).max()
        assert np.abs(swapped - transposed).max() <= (0.0 if k <= 1 else 4.0 * EPS * scale), k
        power, transposed = power @ A, transposed @ A.mT


@pytest.mark.parametrize("angle", CLOSED_FORM_ANGLES)
def test_link_tangent_equals_its_formula_with_the_powers_multiplied_out(angle):
    # ∂y/∂ξ of the module docstring with u_k = (Aᵀ)^k w from explicit powers of Aᵀ and the
    # coefficients of the series table unsigned, against link_tangent (swapped powers, signed
    # table): the same sums in another order, measured ≤ 3.6e-16 of the tangent's scale
    rng = _rng("tangent formula", angle)
    n = 5
    qa, xa, qb, xb = _pairs(rng, angle, n)
    links = Links.of(qa, xa, qb, xb)
    w, M = rng.normal(size=(n, 6)), _spd(rng, n)
    g = links.gradient(w)
    zw_d_g = link_tangent(links, w, M, g) - link_tangent(links, 0.0 * w, 0.0 * M, g)   # the geometric part cancels
    A = _ad(links.xi)
    u = [w]
    for _ in range(4):
        u.append((A.mT @ u[-1][:, :, None])[:, :, 0])
    C = links.coef[:, 6:].reshape(n, 5, 5) * (-1.0) ** np.arange(5)       # the weights of u_k
    v = [sum(C[:, r, k, None] * u[k] for k in range(5)) for r in range(5)]

    def lam(x):
        out = np.zeros((n, 6, 6))
        out[:, :3, 3:] = out[:, 3:, :3] = hat(x[:, :3])
        out[:, 3:, 3:] = hat(x[:, 3:])
        return out

    At = A.mT
    D = lam(v[0]) + At @ lam(v[1]) + At @ At @ lam(v[2]) + At @ At @ At @ lam(v[3]) + links.Jl_inv.mT @ M
    D[:, :, 3:] += v[4][:, :, None] * links.xi[:, None, 3:]
    reference = links.Zw @ D @ links.G
    assert np.abs(zw_d_g - reference).max() <= 1e-13 * np.abs(reference).max()


def test_batched_transport_and_generalised_force_equal_the_single_ones():
    # (n, m, 6) inputs (the model's pressure columns) give the same as m separate (n, 6) calls
    rng = _rng("batched")
    qa, xa, qb, xb = _pairs(rng, 1.0, 5)
    links = Links.of(qa, xa, qb, xb)
    W = rng.normal(size=(5, 3, 6))
    batched = links.generalised_force(links.transport(W))
    single = np.stack([links.generalised_force(links.transport(W[:, j])) for j in range(3)], 1)
    assert np.abs(batched - single).max() <= 1e-15 * np.abs(single).max()   # same products; 1 ulp


@pytest.mark.parametrize("angle", [0.0, 0.3, 2.5])
def test_strain_change_linearises_the_strain_along_the_chart(angle):
    # ξ(q ⊕ h dq) − ξ(q ⊖ h dq) = 2h G [dq_a; dq_b] + O(h³) with G = J_l⁻¹ Zwᵀ: central differences
    # (h = 1e-6) resolve it to ~1e-9 relative (measured ≤ 1.6e-10); 1e-7 still catches any error in G
    rng = _rng("zeta", angle)
    n = 7
    q = np.empty((n + 1, 4))
    q[0] = qexp(rng.normal(size=3))
    for k in range(n):
        q[k + 1] = qmul(q[k], qexp(angle * _unit(rng, 1)[0]))
    x = rng.normal(size=(n + 1, 3))
    dq = rng.normal(size=(n + 1, 6))
    links = Links.of(q[:-1], x[:-1], q[1:], x[1:])
    predicted = links.strain_change(dq)
    h = 1e-6
    xis = []
    for sign in (1.0, -1.0):
        q2, x2 = qmul(qexp(sign * h * dq[:, 3:]), q), x + sign * h * dq[:, :3]
        xis.append(Links.of(q2[:-1], x2[:-1], q2[1:], x2[1:]).xi)
    numeric = (xis[0] - xis[1]) / (2 * h)
    assert np.abs(predicted - numeric).max() <= 1e-7 * np.abs(predicted).max()


# --------------------------------------------------------------------------- coefficients


@pytest.mark.parametrize("theta", [0.0, 1e-8, 1e-3, 0.05, 0.3, 0.5, 1.0, 2.0, 2.5, 3.0, 3.1, 3.14, 3.1415])
def test_so3_column_equals_one_minus_half_theta_cot_half_theta(theta):
    t = np.array([theta * theta])
    c = coefficients(t)[0]
    # independent series of the same function from exact Bernoulli numbers (60 terms: the ratio
    # θ²/4π² ≤ 0.25 leaves < 1e-36): rounding only, measured ≤ 4.4e-16
    assert abs(c[0] - _series(_A_K, t)[0]) <= 2e-15 * c[0]
    if theta >= 0.5:
        # the closed form loses ~eps·12/θ² to cancellation in 1 − (θ/2)cot(θ/2) (≤ 1e-14 from
        # θ = 0.5 up; measured ≤ 2e-15), so it is a reference only away from zero
        closed = (1.0 - 0.5 * theta / math.tan(0.5 * theta)) / theta ** 2
        assert abs(c[0] - closed) <= 1e-14 * closed
    # the weights of I, A, A², A³, A⁴ in J_l⁻¹: 1, −½, c₂ = Σ(2−k)a_k t^(k−1), 0, c₄ = Σ(1−k)a_k t^(k−2)
    c2 = _series([(2 - k) * a for k, a in enumerate(_A_K, 1)], t)[0]
    c4 = _series([(1 - k) * a for k, a in enumerate(_A_K[1:], 2)], t)[0]
    assert c[1] == 1.0 and c[2] == -0.5 and c[4] == 0.0
    # both sides are rounded sums of the same series (c₂'s mixes signs near π): measured ≤ 4.4e-16
    assert abs(c[3] - c2) <= 2e-15 * abs(c2) and abs(c[5] - c4) <= 2e-15 * abs(c4)


@pytest.mark.parametrize("theta", [0.0, 1e-6, 0.3, 1.0, 2.5, 3.1, 3.14, 3.1415])
def test_inverse_left_jacobian_from_coefficients_equals_se3_log(theta):
    # J_l⁻¹ = Σ_k coef[1 + k] ad(ξ)^k (k = 0..4) against se3_log's block formula (Barfoot 7.95),
    # near π too where the series in θ² converges slowest (ratio ¼): measured ≤ 1.5e-15
    rng = _rng("jacobian", theta)
    n = 5
    phi, p = theta * _unit(rng, n), rng.normal(size=(n, 3))
    xi, Jl_inv = se3_log(qexp(phi), p)
    coef = coefficients((xi[:, 3:] ** 2).sum(1))
    A = _ad(xi)
    J = coef[:, 1, None, None] * np.broadcast_to(np.eye(6), A.shape)
    power = np.broadcast_to(np.eye(6), A.shape).copy()
    for k in range(1, 5):
        power = power @ A
        J = J + coef[:, k + 1, None, None] * power
    assert np.abs(J - Jl_inv).max() <= 1e-13 * np.abs(Jl_inv).max()


def test_adaptive_term_count_does_not_change_small_angle_results():
    # the number of series terms follows the batch's largest angle; a small-angle row must come out
    # the same with few terms, with many (a large angle in the batch) and with all 40. Left-out
    # terms are below (θ²/4π²)^k·ulp: measured bitwise equal; 1e-15 allows ~4 ulp of summation order
    small = np.array([0.0, 1e-30, 1e-12, 1e-6, 1e-3, 0.01, 0.09, 0.3, 1.0])
    alone = coefficients(small)
    full = _powers(small, 40) @ SERIES
    assert np.all(np.abs(alone - full) <= 1e-15 * np.abs(full))
    for large in (2.0, 4.0, 9.0, 9.8, 9.86):
        mixed = coefficients(np.r_[small, large])[:-1]
        assert np.all(np.abs(alone - mixed) <= 1e-15 * np.abs(mixed)), large
    for tiny in ([0.0], [1e-200], [1e-6], [1e-3]):                 # the fewest-term batches
        alone = coefficients(np.array(tiny))
        full = _powers(np.array(tiny), 40) @ SERIES
        assert np.all(np.abs(alone - full) <= 1e-15 * np.abs(full)), tiny


def test_coefficients_at_zero_and_tiny_angles_are_finite_and_exact():
    t = np.array([0.0, 1e-30, 1e-200, 5e-324])
    c = coefficients(t)
    assert c.shape == (4, 31) and np.isfinite(c).all()
    assert np.array_equal(c[0], SERIES[0])          # at θ = 0 exactly the constant terms
    # the constants: 1/12 (SO(3)), and J_l⁻¹ = I − ½A + (1/12)A² − (1/720)A⁴ + …; the zeta-based
    # table may be 1 ulp off a fraction (measured 1/12 + 1.4e-17): 1e-15 relative
    for value, exact in zip(c[0, :6], [1 / 12, 1.0, -0.5, 1 / 12, 0.0, -1 / 720]):
        assert abs(value - exact) <= 1e-15 * abs(exact)
    # tiny θ² moves each value by its first-order term (≈ θ² × the t¹ row, ≤ 1e-30 here): equal to
    # the zero row to rounding where that is nonzero, and to first order where it is exactly zero
    assert np.all(np.abs(c[1:] - c[0]) <= 1e-15 * np.abs(c[0]) + 2.0 * t[1:, None] * np.abs(SERIES[1]))
    assert coefficients(np.zeros(0)).shape == (0, 31)


@pytest.mark.parametrize("count", [1, 2, 8, 40])
def test_powers_equal_pow_and_stay_finite_for_zero_and_tiny_t(count):
    t = np.array([0.0, 5e-324, 1e-300, 1e-200, 1e-30, 1e-3, 0.3, 0.5, 1.0, 2.0, 9.8, 16.0])
    with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
        P = _powers(t, count)
    reference = t[:, None] ** np.arange(count, dtype=float)
    assert P.shape == (t.size, count) and np.isfinite(P).all()
    assert np.all(P[:, 0] == 1.0) and np.all(P[0, 1:] == 0.0)
    # running products round once per factor: ≤ count·eps/2 relative (measured ≤ 4.3e-16);
    # where pow underflows, both are within the smallest normal number of zero
    assert np.all(np.abs(P - reference) <= 1e-14 * np.abs(reference) + np.finfo(float).tiny)


# --------------------------------------------------------------------------- chain composition


def _sequential_chain(q0, x0, xi):
    """T_k = T_{k−1} ∘ exp(ξ_k), one link at a time with the reference se3_exp, qmul and qrotate."""
    n = xi.shape[0]
    q, x = np.empty((n + 1, 4)), np.empty((n + 1, 3))
    q[0], x[0] = q0, x0
    q_link, p_link = se3_exp(xi)
    for k in range(n):
        q[k + 1] = qmul(q[k], q_link[k])
        x[k + 1] = x[k] + qrotate(q[k], p_link[k])
    return q, x


@pytest.mark.parametrize("largest", [1e-8, 0.5, 3.1, 4.0, 4.5, 7.0])
@pytest.mark.parametrize("n", [1, 2, 5, 63, 64, 65, 200, 1001])
def test_chain_poses_equal_sequential_composition(n, largest):
    # n ≤ 63 (N ≤ 64 frames) composes by doubling, n ≥ 64 in blocks; per-link angles up to
    # `largest`, one link at it: ≤ 4 rad (θ² ≤ 16) uses the exp series, beyond the closed form
    # (4.5, 7.0 mix both branches); 3.1 is below CARRY_ANGLE, 4.0 above it
    rng = _rng("chain", n, largest)
    q0, x0 = qexp(rng.normal(size=3)), rng.normal(size=3)
    angles = largest * rng.random(n)
    angles[rng.integers(n)] = largest
    xi = np.concatenate([0.1 * rng.normal(size=(n, 3)), angles[:, None] * _unit(rng, n)], 1)
    chain = chain_poses(q0, x0, xi)
    q_ref, x_ref = _sequential_chain(q0, x0, xi)
    assert chain.quaternions.shape == (n + 1, 4) and chain.positions.shape == (n + 1, 3)
    # rounding accumulates along the chain (~n·eps): measured ≤ 5.4e-15 (quaternions, unit size)
    # and ≤ 3.4e-14 of the extent (positions, 1001 links); 1e-12 leaves room for longer chains
    extent = np.abs(x_ref).max()
    assert np.abs(chain.quaternions - q_ref).max() <= 1e-12
    assert np.abs(chain.positions - x_ref).max() <= 1e-12 * extent
    # the relative translations: V ρ of each link against se3_exp's; the exp series alternates near
    # θ = π and loses a few ulps (measured ≤ 3.8e-15 of the largest)
    translations = se3_exp(xi)[1]
    assert np.abs(chain.translations - translations).max() <= 1e-13 * np.abs(translations).max()
    # the rotation matrices are the chain's unnormalised products while the quaternions are
    # renormalised: they drift apart by ~N·eps (measured 5.4e-14 at 1001 links, ≤ 1.2e-14 to 200),
    # so the bound is 1e-13 up to 200 links and grows in proportion beyond
    assert np.abs(chain.rotations - qmatrix(chain.quaternions)).max() <= 1e-13 * max(1.0, (n + 1) / 201)
    if largest >= CARRY_ANGLE:
        assert chain.link_coefficients is None
    else:
        # the same series as coefficients(), evaluated with at least as many terms: measured
        # ≤ 3.6e-16 relative per entry (summation order); 1e-15 allows a few ulps
        expected = coefficients((xi[:, 3:] ** 2).sum(1))
        assert chain.link_coefficients is not None and chain.link_coefficients.shape == (n, 31)
        assert np.all(np.abs(chain.link_coefficients - expected) <= 1e-15 * np.abs(expected) + 1e-300)


@pytest.mark.parametrize("factor,carried", [(1 - 1e-9, True), (1 + 1e-9, False)])
def test_link_coefficients_are_carried_only_below_the_carry_angle(factor, carried):
    rng = _rng("carry", factor)
    xi = np.concatenate([rng.normal(size=(9, 3)), 0.2 * _unit(rng, 9)], 1)
    xi[4, 3:] *= factor * CARRY_ANGLE / 0.2
    chain = chain_poses(np.array([1.0, 0, 0, 0]), np.zeros(3), xi)
    assert (chain.link_coefficients is not None) == carried


@pytest.mark.parametrize("n", [5, 100])
def test_links_of_strains_equal_links_of_the_composed_poses(n):
    # what the model does with a carried state: of_strains(ξ, chain products) against the
    # logarithms of the composed poses; they differ by the poses' rounding (measured ≤ 8.3e-16
    # for ξ and J_l⁻¹, ≤ 5.8e-15 for the rotation-carrying Zw at 100 links)
    rng = _rng("of_strains", n)
    xi = np.concatenate([0.1 * rng.normal(size=(n, 3)), 2.0 * rng.random((n, 1)) * _unit(rng, n)], 1)
    chain = chain_poses(qexp(rng.normal(size=3)), rng.normal(size=3), xi)
    q, x = chain.quaternions, chain.positions
    carried = Links.of_strains(chain.rotations[:-1], xi, x[1:] - x[:-1], chain.link_coefficients)
    logged = Links.of(q[:-1], x[:-1], q[1:], x[1:])
    assert carried.xi is xi or np.array_equal(carried.xi, xi)
    assert np.abs(carried.xi - logged.xi).max() <= 1e-13 * np.abs(xi).max()
    for name in ("Jl_inv", "Zw", "G", "Apow", "coef"):
        a, b = getattr(carried, name), getattr(logged, name)
        assert np.abs(a - b).max() <= 1e-13 * np.abs(b).max(), name
    recomputed = Links.of_strains(chain.rotations[:-1], xi, x[1:] - x[:-1])
    assert np.abs(recomputed.coef - carried.coef).max() <= 1e-15 * np.abs(carried.coef).max()


# --------------------------------------------------------------------------- strain carrying in the model


@pytest.fixture(scope="module")
def cantilever():
    return solver.build_model(solver.load_scene("gallery:cantilever"))


def _rounding_floor(model):
    """Gradient change from rounding the poses: logarithms of poses stored to eps·|x| are off
    by ~eps·L in ρ and ~eps in φ, i.e. by K·[L, L, L, 1, 1, 1]·eps in force (the axial stiffness
    times the length dominates). Measured differences on the cantilever: 0.7-3.4 of
    eps·stiffness scale for steps of 1e-6…1e-1; the bound allows 32."""
    s = np.r_[np.full(3, model.length_scale), np.ones(3)]
    stiffness_scale = float(np.max(np.abs(model.trunk.links.energies[0].stiffness) @ s))
    return 32.0 * EPS * stiffness_scale


def _pose_only(state):
    return State(state.positions.copy(), state.quaternions.copy())


def test_stepped_state_carries_its_strains_and_evaluates_like_its_poses(cantilever):
    model = cantilever
    act = model.actuation(None)
    dq = 1e-3 * _rng("step").normal(size=model.n_dof)
    state = model.step(model.rest_state, dq)
    record = state.carried_strains()
    assert record is not None
    ev = model.evaluate(state, act)
    assert np.array_equal(ev.links.xi, record.xi)               # the carried strains were used
    g = ev.gradient
    g_pose = model.evaluate(_pose_only(state), act).gradient
    floor = _rounding_floor(model)
    # the gradient is ~1e5 N here (a 1e-3 step strains the links), the bound 8.9e-8 N: measured
    # difference 3.8e-9 N (3.7e-14 of the largest gradient entry)
    assert np.abs(g).max() > 1e6 * floor
    assert np.abs(g - g_pose).max() <= floor

    # a copy keeps a valid record (its own arrays, equal to the record) and evaluates identically
    copy = state.copy()
    assert copy.carried_strains() is not None
    assert copy.positions is not state.positions and copy.quaternions is not state.quaternions
    assert np.array_equal(model.evaluate(copy, act).gradient, g)

    # the solver's own states are read-only, so they cannot drift from their record; a (writeable)
    # copy edited in place loses its record and is then evaluated from its poses
    with pytest.raises(ValueError):
        state.positions[3, 0] += 1e-3
    with pytest.raises(ValueError):
        state.quaternions[3, 0] = 1.0
    copy.positions[3, 0] += 1e-3
    assert copy.carried_strains() is None
    assert state.carried_strains() is not None                  # the original is untouched
    assert np.array_equal(model.evaluate(copy, act).gradient,
                          model.evaluate(_pose_only(copy), act).gradient)
    turned = state.copy()
    turned.quaternions[5] = qmul(qexp(np.array([0.0, 1e-3, 0.0])), turned.quaternions[5])
    assert turned.carried_strains() is None
    assert _pose_only(state).carried_strains() is None


def test_pose_only_restart_of_a_converged_solve_stays_put(cantilever):
    model = cantilever
    result = model.solve()
    assert result.converged and result.state.carried_strains() is not None
    again = model.solve(initial=_pose_only(result.state))
    assert again.converged
    # the pose-only evaluation sees the rounding floor (measured residual ~3e-9 of the load
    # instead of 9.5e-11 with the carried strains); Newton's correction for such a residual is
    # that fraction of the full-load deflection (~0.3 L), ≲ 1e-9 L. Measured: the correction is
    # below the poses' resolution and the tip does not move at all (0.0). A pose-only evaluation
    # biased by 3e-10 in the links' shear strain would already move it past the bound
    tip_motion = np.linalg.norm(again.state.positions[-1] - result.state.positions[-1])
    assert tip_motion <= 1e-9 * model.length_scale
