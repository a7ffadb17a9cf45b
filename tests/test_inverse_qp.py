"""Constraint-space QP of the inverse model (paper eqs. 11–13) on seeded synthetic problems.

The synthetic problems are built like the real ones: an SPD stiffness ``K``, cable
Jacobians ``Ja`` with ``B = -Jaᵀ`` (a tension shortens its cable), effector rows
``Je``; ``W_ea = Je K⁻¹ B`` and ``W_aa = Ja K⁻¹ B`` (paper eqs. 11–12).
"""

from __future__ import annotations

import numpy as np
import pytest

from vertebra.solver.gallery.targets import circle
from vertebra.solver.inverse import (
    ConstraintProblem,
    ConstraintSpace,
    available_backends,
    quadratic_form,
    solve_constraint_problem,
)
from vertebra.solver.inverse.problems import synthetic_problem
from vertebra.core.errors import ConvergenceError, OptionError

# The default exact backend (active set: exact to round-off) and one interior-point
# solver through qpsolvers (accurate to its gap tolerance, ~1e-7 relative in effort).
EXACT = ["daqp"]
INTERIOR = [b for b in ("qpsolvers:clarabel",) if b in available_backends()]


def _problem(W_ea, de, W_aa=None, delta_a_free=None, lambda0=None, **space):
    """A problem in its own space (``space``: the ConstraintSpace keywords)."""
    return ConstraintProblem(ConstraintSpace(W_ea.shape[1], W_ea.shape[0], **space), W_ea, de, W_aa,
                             delta_a_free, lambda0)


def test_validation_names_the_numbers():
    W_ea, de, W_aa, _ = synthetic_problem(0, n_act=4)
    with pytest.raises(OptionError, match=r"delta_e_free.shape = \(2,\), but it must be \(3,\)"):
        _problem(W_ea, de[:2])
    with pytest.raises(OptionError, match=r"lambda_lower\[1\] = 5.0 > lambda_upper\[1\] = 1.0"):
        _problem(W_ea, de, lambda_lower=[0, 5, 0, 0], lambda_upper=1.0)
    with pytest.raises(OptionError, match="W_aa.shape"):
        _problem(W_ea, de, W_aa=W_aa[:3, :3], delta_a_free=np.zeros(4))
    with pytest.raises(OptionError, match="displacement limits need W_aa"):
        _problem(W_ea, de, displacement_upper=1.0)
    with pytest.raises(OptionError, match="effector_weights: must be finite and > 0"):
        _problem(W_ea, de, effector_weights=[1, 0, 1])
    with pytest.raises(OptionError, match=r"len\(lambda_upper\) = 3, but it must be 4"):
        _problem(W_ea, de, lambda_upper=[1.0, 2.0, 3.0])
    with pytest.raises(OptionError, match="regularisation: must be finite and ≥ 0"):
        _problem(W_ea, de, regularisation=-1e-8)


@pytest.mark.filterwarnings("ignore:overflow encountered")
def test_a_non_finite_linearisation_is_a_convergence_failure_naming_the_array():
    # NaN or ±inf anywhere in the linearised arrays is a numerical failure (the state diverged),
    # whichever array and entry holds it; a non-finite warm start is a bad argument.
    W_ea, de, W_aa, _ = synthetic_problem(0)
    n = W_ea.shape[1]
    space = ConstraintSpace(n, 3, lambda_lower=0.0, lambda_upper=20.0)
    arrays = dict(W_ea=W_ea, delta_e_free=de, W_aa=W_aa, delta_a_free=np.zeros(n), lambda0=np.ones(n))
    ConstraintProblem(space, **arrays)  # finite: accepted
    big = dict(arrays, W_ea=W_ea * 1e300)  # finite values whose squares overflow: still accepted
    ConstraintProblem(space, **big)
    for bad in (np.nan, np.inf, -np.inf):
        for name in arrays:
            broken = {k: v.copy() for k, v in arrays.items()}
            broken[name].reshape(-1)[-1] = bad
            error = OptionError if name == "lambda0" else ConvergenceError
            with pytest.raises(error, match=name):
                ConstraintProblem(space, **broken)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("exact", EXACT)
