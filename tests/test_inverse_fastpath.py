"""The inverse tick's fast path gives what the validated path gives, bit for bit.

Per step the controller skips re-validating its bounds, weights and regulariser (validated
with the first linearisation), calls LAPACK's banded solve itself, multiplies ``K⁻¹[r, B]``
by all of ``Je`` instead of searching its nonzero columns, and ``solve_constraint_problem``
computes the objective, stationarity and active sets only when they are read (and, for the
controller's own problems, the prediction ``δe``); with the default DAQP backend and no
displacement rows it calls DAQP without the intermediate objects and copies. Each shortcut
is compared here with the path it replaces; bad input must still fail with the validated
path's messages.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.gallery import load
import vertebra.solver.inverse.qp as qp_module
from vertebra.solver.banded import BandedFactor, factor_lu
from vertebra.solver.inverse.controller import InverseController, InverseSettings, _project, _solve_rhs, constraint_problem
from vertebra.solver.inverse.problems import synthetic_problem
from vertebra.solver.inverse.qp import ConstraintProblem, DaqpBackend, quadratic_form, solve_constraint_problem

SCENES = ["paper_3v_4t", "paper_5v_16t", "tendon_two_section"]


def _same(a, b, path=""):
    """Bitwise equality of results (arrays, floats incl. NaN, dataclasses, dicts)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            if f.name not in ("time_s", "timings", "state"):
                _same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
        return
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, path
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), path
        return
    if isinstance(a, float) and a != a:
        assert b != b, path
        return
    assert type(a) is type(b) and a == b, (path, a, b)


def _setup(name):
    model = solver.build_model(load(name))
    lo, hi = model.actuator_bounds
    lam = np.clip(np.full(len(model.actuator_names), 0.3), lo, hi)
    state = model.solve(lam).state
    return model, lam, state, model.effector_positions(state)


def _kw(ctl):
    return dict(weights=ctl.weights, lambda_bounds=ctl.lambda_bounds,
                displacement_bounds=ctl.displacement_bounds, regularisation=ctl.settings.regularisation)


@pytest.mark.parametrize("name", SCENES)
def test_controller_problem_is_the_validated_constraint_problem(name):
    model, lam, state, base = _setup(name)
    rng = np.random.default_rng(0)
    # the rest state too: straight, so Je has exact zeros inside the effector frames' DoFs
    for start in (state, model.rest_state):
        ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=start)
        template = None
        for k in range(4):
            targets = base + 1e-3 * rng.normal(size=base.shape)
            lin = model.linearise(ctl.state, ctl.actuation)
            fast = ctl._constraint_problem(lin, targets)
            slow = constraint_problem(lin, targets, ctl.actuation, **_kw(ctl))
            _same(fast[0], slow[0], "problem")
            _same(fast[1], slow[1], "K⁻¹r")
            _same(fast[2], slow[2], "K⁻¹B")
            assert set(fast[3]) == set(slow[3])
            if k == 0:
                template = ctl._hot.template
            else:  # validated once, then reused: the fast path was taken
                assert ctl._hot.template is template and fast[0] is not template
            ctl.step(targets)


@pytest.mark.parametrize("mode", ["tick", "converged"])
def test_steps_equal_those_of_a_controller_validating_every_step(mode):
    model, lam, state, base = _setup("paper_3v_4t")
    fast = InverseController(model, InverseSettings(mode=mode), actuation=lam, state=state)
    slow = InverseController(model, InverseSettings(mode=mode), actuation=lam, state=state)
    rng = np.random.default_rng(1)
    for k in range(5 if mode == "tick" else 2):
        # small moves, then far out of reach (actuator bounds become active)
        targets = base + (1e-3 if k < 3 else 0.2) * rng.normal(size=base.shape)
        slow._hot = None  # forget the validated problem: every problem is built by ConstraintProblem()
        a, b = fast.step(targets), slow.step(targets)
        _same(dataclasses.replace(a, state=None), dataclasses.replace(b, state=None), f"step {k}")
        _same(a.state.positions, b.state.positions)
        _same(a.state.quaternions, b.state.quaternions)
        assert set(a.timings) == set(b.timings)


