"""Inverse simulation on the runtime model (paper §IV): linearise → project → QP → step.

Targets come from forward solutions at known actuations (so they are reachable), or are
pushed out of reach on purpose. Gallery scenes are reused, never copied (STYLE §8).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.gallery import load
from vertebra.solver.gallery.targets import reachable_loop
from vertebra.solver.inverse import ConstraintSpace
from vertebra.solver.inverse.controller import InverseController, InverseSettings
from vertebra.core.errors import ConvergenceError, OptionError, SceneError


def _model(name, **replace):
    scene = load(name)
    if replace:
        scene = dataclasses.replace(scene, **replace)
    return solver.build_model(scene)


def _within_bounds(model, actuation):
    lo, hi = model.actuator_bounds
    return bool(np.all(actuation >= lo) and np.all(actuation <= hi))


def _forward_targets(model, actuation):
    result = model.solve(actuation)
    return model.effector_positions(result.state)


@pytest.mark.parametrize("name, actuation", [
    ("paper_3v_4t", [2.0, 0.5, 0.0, 1.0]),
    # posture control: two effectors (vertebra 2 and the tip), 16 tendons
    ("paper_5v_16t", [1.5, 0, 0, 0.5, 0, 1.0, 0, 0, 0.8, 0, 0, 0.3, 0, 0, 0.6, 0]),
])
def test_converged_inverse_of_a_forward_solution_reaches_the_target(name, actuation):
    # The requirement is 1e-6 m; the regulariser's fixed-point bias is ~1e-7 m on these
    # scenes (bench_qp.py: bias ≈ ε × gap) and Newton's tolerance is far below it.
    model = _model(name)
    targets = _forward_targets(model, np.array(actuation))
    step = InverseController(model, InverseSettings(mode="converged")).step(targets)
    assert step.reached and step.status == "reached" and step.equilibrium
    assert np.all(step.errors <= 1e-6)
    assert _within_bounds(model, step.actuation)
    # the reported state is a true equilibrium under the returned actuation
    check = model.solve(step.actuation, initial=step.state)
    assert np.all(np.linalg.norm(model.effector_positions(check.state) - targets, axis=1) <= 1e-6)


def test_unreachable_target_gives_the_closest_reach_within_bounds():
    # A tip target far beside the 85 mm robot: tensions saturate, the error stays, the
    # status says so. Closest reach: no feasible actuation nearby does better — each
    # single-actuator change of ±10 % of its range leaves the error ≥ 99 % of the
    # achieved one (the loop stops when an iteration gains < 1 %).
    model = _model("paper_3v_4t")
    targets = np.array([[0.08, 0.0, 0.03]])
    step = InverseController(model, InverseSettings(mode="converged")).step(targets)
    assert not step.reached and step.status == "closest_reach"
    assert _within_bounds(model, step.actuation)
    active = step.qp.diagnostics()
    assert active.active_upper.any() or active.active_lower.any()
    lo, hi = model.actuator_bounds
    for j in range(len(step.actuation)):
        for sign in (-1.0, 1.0):
            lam = step.actuation.copy()
            lam[j] = np.clip(lam[j] + sign * 0.1 * (hi[j] - lo[j]), lo[j], hi[j])
            if lam[j] == step.actuation[j]:
                continue
            try:
                pos = model.effector_positions(model.solve(lam, initial=step.state).state)
            except ConvergenceError:
                continue
            assert np.linalg.norm(pos - targets) >= 0.99 * step.errors.max()


def test_gauss_seidel_and_exact_qp_agree_on_the_robot():
    # Three tendons (0°, 90°, 180°) for one 3-D target. Both backends reach the target
    # (1e-6 m) and agree on what bends the robot — the antagonist difference t1 − t3 and
    # t2 — to 1e-3 relative. The common mode of t1 and t3 only compresses the stiff
    # backbone (~1e-6 m per N): the 1e-6 m tolerance cannot resolve it, and there the
    # regulariser (exact QP) and the warm start (Gauss–Seidel, paper §IV) decide.
    scene = load("paper_3v_4t")
    model = solver.build_model(dataclasses.replace(scene, cables=scene.cables[:3]))
    targets = _forward_targets(model, np.array([1.0, 0.6, 0.3]))
    steps = {b: InverseController(model, InverseSettings(backend=b)).step(targets)
             for b in ("daqp", "gauss-seidel")}
    assert all(s.reached for s in steps.values())
    bend = {b: np.array([s.actuation[0] - s.actuation[2], s.actuation[1]]) for b, s in steps.items()}
    np.testing.assert_allclose(bend["gauss-seidel"], bend["daqp"], rtol=1e-3)
    np.testing.assert_allclose(bend["daqp"], [0.7, 0.6], rtol=1e-3)  # the forward tensions' bending part


def test_redundant_16_tendon_actuation_is_smooth_along_a_loop():
    # Tip-only control with 16 tendons (13 redundant efforts), converged inverse along a
    # closed reachable loop: every point reached (1e-6 m), efforts never jump (largest
    # step ≤ 5× the median step: a continuous solution map sampled uniformly) and the loop
    # closes (same efforts at the same target — a unique solution — to 1e-4 of the largest
    # effort: each step stops once λ changes by ≤ 1e-4 relative per iteration; measured
    # 5e-6).
    scene = load("paper_5v_16t")
    tip = [e for e in scene.effectors if e.name == "tip"]
    scene = dataclasses.replace(scene, effectors=tuple(tip))
    model = solver.build_model(scene)
    loop = reachable_loop(model, scene, 25, base=0.1, amplitude=1.0)
    controller = InverseController(model, InverseSettings(mode="converged"))
    efforts = []
    for target in loop:
        step = controller.step(target)
        assert step.reached, (step.status, step.errors)
        assert _within_bounds(model, step.actuation)
        efforts.append(step.actuation)
    efforts = np.array(efforts)
    moves = np.linalg.norm(np.diff(efforts, axis=0), axis=1)
    assert moves.max() <= 5 * np.median(moves)
    np.testing.assert_allclose(efforts[-1], efforts[0], rtol=0, atol=1e-4 * efforts.max())


def test_tick_mode_tracks_and_settles():
    # Real-time mode: one linearise–QP–step per tick, no Newton solve. Along a reachable
    # loop the commanded tensions stay in bounds and the tracking error stays below 1 mm
    # (the default tick tolerance of the CLI); held at the last target, the ticks converge
    # like Newton so the equilibrium under the final tensions reaches it to 1e-6 m.
    scene = load("paper_3v_4t")
    model = solver.build_model(scene)
    loop = reachable_loop(model, scene, 20, base=0.2, amplitude=1.0)
    controller = InverseController(model, InverseSettings(mode="tick"))
    for target in loop:
        step = controller.step(target[0])
        assert _within_bounds(model, step.actuation)
        assert step.status == "tick" and not step.equilibrium
        assert step.errors.max() <= 1e-3
    for _ in range(8):
        step = controller.step(loop[-1])
    settled = model.solve(step.actuation, initial=step.state)
    assert np.linalg.norm(model.effector_positions(settled.state) - loop[-1]) <= 1e-6


def test_tick_mode_reusing_the_tangent_factors_it_on_fewer_ticks_and_settles_alike(monkeypatch):
    # tangent_reuse = 2: a tick's factor serves up to two following ticks (chord steps) while
    # every tick is applied in full, its prediction holds and the tensions stay within 15 % of
    # those it was linearised at. Around an equilibrium under 2 N per tendon, on a 0.1 mm circle,
    # the commands stay in bounds and the tangent is assembled on fewer than half of the ticks;
    # held at one target, the chord ticks converge where the exact ones do (each one's imbalance
    # is exact; only the tangent is older): their equilibria agree to 1e-7 m. With the default
    # (0) every tick assembles its own tangent.
    import vertebra.solver.outputs as outputs

    model = _model("paper_3v_4t")
    start = np.full(4, 2.0)
    state = model.solve(start).state
    centre = model.effector_positions(state)
    assembled = []
    tangent = outputs.tangent
    monkeypatch.setattr(outputs, "tangent", lambda trunk, ev: assembled.append(1) or tangent(trunk, ev))
    settled = {}
    for reuse in (0, 2):
        assembled.clear()
        controller = InverseController(model, InverseSettings(mode="tick", tangent_reuse=reuse), actuation=start,
                                       state=state)
        targets = [centre + 1e-4 * np.array([np.cos(a), np.sin(a), 0.0]) for a in np.linspace(0, 2 * np.pi, 25)]
        targets += [targets[-1]] * 15
        for target in targets:
            step = controller.step(target)
            assert _within_bounds(model, step.actuation) and step.errors.max() <= 1e-3
        assert len(assembled) == len(targets) if reuse == 0 else 0 < len(assembled) < 0.5 * len(targets)
        solved = model.solve(step.actuation, initial=step.state)
        settled[reuse] = model.effector_positions(solved.state)
    assert np.abs(settled[2] - settled[0]).max() <= 1e-7
    assert np.linalg.norm(settled[0] - targets[-1]) <= 1e-5


def test_stroke_limit_is_respected_at_the_closest_reach():
    # A cable stroke limit (shortening ≥ −1 mm) that the target would need to exceed:
    # the inverse stops at the limit. At a converged fixed point the linearised stroke is
    # the true stroke, so the limit holds to the Newton tolerance (1e-9 m margin).
    scene = load("paper_3v_4t")
    limited = dataclasses.replace(scene.cables[0], min_stroke=-1.0e-3)
    model = solver.build_model(dataclasses.replace(scene, cables=(limited, *scene.cables[1:])))
    free = solver.build_model(scene)
    targets = _forward_targets(free, np.array([6.0, 0.0, 0.0, 0.0]))
    assert free.actuator_displacements(free.solve(np.array([6.0, 0, 0, 0])).state, np.array([6.0, 0, 0, 0]))[0] < -1.2e-3
    step = InverseController(model, InverseSettings(mode="converged")).step(targets)
    assert not step.reached
    assert step.displacements[0] >= -1.0e-3 - 1e-9
    assert step.displacements[0] <= -1.0e-3 + 1e-6  # it does pull up to the limit
    assert _within_bounds(model, step.actuation)


def pneumatic_entry(length=0.03, youngs_modulus=1e6, poisson_ratio=0.45, outer=0.012, inner=0.004,
                    cavity_radius=0.007, cavity_area=4e-5, n_cavities=3):
    """A synthetic three-cavity elastomer segment (no CBHA catalogue entry exists yet):
    tube compliance C, pressure acting as a push ``F`` on the top face at each cavity,
    G = C F, V = Fᵀ C F + v₀ I — symmetric positive definite by construction."""
    from vertebra.solver.timoshenko import Section, timoshenko_compliance
    from vertebra.store.entry import SegmentEntry

    C = timoshenko_compliance(length, youngs_modulus, youngs_modulus / (2 * (1 + poisson_ratio)),
                              Section.tube(outer, inner, poisson_ratio))
    F = np.zeros((6, n_cavities))
    for k in range(n_cavities):
        angle = 2 * np.pi * k / n_cavities
        point = cavity_radius * np.array([np.cos(angle), np.sin(angle), 0.0])
        F[:3, k] = [0.0, 0.0, cavity_area]
        F[3:, k] = np.cross(point, F[:3, k])
    G = C @ F
    compliance = np.block([[C, G], [G.T, F.T @ C @ F + 1e-12 * np.eye(n_cavities)]])
    return SegmentEntry(key="synthetic-pneumatic", name="synthetic-pneumatic", family="synthetic",
                        parameters={}, compliance=compliance,
                        cavity_volumes=np.full(n_cavities, cavity_area * length), mass=0.0,
                        center_of_mass=np.array([0.0, 0.0, length / 2]),
                        rest_translation=np.array([0.0, 0.0, length]))


def _pneumatic_model(**extra):
    """Four synthetic pneumatic segments, one chamber per cavity over the whole trunk (0–1.5 bar),
    a tip effector; ``extra`` scene tables (e.g. cables)."""
    entry = pneumatic_entry()
    scene = solver.parse_scene({
        "catalogue": {"path": "unused.h5"},
        "segment": [{"type": "entry", "entry": entry.name, "count": 4}],
        "chamber": [{"name": f"c{k}", "cavity": k, "from": 1, "to": 4, "min_pressure": 0.0,
                     "max_pressure": 1.5e5} for k in range(3)],
        "effector": [{"name": "tip", "vertebra": -1}],
        **extra,
    })
    return solver.build_model(scene, entries={entry.name: entry})


def test_chambers_inverse_reaches_the_target():
    # Pressure actuation (one chamber per cavity over the whole trunk), same 1e-6 m
    # requirement as for cables; pressures stay in [0, 1.5 bar].
    model = _pneumatic_model()
    targets = _forward_targets(model, np.array([5e4, 1e4, 0.0]))
    step = InverseController(model, InverseSettings()).step(targets)
    assert step.reached and np.all(step.errors <= 1e-6)
    assert _within_bounds(model, step.actuation)


def test_hybrid_cables_and_chambers_in_one_qp():
    # Tensions (N) and pressures (Pa) side by side: the energy regulariser is in joules
    # for both, so one QP serves them (paper §VI: hybrid actuation). The inverse of a
    # forward solution under a mixed actuation reaches the target to 1e-6 m within bounds.
    model = _pneumatic_model(cable=[{"name": f"t{k}", "radius": 0.011, "angle_deg": 60.0 + 120.0 * k, "from": 1,
                                     "to": 4, "min_tension": 0.0, "max_tension": 5.0} for k in range(3)])
    assert model.actuator_names == ["t0", "t1", "t2", "c0", "c1", "c2"]
    targets = _forward_targets(model, np.array([0.5, 0.0, 0.0, 3e4, 0.0, 1e4]))
    step = InverseController(model, InverseSettings()).step(targets)
    assert step.reached and np.all(step.errors <= 1e-6)
    assert _within_bounds(model, step.actuation)


def test_the_projection_by_halves_of_the_cholesky_factor_is_the_banded_solves():
    # With conservative loads K = L Lᵀ and every actuator's force is its Jacobian row scaled
    # (B = Jaᵀ diag(c): −1 per cable, +1 per chamber), so one forward sweep L⁻¹[Jaᵀ, Jeᵀ, r]
    # gives what the banded solve K⁻¹[r, B] gives: W_ea, W_aa, the free gaps, the state change
    # and the effectors' motion under a force. Two orders of the same elimination on a definite
    # band: they agree to rounding, ≤ 1e-12 of the largest entry here (bound 1e-10, which leaves
    # room for the condition of K, not for a wrong product).
    cables = [{"name": f"t{k}", "radius": 0.011, "angle_deg": 60.0 + 120.0 * k, "from": 1, "to": 4,
               "min_tension": 0.0, "max_tension": 5.0} for k in range(3)]
    cases = [(_pneumatic_model(cable=cables), np.array([0.5, 0.0, 0.2, 3e4, 0.0, 1e4])),
             (_model("paper_5v_16t"), np.full(16, 0.3))]
    for model, lam in cases:
        state = model.solve(lam).state
        lin = model.linearise(state, lam)
        assert lin.cholesky is not None
        np.testing.assert_array_equal(lin.actuator_forces, lin.actuator_jacobian.T * lin.force_scale)
        space = ConstraintSpace.of_model(model)
        targets = model.effector_positions(state) + 1e-3
        halves = space.project(lin, targets, lam)
        banded = space.project(dataclasses.replace(lin, force_scale=None), targets, lam)
        assert halves.halves is not None and banded.halves is None
        other = np.clip(lam * 1.1 + 0.01, *model.actuator_bounds)
        force = np.random.default_rng(0).normal(size=lin.residual.size) * np.abs(lin.residual).max()
        for a, b in ((halves.problem.W_ea, banded.problem.W_ea), (halves.problem.W_aa, banded.problem.W_aa),
                     (halves.problem.delta_e_free, banded.problem.delta_e_free),
                     (halves.problem.delta_a_free, banded.problem.delta_a_free),
                     (halves.state_change(other), banded.state_change(other)),
                     (halves.effector_motion(force), banded.effector_motion(force))):
            assert np.abs(a - b).max() <= 1e-10 * np.abs(b).max()


# ---------------------------------------------------------------------------- inputs and results


def _at_a_forward_solution(name):
    model = _model(name)
    lo, hi = model.actuator_bounds
    lam = np.clip(np.full(len(model.actuator_names), 0.3), lo, hi)
    state = model.solve(lam).state
    return model, lam, state, model.effector_positions(state)


def test_settings_and_scenes_are_checked_by_meaning():
    for bad, field in ((dict(mode="fast"), "mode"), (dict(tolerance=0.0), "tolerance"),
                       (dict(tolerance=np.nan), "tolerance"), (dict(regularisation=-1.0), "regularisation"),
                       (dict(backend="simplex"), "backend"), (dict(max_iterations=0), "max_iterations"),
                       (dict(progress=1.0), "progress"), (dict(tangent_reuse=-1), "tangent_reuse"),
                       (dict(tangent_reuse=1.5), "tangent_reuse")):
        with pytest.raises(OptionError) as error:
            InverseSettings(**bad)
        assert error.value.field == field
    assert InverseSettings(mode="tick").tolerance == 1e-3 and InverseSettings().tolerance == 1e-6
    scene = load("paper_3v_4t")
    for replace, field in ((dict(effectors=()), "effector"), (dict(cables=()), "cable")):
        with pytest.raises(SceneError) as error:
            InverseController(solver.build_model(dataclasses.replace(scene, **replace)))
        assert error.value.field == field and error.value.file == scene.source


def test_bad_targets_are_named_and_any_layout_of_good_ones_is_the_same():
    model, lam, state, base = _at_a_forward_solution("paper_5v_16t")
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    with pytest.raises(OptionError, match="targets: must hold 2×3 values"):
        controller.step(base[:1])
    for bad in (np.nan, np.inf):
        t = base.copy()
        t[1, 2] = bad
        with pytest.raises(OptionError, match=f"effector\\(s\\) {model.effector_names[1]} have no finite target"):
            controller.step(t)
    a = controller.step(base.tolist())
    controller.state, controller.actuation = state, lam
    b = controller.step(base.reshape(-1))
    np.testing.assert_array_equal(a.actuation, b.actuation)
    np.testing.assert_array_equal(a.state.positions, b.state.positions)


def test_a_diverged_linearisation_is_a_convergence_failure_naming_the_array(monkeypatch):
    # NaN in what the model linearises (a state that blew up) must not reach the QP: the
    # projection fails with ConvergenceError (exit 1 on the command line), not a ValueError.
    model, lam, state, base = _at_a_forward_solution("paper_3v_4t")
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    controller.step(base)
    real = model.linearise
    for field, array in (("effector_jacobian", "W_ea"), ("effector_positions", "delta_e_free"),
                         ("actuator_displacements", "delta_a_free"), ("actuator_jacobian", "W_aa")):
        def broken(state, actuation=None, *, previous=None, field=field):
            lin = real(state, actuation, previous=previous)
            bad = getattr(lin, field).copy()
            bad.reshape(-1)[0] = np.nan
            return dataclasses.replace(lin, **{field: bad})

        monkeypatch.setattr(model, "linearise", broken)
        with pytest.raises(ConvergenceError, match=f"constraint projection: {array} contains NaN"):
            controller.step(base)


def test_the_constraint_space_is_validated_once_and_read_only():
    model, lam, state, base = _at_a_forward_solution("paper_3v_4t")
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    space = controller.space
    for a in (space.lambda_lower, space.lambda_upper, space.displacement_lower, space.effector_weights):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1.0
    with pytest.raises(OptionError, match=r"lambda_lower\[0\] = .* > lambda_upper\[0\]"):
        dataclasses.replace(space, lambda_lower=space.lambda_upper, lambda_upper=space.lambda_lower)
    # a tighter box assigned to the controller holds in the next ticks
    controller.space = dataclasses.replace(space, lambda_upper=np.full(space.n_actuators, 0.5))
    for _ in range(3):
        step = controller.step(base + 0.02)
        assert np.all(step.actuation <= 0.5) and np.all(step.actuation >= space.lambda_lower)
    assert isinstance(controller.space, ConstraintSpace)


def test_step_errors_reached_and_settled_equilibria():
    # A tick's errors are |position − target| of its predicted state; settled, the step is an
    # equilibrium under the same actuation (an independent solve lands on the same state to the
    # solver tolerance) with its errors and reached flag recomputed there.
    model, lam, state, base = _at_a_forward_solution("tendon_two_section")
    controller = InverseController(model, InverseSettings(mode="tick", tolerance=1e-4), actuation=lam, state=state)
    seen = set()
    for k in range(6):
        targets = base + (2e-5 if k < 3 else 2e-3) * np.arange(base.size).reshape(base.shape)
        step = controller.step(targets)
        np.testing.assert_allclose(step.errors, np.linalg.norm(step.positions - targets, axis=1), rtol=1e-14)
        assert step.reached is bool(np.all(step.errors <= 1e-4)) and not step.equilibrium
        seen.add(step.reached)
        settled = controller.settled(step)
        assert settled.equilibrium and settled.equilibrium_failure == ""
        np.testing.assert_array_equal(settled.actuation, step.actuation)
        check = model.solve(step.actuation, initial=step.state).state
        np.testing.assert_allclose(settled.positions, model.effector_positions(check), rtol=0, atol=1e-12)
        np.testing.assert_allclose(settled.errors, np.linalg.norm(settled.positions - targets, axis=1), rtol=1e-14)
        assert settled.reached is bool(np.all(settled.errors <= 1e-4))
        assert controller.state is step.state  # the controller continues from its own prediction
    assert seen == {True, False}


def test_ticks_warm_started_by_the_kept_least_effort_model_equal_cold_ones():
    # A controller's DAQP backend keeps the least-effort stage's model and solves each tick's
    # second stage from the working set the last one left (1–2 active-set iterations instead of
    # ~25). The answer is the stage's optimum whatever the start: ticks whose every QP is solved
    # by a new backend (the stage from the first stage's answer) command the same tensions to
    # rounding, and the kept model takes fewer iterations.
    from vertebra.solver.inverse.backends import get_backend

    model = solver.build_model(load("paper_5v_16t"))
    lower, upper = model.actuator_bounds
    lam = np.clip(np.full(len(model.actuator_names), 0.3), lower, upper)
    state = model.solve(lam).state
    warm, cold = (InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
                  for _ in range(2))
    centre = model.effector_positions(state)
    iterations = {"warm": 0, "cold": 0}
    for k in range(25):
        angle = 2 * np.pi * k / 25
        target = centre + 1e-3 * np.array([np.cos(angle), np.sin(angle), 0.0])
        cold.backend = get_backend("daqp")        # nothing kept from the last tick
        a, b = warm.step(target), cold.step(target)
        np.testing.assert_allclose(a.actuation, b.actuation, rtol=0, atol=1e-9 * float(np.abs(b.actuation).max()))
        assert a.status == b.status == "tick"
        if k:
            iterations["warm"] += a.qp.iterations
            iterations["cold"] += b.qp.iterations
    assert len(warm.backend._models) == 1       # the least-effort stage's, set up once
    assert iterations["warm"] < 0.5 * iterations["cold"], iterations