def test_gauss_seidel_and_exact_qp_agree_when_well_posed(seed, exact):
    # n_act ≤ rows and full column rank: one optimum. Gauss–Seidel stops at a sweep
    # that moves the effectors by < 1e-10 × the free gap; the optimum is then known to
    # ~1e-10 × cond(H) relative in effort, so 1e-6 leaves margin for cond(H) ≲ 1e4 here,
    # and the predicted gaps agree to 1e-8 of the free gap.
    W_ea, de, W_aa, _ = synthetic_problem(seed, n_act=4, n_rows=6)
    problem = _problem(W_ea, de, lambda_lower=0.0, lambda_upper=6.0,
                       W_aa=W_aa, delta_a_free=np.zeros(4))
    gs = solve_constraint_problem(problem, "gauss-seidel")
    qp = solve_constraint_problem(problem, exact)
    assert gs.converged and qp.converged
    scale = np.linalg.norm(de)
    assert np.linalg.norm(gs.delta_e - qp.delta_e) <= 1e-8 * scale
    np.testing.assert_allclose(gs.actuation, qp.actuation, rtol=0, atol=1e-6 * np.abs(qp.actuation).max())


@pytest.mark.parametrize("backend", ["gauss-seidel", *EXACT, *INTERIOR])
def test_bounds_are_never_violated(backend):
    # Tight effort boxes and stroke limits on random problems: the λ box is exact
    # (the result is clipped), the displacement rows hold to 1e-9 relative (solver
    # feasibility tolerance) — or are reported as relaxed when they cannot hold.
    rng = np.random.default_rng(7)
    for seed in range(6):
        W_ea, de, W_aa, _ = synthetic_problem(seed, n_act=8, reach=3.0)
        lo = rng.uniform(0.0, 0.5, 8)
        hi = lo + rng.uniform(0.5, 2.0, 8)
        dlo = -np.abs(W_aa).sum(axis=1) * 0.7  # stroke limit inside the box's reach
        problem = _problem(W_ea, de, lambda_lower=lo, lambda_upper=hi, W_aa=W_aa,
                           delta_a_free=np.zeros(8), displacement_lower=dlo)
        sol = solve_constraint_problem(problem, backend, max_iterations=20000)
        assert np.all(sol.actuation >= lo) and np.all(sol.actuation <= hi)
        if sol.status != "relaxed":
            assert np.all(sol.delta_a >= dlo - 1e-9 * np.abs(dlo)), backend
        else:
            assert np.all(sol.delta_a >= dlo - sol.displacement_relaxation - 1e-9 * np.abs(dlo))


@pytest.mark.parametrize("backend", ["gauss-seidel", *EXACT])
def test_unreachable_target_gives_the_closest_reach(backend):
    # Independent reference: bounded least squares (scipy lsq_linear) on the same
    # regularised objective. Equal optimal objective to 1e-7 relative (GS stops at
    # 1e-10 relative effector motion per sweep; the objective is quadratic in it).
    from scipy.optimize import lsq_linear

    W_ea, de, W_aa, _ = synthetic_problem(3, n_act=6, reach=10.0)
    problem = _problem(W_ea, de, lambda_lower=0.0, lambda_upper=5.0, W_aa=W_aa,
                       delta_a_free=np.zeros(6))
    sol = solve_constraint_problem(problem, backend, max_iterations=20000)
    qf = quadratic_form(problem)
    A = np.vstack([W_ea, np.diag(np.sqrt(qf.regularisation_weight * qf.energy_diagonal))])
    b = np.concatenate([-de, np.zeros(6)])
    ref = lsq_linear(A, b, bounds=(0.0, 5.0), method="bvls", tol=1e-15)
    ref_objective = 0.5 * float(np.sum((A @ ref.x - b) ** 2))
    assert sol.effector_error > 0.1 * np.linalg.norm(de)  # really out of reach
    diagnostics = sol.diagnostics()
    assert diagnostics.objective == pytest.approx(ref_objective, rel=1e-7)
    assert diagnostics.active_upper.any()  # the closest reach pulls some actuators to their limit