def test_a_nonzero_outside_the_effector_frames_is_used_by_the_full_product():
    model, lam, state, base = _setup("paper_5v_16t")
    lin = model.linearise(state, lam)
    Je = lin.effector_jacobian.copy()
    outside = np.flatnonzero(~np.any(Je != 0.0, axis=0))
    assert outside.size > 0
    Je[1, outside[0]] = 0.5  # a Jacobian the model does not make: must still be used as is
    odd = dataclasses.replace(lin, effector_jacobian=Je)
    full = _project(odd, base, lam, full=True)
    searched = _project(odd, base, lam)
    for x, y in zip(full[:5], searched[:5]):
        _same(x, y)
    assert not np.array_equal(full[1], _project(lin, base, lam, full=True)[1])


def test_relinearised_refuses_what_the_validation_would_reject():
    W_ea, de, W_aa, _ = synthetic_problem(0)
    n = W_ea.shape[1]
    da, lam0 = np.zeros(n), np.ones(n)
    template = ConstraintProblem(W_ea, de, lambda_lower=0.0, lambda_upper=20.0, W_aa=W_aa, delta_a_free=da,
                                 lambda0=lam0)
    ok = template._relinearised(2 * W_ea, de + 1, 2 * W_aa, da + 1, lam0 + 1)
    _same(ok, ConstraintProblem(2 * W_ea, de + 1, lambda_lower=0.0, lambda_upper=20.0, W_aa=2 * W_aa,
                                delta_a_free=da + 1, lambda0=lam0 + 1))
    messages = {"W_ea": "W_ea contains non-finite values", "de": "delta_e_free contains (NaN|non-finite values)",
                "W_aa": "W_aa contains non-finite values", "da": "delta_a_free contains (NaN|non-finite values)",
                "lam0": "lambda0 contains NaN"}
    for bad in (np.nan, np.inf, -np.inf):
        for which in messages:
            args = dict(W_ea=W_ea.copy(), de=de.copy(), W_aa=W_aa.copy(), da=da.copy(), lam0=lam0.copy())
            args[which].reshape(-1)[1] = bad
            assert template._relinearised(args["W_ea"], args["de"], args["W_aa"], args["da"],
                                          args["lam0"]) is None, (which, bad)
            if which == "lam0" and bad != bad:
                with pytest.raises(ValueError, match=messages[which]):
                    ConstraintProblem(args["W_ea"], args["de"], lambda_lower=0.0, lambda_upper=20.0,
                                      W_aa=args["W_aa"], delta_a_free=args["da"], lambda0=args["lam0"])
            elif which != "lam0":
                with pytest.raises(ValueError, match=messages[which]):
                    ConstraintProblem(args["W_ea"], args["de"], lambda_lower=0.0, lambda_upper=20.0,
                                      W_aa=args["W_aa"], delta_a_free=args["da"], lambda0=args["lam0"])
    # wrong shapes or types go to the validation too
    assert template._relinearised(W_ea[:2], de[:2], W_aa, da, lam0) is None
    assert template._relinearised(W_ea, de, W_aa, da, lam0[:3]) is None
    assert template._relinearised(W_ea.astype(np.float32), de, W_aa, da, lam0) is None


def test_a_non_finite_linearisation_fails_as_in_the_validated_path():
    model, lam, state, base = _setup("paper_3v_4t")
    ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    ctl.step(base)  # the validated problem is kept from here on
    real = model.linearise
    for field, message in (("effector_jacobian", "W_ea contains non-finite values"),
                           ("effector_positions", "delta_e_free contains NaN"),
                           ("actuator_displacements", "delta_a_free contains NaN")):
        def broken(state, actuation=None, field=field):
            lin = real(state, actuation)
            bad = getattr(lin, field).copy()
            bad.reshape(-1)[0] = np.nan
            return dataclasses.replace(lin, **{field: bad})

        model.linearise = broken
        try:
            with pytest.raises(ValueError, match=message) as validated:
                constraint_problem(broken(ctl.state, ctl.actuation), base, ctl.actuation, **_kw(ctl))
            with pytest.raises(ValueError) as fast:
                ctl.step(base)
            assert str(fast.value) == str(validated.value)
        finally:
            del model.linearise


def test_bounds_are_read_only_and_new_ones_are_validated():
    model, lam, state, base = _setup("paper_3v_4t")
    ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    ctl.step(base)
    for a in (*ctl.lambda_bounds, *ctl.displacement_bounds, ctl.weights):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1.0
    lo, hi = ctl.lambda_bounds
    ctl.lambda_bounds = (hi, lo)  # swapped: the next problem is validated again
    with pytest.raises(ValueError, match=r"lambda_lower\[0\] = .* > lambda_upper\[0\]"):
        ctl.step(base)
    ctl.lambda_bounds = (lo, hi)
    ctl.weights = np.zeros_like(ctl.weights)
    with pytest.raises(ValueError, match="effector_weights must be finite and > 0"):
        ctl.step(base)


def test_bad_targets_are_named():
    model, lam, state, base = _setup("paper_5v_16t")
    ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    with pytest.raises(ValueError, match="targets must hold 2×3 values"):
        ctl.step(base[:1])
    for bad in (np.nan, np.inf):
        t = base.copy()
        t[1, 2] = bad
        with pytest.raises(ValueError, match=f"effector\\(s\\) {model.effector_names[1]} have no target"):
            ctl.step(t)
    a = ctl.step(base.tolist())
    ctl.state, ctl.actuation = state, lam
    b = ctl.step(base.reshape(-1))
    _same(dataclasses.replace(a, state=None), dataclasses.replace(b, state=None))


def _eager_diagnostics(problem, sol):
    """The diagnostics as solve_constraint_problem computed them before they became lazy."""
    from vertebra.solver.inverse.qp import quadratic_form
    qp = quadratic_form(problem)
    lam, n = sol.actuation, problem.n_actuators
    g = qp.P @ lam + qp.q
    objective = 0.5 * float(lam @ (g + qp.q)) + qp.c
    lo, hi = problem.lambda_lower, problem.lambda_upper
    atol_l = 1e-9 * np.maximum(np.abs(lam), np.where(np.isfinite(lo), np.abs(lo), 0.0)) + 1e-300
    out = dict(objective=objective, active_lower=lam <= lo + atol_l, active_upper=lam >= hi - atol_l)
    if problem._has_rows:
        da, dlo, dhi = sol.delta_a, problem.displacement_lower, problem.displacement_upper
        atol_d = 1e-9 * np.abs(da) + 1e-300
        out.update(active_displacement_lower=da <= dlo + atol_d, active_displacement_upper=da >= dhi - atol_d,
                   stationarity=float("nan"))
    else:
        out.update(active_displacement_lower=np.zeros(n, bool), active_displacement_upper=np.zeros(n, bool))
        diag = qp.P.flat[:: n + 1]
        proj = np.clip(lam - g / diag, lo, hi)
        out["stationarity"] = float(np.max(np.abs(proj - lam) * np.sqrt(diag)))
    return out


@pytest.mark.parametrize("backend", ["daqp", "gauss-seidel"])
@pytest.mark.parametrize("rows", [False, True])
def test_diagnostics_read_later_are_those_of_the_solve(backend, rows):
    W_ea, de, W_aa, _ = synthetic_problem(2)
    n = W_ea.shape[1]
    lo, hi = np.zeros(n), np.full(n, 5.0)
    extra = dict(displacement_lower=-1e-3, displacement_upper=np.where(np.arange(n) % 3 == 0, 1e-4, np.inf)) \
        if rows else {}
    problem = ConstraintProblem(W_ea, de, lambda_lower=lo, lambda_upper=hi, W_aa=W_aa,
                                delta_a_free=np.full(n, 1e-5), **extra)
    sol = solve_constraint_problem(problem, backend)
    assert sol.status != "relaxed"
    expected = _eager_diagnostics(problem, sol)
    assert expected["active_lower"].any() and not expected["active_lower"].all()  # not trivial
    assert "_diagnostics" in vars(sol)  # not computed yet
    # what the caller does with the arrays afterwards does not change the diagnostics
    sol.actuation[:] = 1.0
    lo[:] = -1.0
    for name, value in expected.items():
        _same(getattr(sol, name), value, name)
    again = solve_constraint_problem(problem, backend)
    _same(dataclasses.replace(again), again)  # replace and repr see every field
    assert f"stationarity={again.stationarity!r}" in repr(solve_constraint_problem(problem, backend))
    with pytest.raises(AttributeError):
        again.no_such_field  # noqa: B018


def _stacked(lin):
    return np.column_stack([lin.residual, lin.actuator_forces])