def test_infeasible_stroke_limits_are_relaxed_minimally_and_reported():
    # A stroke limit above the free displacement at zero effort cannot hold with λ ≥ 0
    # (pulling only shortens the cable): the step relaxes it by exactly the deficit.
    W_ea, de, W_aa, _ = synthetic_problem(5, n_act=4)
    da_free = np.full(4, -1e-3)
    problem = _problem(W_ea, de, lambda_lower=0.0, lambda_upper=10.0, W_aa=W_aa,
                       delta_a_free=da_free, displacement_lower=-5e-4)
    for backend in ["gauss-seidel", *EXACT, *INTERIOR]:
        sol = solve_constraint_problem(problem, backend)
        assert sol.status == "relaxed"
        assert np.all(sol.actuation >= 0.0) and np.all(sol.actuation <= 10.0)
        # the best any λ ≥ 0 can do is λ = 0 (W_aa ≤ 0 on its diagonal): deficit 5e-4
        np.testing.assert_allclose(sol.displacement_relaxation, 5e-4, rtol=1e-6)


@pytest.mark.parametrize("exact", EXACT)
def test_redundant_actuation_has_a_unique_solution(exact):
    # 16 tendons, one 3-D target: W_eaᵀW_ea has rank 3. From any warm start the exact
    # QP returns the same efforts (the regulariser makes the QP strictly convex); 1e-6
    # relative is the solver's accuracy on a Hessian of condition ~1/ε = 1e8.
    W_ea, de, W_aa, _ = synthetic_problem(11)
    rng = np.random.default_rng(1)
    sols = []
    for _ in range(4):
        problem = _problem(W_ea, de, lambda_lower=0.0, lambda_upper=20.0, W_aa=W_aa,
                           delta_a_free=np.zeros(16), lambda0=rng.uniform(0, 20, 16))
        sol = solve_constraint_problem(problem, exact)
        assert sol.converged
        # reachable: the regulariser biases the effector by ≪ 1e-6 of the gap
        assert sol.effector_error <= 1e-6 * np.linalg.norm(de)
        sols.append(sol.actuation)
    for lam in sols[1:]:
        np.testing.assert_allclose(lam, sols[0], rtol=0, atol=1e-6 * np.abs(sols[0]).max())


def test_redundant_actuation_is_smooth_along_a_circle():
    # The solution map of a strictly convex QP is continuous, so uniformly spaced
    # targets give efforts without jumps: no step larger than 5× the median step
    # (an arbitrary choice among many solutions would jump by O(λ) instead).
    W_ea, de0, W_aa, _ = synthetic_problem(2)
    space = ConstraintSpace(16, 3, lambda_lower=0.0, lambda_upper=20.0)
    lam = None
    path = []
    for de in circle(de0, 0.3 * np.linalg.norm(de0), 121, normal=np.random.default_rng(0).normal(size=3)):
        sol = solve_constraint_problem(ConstraintProblem(space, W_ea, de, W_aa, np.zeros(16), lam))
        assert sol.converged
        lam = sol.actuation
        path.append(lam)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert steps.max() <= 5 * np.median(steps)
    assert np.linalg.norm(path[-1] - path[0]) <= 1e-6 * np.abs(path[0]).max()  # closed loop


def test_regulariser_is_invariant_to_units_and_actuator_count():
    # Units: tension in mN instead of N for half the actuators, mm instead of m for the
    # effector: the same physical answer. The regularised Hessian has condition ~1/ε =
    # 1e8, so round-off alone moves efforts by ~1e-8 relative: 1e-6 is the tolerance.
    W_ea, de, W_aa, _ = synthetic_problem(4, n_act=6)
    base = solve_constraint_problem(_problem(W_ea, de, lambda_lower=0.0, lambda_upper=20.0,
                                    W_aa=W_aa, delta_a_free=np.zeros(6)))
    s = np.array([1e3, 1, 1e3, 1, 1e3, 1])  # λ' = s λ
    scaled = solve_constraint_problem(_problem(
        1e3 * W_ea / s, 1e3 * de, lambda_lower=0.0, lambda_upper=20.0 * s,
        W_aa=W_aa / s[None, :] / s[:, None], delta_a_free=np.zeros(6)))
    np.testing.assert_allclose(scaled.actuation / s, base.actuation, rtol=1e-6, atol=1e-9 * base.actuation.max())
    # Count: every actuator doubled (two identical cables) shares the effort; the sum
    # equals the original to the regulariser's O(ε) effect on a reachable target.
    W2 = np.hstack([W_ea, W_ea])
    Waa2 = np.block([[W_aa, W_aa], [W_aa, W_aa]])
    dup = solve_constraint_problem(_problem(W2, de, lambda_lower=0.0, lambda_upper=20.0,
                                            W_aa=Waa2, delta_a_free=np.zeros(12)))
    np.testing.assert_allclose(dup.actuation[:6], dup.actuation[6:], rtol=0, atol=1e-6 * dup.actuation.max())
    assert np.linalg.norm(dup.delta_e) <= 1e-6 * np.linalg.norm(de)
    assert np.linalg.norm(base.delta_e) <= 1e-6 * np.linalg.norm(de)