def _lu(lin):
    """The same tangent, factorised by banded LU (what the model does when K is not SPD)."""
    f = lin.factor
    n, kd = f.data.shape[1], f.kd
    L = np.zeros((n, n))
    for d in range(kd + 1):
        L[np.arange(d, n), np.arange(n - d)] = f.data[d, : n - d]
    K = L @ L.T
    ab = np.zeros((3 * kd + 1, n))
    i, j = np.nonzero(np.abs(np.subtract.outer(np.arange(n), np.arange(n))) <= kd)
    ab[2 * kd + i - j, j] = K[i, j]
    return factor_lu(ab, kd)


class _Wrapped:
    """A factor that is not a BandedFactor: the solve must go through ``lin.solve``."""

    def __init__(self, factor):
        self.factor, self.calls = factor, 0

    def solve(self, rhs):
        self.calls += 1
        return self.factor.solve(rhs)


@pytest.mark.parametrize("name", SCENES)
def test_the_direct_banded_solve_is_lin_solve(name):
    model, lam, state, _ = _setup(name)
    for s in (state, model.rest_state):
        lin = model.linearise(s, lam)
        assert type(lin.factor) is BandedFactor and lin.factor.kind == "cholesky"
        X, reference = _solve_rhs(lin), lin.solve(_stacked(lin))
        _same(X, reference)
        assert X.flags.f_contiguous == reference.flags.f_contiguous  # the same layout downstream
    lu = dataclasses.replace(lin, factor=_lu(lin))
    assert lu.factor.kind == "lu"
    _same(_solve_rhs(lu), lu.solve(_stacked(lu)))
    wrapped = dataclasses.replace(lin, factor=_Wrapped(lin.factor))
    _same(_solve_rhs(wrapped), reference)
    assert wrapped.factor.calls == 1


def test_the_controller_solves_an_lu_factor_with_lin_solve():
    model, lam, state, base = _setup("paper_5v_16t")
    real = model.linearise
    model.linearise = lambda st, act=None: dataclasses.replace(real(st, act), factor=_lu(real(st, act)))
    try:
        ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
        for k in range(3):
            targets = base + 1e-3 * k
            lin = model.linearise(ctl.state, ctl.actuation)
            fast = ctl._constraint_problem(lin, targets)
            slow = constraint_problem(lin, targets, ctl.actuation, **_kw(ctl))
            _same(fast[0], slow[0], "problem")
            _same(fast[2], lin.solve(lin.actuator_forces), "K⁻¹B")
            ctl.step(targets)
    finally:
        del model.linearise


class _GenericDaqp(DaqpBackend):
    """DAQP through the generic driver (a subclass: not the fast path)."""


def _box_problems():
    for seed in range(4):
        W_ea, de, W_aa, _ = synthetic_problem(seed)
        n = W_ea.shape[1]
        lo, hi = np.zeros(n), np.full(n, 5.0 if seed % 2 else np.inf)
        weights = 1.0 if seed < 2 else np.linspace(0.5, 2.0, W_ea.shape[0])
        yield ConstraintProblem(W_ea, de, lambda_lower=lo, lambda_upper=hi, W_aa=W_aa,
                                delta_a_free=np.full(n, 1e-5), lambda0=np.full(n, 1.0), effector_weights=weights)
        yield ConstraintProblem(W_ea, de, lambda_lower=lo, lambda_upper=hi)  # no W_aa, no warm start
        W_aa = W_aa.copy()
        W_aa[np.arange(0, n, 3), np.arange(0, n, 3)] = 0.0  # actuators without own displacement: floored d
        yield ConstraintProblem(W_ea, de, lambda_lower=-1.0, lambda_upper=hi, W_aa=W_aa,
                                delta_a_free=np.zeros(n), regularisation=1e-6)


def test_the_box_daqp_path_is_the_generic_driver(monkeypatch):
    taken = []
    real = qp_module._solve_box_daqp
    monkeypatch.setattr(qp_module, "_solve_box_daqp", lambda *a: taken.append(1) or real(*a))
    statuses = set()
    for problem in _box_problems():
        for kw in ({}, {"max_iterations": 1}):  # 1 iteration: DAQP stops early, the start is kept
            n_taken = len(taken)
            fast = solve_constraint_problem(problem, "daqp", **kw)
            assert len(taken) == n_taken + 1
            assert "_diagnostics" in vars(fast)
            _same(fast, solve_constraint_problem(problem, _GenericDaqp(), **kw))
            _same(solve_constraint_problem(problem, DaqpBackend(), **kw), fast)
            assert len(taken) == n_taken + 2
            statuses.add(fast.status)
    assert statuses == {"optimal", "max_iterations"}
    # with displacement rows, or another backend: the generic driver
    W_ea, de, W_aa, _ = synthetic_problem(0)
    rows = ConstraintProblem(W_ea, de, lambda_lower=0.0, lambda_upper=5.0, W_aa=W_aa,
                             delta_a_free=np.zeros(W_ea.shape[1]), displacement_upper=1e-4)
    n_taken = len(taken)
    solve_constraint_problem(rows, "daqp")
    solve_constraint_problem(next(_box_problems()), "gauss-seidel")
    assert len(taken) == n_taken