@pytest.mark.parametrize("interior", INTERIOR)
def test_interior_point_backend_agrees_with_active_set(interior):
    # Clarabel stops at a duality gap of 1e-10 on the Jacobi-scaled problem: efforts
    # agree with DAQP's active-set answer to ~1e-7 relative; 1e-5 leaves margin.
    W_ea, de, W_aa, _ = synthetic_problem(8, n_act=5, n_rows=6, reach=2.0)
    problem = _problem(W_ea, de, lambda_lower=0.0, lambda_upper=8.0, W_aa=W_aa,
                       delta_a_free=np.zeros(5))
    a = solve_constraint_problem(problem, "daqp")
    b = solve_constraint_problem(problem, interior)
    np.testing.assert_allclose(b.actuation, a.actuation, rtol=0, atol=1e-5 * np.abs(a.actuation).max())


def test_diagnostics_certify_the_box_optimum():
    # At the optimum of a box QP the projected gradient step vanishes: DAQP is exact to
    # round-off, so the stationarity (in effector units) is ≤ 1e-12 of the free gap; an
    # actuator at its lower (upper) bound has a gradient pushing it outwards (≥ 0, ≤ 0), a free
    # one none (both to 1e-9 of the gradient at λ = 0).
    W_ea, de, W_aa, _ = synthetic_problem(2)
    problem = _problem(W_ea, de, W_aa, np.full(16, 1e-5), lambda_lower=0.0, lambda_upper=5.0)
    sol = solve_constraint_problem(problem, "daqp")
    diagnostics = sol.diagnostics()
    assert diagnostics.active_lower.any() and not diagnostics.active_lower.all()  # a real active set
    assert diagnostics.stationarity <= 1e-12 * np.linalg.norm(de)
    form = quadratic_form(problem)
    gradient = form.P @ sol.actuation + form.q
    scale = np.abs(form.q).max()  # the gradient at λ = 0
    assert np.all(gradient[diagnostics.active_lower] >= -1e-9 * scale)
    assert np.all(gradient[diagnostics.active_upper] <= 1e-9 * scale)
    free = ~(diagnostics.active_lower | diagnostics.active_upper)
    assert np.all(np.abs(gradient[free]) <= 1e-9 * scale)
    assert diagnostics.objective == pytest.approx(
        0.5 * sol.actuation @ form.P @ sol.actuation + form.q @ sol.actuation + form.c, rel=1e-12)


def test_actuators_without_own_displacement_stay_regularised():
    # d = |W_aa,ii| = 0 for every third actuator: its energy weight is floored at 1e-12 of
    # the largest, so the regularised Hessian stays positive definite and the QP unique.
    W_ea, de, W_aa, _ = synthetic_problem(1)
    W_aa = W_aa.copy()
    W_aa[np.arange(0, 16, 3), np.arange(0, 16, 3)] = 0.0
    form = quadratic_form(_problem(W_ea, de, W_aa, np.zeros(16), lambda_lower=-1.0, regularisation=1e-6))
    d = np.abs(W_aa.diagonal())
    np.testing.assert_array_equal(form.energy_diagonal[d > 0], d[d > 0])
    np.testing.assert_array_equal(form.energy_diagonal[d == 0], 1e-12 * d.max())
    assert np.linalg.eigvalsh(form.P).min() > 0


def test_an_iteration_limit_is_reported_and_the_box_still_holds():
    W_ea, de, W_aa, _ = synthetic_problem(3)
    problem = _problem(W_ea, de, W_aa, np.zeros(16), np.ones(16), lambda_lower=0.0, lambda_upper=5.0)
    for backend in ("daqp", "gauss-seidel"):
        sol = solve_constraint_problem(problem, backend, max_iterations=1)
        assert sol.status == "max_iterations" and not sol.converged
        assert np.all(sol.actuation >= 0.0) and np.all(sol.actuation <= 5.0)


def test_backends_are_reached_only_through_the_registry():
    from vertebra.solver.inverse.backends import BACKENDS, GaussSeidelBackend, get_backend, register_backend

    for name in available_backends():
        assert get_backend(name).name == name
    with pytest.raises(OptionError, match="unknown QP backend 'simplex'; known: .*daqp.*qpsolvers:<name>"):
        get_backend("simplex")
    with pytest.raises(OptionError, match="backend"):
        get_backend("qpsolvers:no-such-solver")
    calls = []

    class Counted(GaussSeidelBackend):
        name = "counted"

        def solve(self, form, start, **kw):
            calls.append(form.P.shape)
            return super().solve(form, start, **kw)

    register_backend("counted", Counted)
    try:
        W_ea, de, W_aa, _ = synthetic_problem(0, n_act=4, n_rows=6)
        problem = _problem(W_ea, de, W_aa, np.zeros(4), lambda_lower=0.0, lambda_upper=6.0)
        sol = solve_constraint_problem(problem, "counted")
        assert calls == [(4, 4)] and sol.backend == "counted"
        # unscaled backend: the same answer as the exact QP (the well-posed case above)
        reference = solve_constraint_problem(problem, "daqp")
        np.testing.assert_allclose(sol.actuation, reference.actuation, rtol=0,
                                   atol=1e-6 * np.abs(reference.actuation).max())
    finally:
        del BACKENDS["counted"]


def test_damping_is_centred_on_the_current_actuation():
    # Levenberg–Marquardt damping penalises λ − λ0 only: started at the undamped answer it
    # returns it (to the solver's tolerance; the damped and undamped QPs share that minimiser),
    # and from λ0 = 0 it shortens the step (the change it weighs can only shrink).
    W_ea, de, W_aa, _ = synthetic_problem(6, n_act=6)
    space = ConstraintSpace(6, 3, lambda_lower=0.0, lambda_upper=20.0)
    plain = solve_constraint_problem(ConstraintProblem(space, W_ea, de, W_aa, np.zeros(6), np.zeros(6)))
    again = solve_constraint_problem(ConstraintProblem(space, W_ea, de, W_aa, np.zeros(6), plain.actuation,
                                                       damping=1e-2))
    assert np.allclose(again.actuation, plain.actuation, rtol=1e-7, atol=1e-9 * plain.actuation.max())
    damped = solve_constraint_problem(ConstraintProblem(space, W_ea, de, W_aa, np.zeros(6), np.zeros(6),
                                                        damping=1e-2))
    assert np.linalg.norm(damped.actuation) < np.linalg.norm(plain.actuation)


def test_a_tick_box_narrows_the_actuator_limits_by_the_per_tick_changes():
    space = ConstraintSpace(3, 3, lambda_lower=0.0, lambda_upper=[30.0, 30.0, np.inf], max_change=[7.5, 1.0, np.inf])
    lower, upper = space.tick_box(np.array([2.0, 29.5, 5.0]))
    assert np.array_equal(lower, [0.0, 28.5, 0.0]) and np.array_equal(upper, [9.5, 30.0, np.inf])
    W_ea, de, _, _ = synthetic_problem(1, n_act=3)
    answer = solve_constraint_problem(ConstraintProblem(space, W_ea, de * 100, lambda0=np.array([2.0, 29.5, 5.0]),
                                                        box=(lower, upper)))
    assert np.all(answer.actuation >= lower) and np.all(answer.actuation <= upper)
    with pytest.raises(OptionError, match="max_change"):
        ConstraintSpace(3, 3, max_change=-1.0)
    with pytest.raises(OptionError, match="box"):
        ConstraintProblem(space, W_ea, de, box=(upper, lower))