def _reference_quadratic_form(problem):
    """The quadratic form as quadratic_form computed it before the shared _hessian (P, q, c, ρ, d)."""
    w, de = problem.effector_weights, problem.delta_e_free
    Wsq = problem.W_ea * w[:, None]
    H = problem.W_ea.T @ Wsq
    q = Wsq.T @ de
    c = 0.5 * float(de @ (w * de))
    n = H.shape[0]
    h = H.diagonal().copy()
    d = np.abs(problem.W_aa.diagonal()) if problem.W_aa is not None else h.copy()
    dmax = d.max()
    d = np.maximum(d, 1e-12 * dmax if dmax > 0 else 1.0)
    s = float(np.mean(h / d))
    rho = problem.regularisation * (s if s > 0 else 1.0)
    H.flat[:: n + 1] += rho * d
    return H, q, c, rho, d


def test_the_quadratic_form_and_its_floored_energy_diagonal_are_unchanged():
    floored = 0
    for problem in _box_problems():
        qp = quadratic_form(problem)
        P, q, c, rho, d = _reference_quadratic_form(problem)
        for name, value in {"P": P, "q": q, "c": c, "regularisation_weight": rho, "energy_diagonal": d}.items():
            _same(getattr(qp, name), value, name)
        if problem.W_aa is not None:
            floored += int(np.count_nonzero(d != np.abs(problem.W_aa.diagonal())))
    assert floored > 0  # the floor was applied somewhere


def test_the_controllers_problems_predict_when_read():
    model, lam, state, base = _setup("paper_5v_16t")
    ctl = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    ctl.step(base)  # validated once: later problems are the controller's own
    for k in range(3):
        targets = base + 1e-3 * k
        step = ctl.step(targets)
        assert "_prediction" in vars(step.qp) and "_diagnostics" in vars(step.qp)
        lin = model.linearise(ctl.state, ctl.actuation)
        owned = ctl._constraint_problem(lin, targets)[0]
        assert vars(owned).get("_owned") is True
        copy = ConstraintProblem(**{f.name: getattr(owned, f.name) for f in dataclasses.fields(owned) if f.init})
        lazy, eager = solve_constraint_problem(owned), solve_constraint_problem(copy)
        assert "_prediction" in vars(lazy) and "_prediction" not in vars(eager)
        lazy.actuation[:] = 0.0  # the caller's array: the prediction uses the solution's own copy
        eager.actuation[:] = 0.0
        _same(lazy, eager)
        assert "_prediction" not in vars(lazy)
        _same(dataclasses.replace(solve_constraint_problem(owned)), solve_constraint_problem(copy))


def test_step_errors_and_reached_are_those_of_numpy():
    model, lam, state, base = _setup("tendon_two_section")
    ctl = InverseController(model, InverseSettings(mode="tick", tolerance=1e-4), actuation=lam, state=state)
    seen = set()
    for k in range(6):
        targets = base + (2e-5 if k < 3 else 2e-3) * np.arange(base.size).reshape(base.shape)
        step = ctl.step(targets)
        _same(step.errors, np.linalg.norm(step.positions - targets, axis=1))
        assert step.reached is bool(np.all(step.errors <= 1e-4))
        seen.add(step.reached)
        assert set(vars(step)) == {f.name for f in dataclasses.fields(step)}
        assert step.actuation_change != step.actuation_change  # NaN in tick mode
        _same(dataclasses.replace(step, state=None), dataclasses.replace(step, state=None))
    assert seen == {True, False}
    bad = base.copy()
    bad[0, 0] = np.nan  # not a target the controller accepts; _result must still say "not reached"
    assert ctl._result(bad, step.qp, 1, {}, 0.0, False).reached is False
