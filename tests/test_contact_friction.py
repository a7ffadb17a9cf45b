"""Coulomb friction at obstacle contacts (docs/contact.md, "Friction"): μ = 0 is the frictionless
solve, a tip pressed on a plane sticks below μ f_n and slips on the cone above it, loading and
unloading shows hysteresis, the work balances, the scene's field is validated."""

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.core.errors import OptionError, SceneError
from vertebra.solver import contact, contact_friction
from vertebra.solver.timoshenko import Section, timoshenko_compliance

E, NU, RADIUS, LENGTH = 200e9, 0.3, 1e-3, 0.5
EI = E * math.pi * RADIUS ** 4 / 4
P = 1e-3 * EI / LENGTH ** 2          # the press: small deflection (geometric coupling ~1e-6)
C = timoshenko_compliance(LENGTH, E, E / (2 * (1 + NU)), Section.circle(RADIUS, NU))[0, 0]   # tip compliance


def rod(mu=None, obstacle=None, **segment):
    """A steel rod along +z, its frames points (capsule radius 0), its tip touching the face x = 0
    of a box (x from 0 to 2 cm, 2 mm high about the tip: no other frame is near it) at rest, with
    a dead tip force."""
    plane = obstacle or {"type": "box", "center": [0.01, 0.0, LENGTH], "half_extents": [0.01, 0.05, 0.001]}
    if mu is not None:
        plane = dict(plane, friction=mu)
    return solver.build_model(solver.parse_scene({
        "segment": [dict({"type": "beam", "count": 1, "elements": 20, "length": LENGTH, "youngs_modulus": E,
                          "poisson_ratio": NU, "section": {"shape": "circle", "radius": RADIUS},
                          "contact_radius": 0.0}, **segment)],
        "load": [{"vertebra": -1, "force": [0.0, 0.0, 0.0]}], "obstacle": [plane]}))


def load(model, force):
    dead = model.parameters.dead.copy()
    dead[-1, :3] = force
    model.set_parameters(dead=dead)


def tip_contact(result):
    (found,) = [c for c in result.contacts if c.force > 0.0]
    return found


def pressed(mu):
    """The rod pressed on the plane by P (from rest), then its history."""
    model = rod(mu)
    load(model, [P, 0.0, 0.0])
    first = model.solve()
    assert first.converged and tip_contact(first).sliding == "stick"
    return model, first


def loaded(mu, share):
    """The pressed rod (:func:`pressed`) then loaded by ``F = share·μP`` along +y: (the pressed
    result, F, the result, its tip contact)."""
    model, first = pressed(mu)
    F = share * mu * P
    load(model, [P, F, 0.0])
    result = model.solve(history=first.friction)
    assert result.converged
    return first, F, result, tip_contact(result)


def test_mu_zero_is_the_frictionless_solve_bit_for_bit(monkeypatch):
    results = []
    for mu in (None, 0.0):
        model = rod(mu)
        load(model, [P, 0.3 * P, 0.1 * P])
        results.append(model.solve())
    # friction = 0 compiles the same obstacle: the friction module is never called
    def refuse(*args, **kwargs):
        raise AssertionError("contact friction code ran at μ = 0")
    for name in ("solve", "Session", "coulomb", "FrictionalConstraints"):
        monkeypatch.setattr(contact_friction, name, refuse)
    model = rod(0.0)
    load(model, [P, 0.3 * P, 0.1 * P])
    again = model.solve()
    for other in (results[1], again):
        assert np.array_equal(other.state.positions, results[0].state.positions)
        assert np.array_equal(other.state.quaternions, results[0].state.quaternions)
        assert other.iterations == results[0].iterations and other.friction is None
        assert [c.as_dict() for c in other.contacts] == [c.as_dict() for c in results[0].contacts]
    assert "friction" not in again.contacts[0].as_dict()


@pytest.mark.parametrize("mu", [0.2, 0.5])
@pytest.mark.parametrize("share", [0.3, 0.98])
def test_tip_sticks_below_the_threshold(mu, share):
    # pinned by the plane and friction, the tip carries the whole tangential load: f_t = F, f_n = P,
    # nothing moves, for F below the threshold μP
    first, F, result, c = loaded(mu, share)
    assert c.sliding == "stick"
    assert np.max(np.abs(result.state.positions - first.state.positions)) <= 1e-12
    assert math.isclose(c.force, P, rel_tol=1e-9)
    assert math.isclose(-c.friction[1], F, rel_tol=1e-9) and abs(c.friction[2]) <= 1e-12 * P
    assert math.hypot(*c.friction) <= mu * c.force


@pytest.mark.parametrize("mu", [0.2, 0.5])
@pytest.mark.parametrize("share", [1.02, 1.5, 3.0])
def test_tip_slips_on_the_cone_above_the_threshold(mu, share):
    first, F, result, c = loaded(mu, share)
    friction = np.array(c.friction)
    assert c.sliding == "slip"
    assert math.isclose(np.linalg.norm(friction), mu * c.force, rel_tol=1e-9)
    slide = result.state.positions[-1] - first.state.positions[-1]
    slide[0] = 0.0                                           # (along the face)
    # the tip slides along the load, the friction opposes the sliding (maximum dissipation)
    assert slide[1] > 0.0
    assert np.linalg.norm(np.cross(friction, slide)) <= 1e-9 * np.linalg.norm(friction) * np.linalg.norm(slide)
    assert float(friction @ slide) < 0.0
    # the cantilever bent by what friction leaves of the load: (F − μ f_n)·c (Timoshenko tip compliance)
    assert math.isclose(slide[1], (F - mu * c.force) * C, rel_tol=1e-5)
    # and exactly the frictionless rod under the load less the friction force (a dead force at the tip)
    frictionless = rod()
    load(frictionless, np.array([P, F, 0.0]) + friction)
    reference = frictionless.solve(tolerance=1e-12)
    assert np.max(np.abs(reference.state.positions - result.state.positions)) <= 1e-12


def test_from_rest_the_load_path_decides():
    # a single solve from rest under (P, F): proportional loading, so the tip sticks exactly when F ≤ μP
    for share, sliding in ((0.9, "stick"), (1.1, "slip")):
        model = rod(0.3)
        load(model, [P, share * 0.3 * P, 0.0])
        result = model.solve()
        c = tip_contact(result)
        assert result.converged and c.sliding == sliding
        moved = abs(result.state.positions[-1][1])
        assert moved <= 1e-12 if sliding == "stick" else math.isclose(moved, 0.1 * 0.3 * P * C, rel_tol=1e-5)


def test_loading_and_unloading_shows_hysteresis():
    # F: 0 → 1.5μP → 0 → −0.4μP → −1.5μP → 0 with the press held. Out: slides to (F − μP)c = ½μPc;
    # back it sticks there while F − ½μP stays within the cone (F ≥ −½μP); at −1.5μP it slides to −½μPc
    mu = 0.3
    model, first = pressed(mu)
    path = [0.0, 0.5, 1.0, 1.5, 1.0, 0.5, 0.0, -0.4, -1.5, -1.0, 0.0]
    history, tips, states = first.friction, [], []
    for share in path:
        load(model, [P, share * mu * P, 0.0])
        result = model.solve(history=history)
        assert result.converged
        history = result.friction
        tips.append(result.state.positions[-1][1])
        states.append(tip_contact(result).sliding)
    tips = np.array(tips)
    unit = mu * P * C
    assert np.allclose(tips[:3], 0.0, atol=1e-12)                           # stuck until μP
    assert math.isclose(tips[3], 0.5 * unit, rel_tol=1e-5) and states[3] == "slip"
    assert np.allclose(tips[4:7], tips[3], atol=1e-12, rtol=0.0)           # unloading: stuck where it slid
    assert abs(tips[6] - tips[0]) >= 0.49 * unit                              # F = 0, two equilibria
    assert np.allclose(tips[7], tips[3], atol=1e-12, rtol=0.0)              # reversed within 2μP of the peak: stuck
    assert math.isclose(tips[8], -0.5 * unit, rel_tol=1e-5) and states[8] == "slip"
    assert np.allclose(tips[9:], tips[8], atol=1e-12, rtol=0.0)             # and stuck again on the way back
    assert all(s == "stick" for i, s in enumerate(states) if i not in (3, 8))


def test_work_of_the_load_is_the_strain_energy_plus_the_friction_dissipation():
    # F raised from the threshold to 3μP in steps, the tip sliding: ∫F dy = ΔU + ∫|f_t| ds
    mu = 0.3
    model, first = pressed(mu)
    load(model, [P, mu * P, 0.0])
    start = model.solve(history=first.friction)
    history, tip, force = start.friction, [start.state.positions[-1].copy()], [mu * P]
    friction = [np.linalg.norm(tip_contact(start).friction)]
    for F in np.linspace(mu * P, 3 * mu * P, 9)[1:]:
        load(model, [P, F, 0.0])
        result = model.solve(history=history)
        history = result.friction
        tip.append(result.state.positions[-1].copy())
        force.append(F)
        friction.append(np.linalg.norm(tip_contact(result).friction))
    tip, force, friction = np.array(tip), np.array(force), np.array(friction)
    work = float(np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(tip[:, 1])))
    dissipated = float(np.sum(0.5 * (friction[1:] + friction[:-1]) * np.linalg.norm(np.diff(tip[:, 1:], axis=0), axis=1)))

    def strain_energy(result_state, F):
        load(model, [P, F, 0.0])
        return model.potential(result_state) + float(np.array([P, F, 0.0]) @ result_state.positions[-1])

    energy = strain_energy(result.state, force[-1]) - strain_energy(start.state, force[0])
    assert dissipated > 0.5 * work
    assert math.isclose(work, energy + dissipated, rel_tol=1e-6)


def test_a_tip_on_a_sphere_slips_against_its_motion():
    # a curved obstacle: the tip on a sphere beside it, pushed along a tangent at an angle — the
    # friction force is on the cone and opposite the slip along the surface
    sphere = {"type": "sphere", "center": [0.05, 0.0, LENGTH], "radius": 0.05}
    model = rod(0.25, obstacle=sphere)
    load(model, [P, 0.0, 0.0])
    first = model.solve()
    load(model, [P, 0.5 * P, 0.2 * P])
    result = model.solve(history=first.friction)
    assert result.converged
    slide = result.state.positions[-1] - first.state.positions[-1]
    touching = [c for c in result.contacts if c.force > 0.0]       # (the tip's frame, and its link's chord beside it)
    assert touching
    for c in touching:
        friction = np.array(c.friction)
        assert c.sliding == "slip" and math.isclose(np.linalg.norm(friction), 0.25 * c.force, rel_tol=1e-9)
        # in the tangent plane of the anchor (held through the increment), so off the end state's
        # tangent plane by the normal's turn along the slide (|slide| / R)
        assert abs(friction[0]) <= 1e-12 * np.linalg.norm(friction)
        turn = np.linalg.norm(slide) / 0.05
        assert abs(friction @ np.array(c.normal)) <= 1.01 * turn * np.linalg.norm(friction)
        assert float(friction @ slide) < -0.99 * np.linalg.norm(friction) * np.linalg.norm(slide)
        assert c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12


def test_friction_field_is_validated():
    for value, reason in ((-0.1, "must be >= 0"), ("high", "expected a number")):
        with pytest.raises(SceneError) as error:
            rod(value)
        assert "obstacle[0].friction" in str(error.value) and reason in str(error.value)
    with pytest.raises(SceneError, match="did you mean `friction`"):
        solver.parse_scene({"segment": [{"type": "beam", "count": 1, "length": 0.1, "youngs_modulus": E,
                                         "section": {"shape": "circle", "radius": RADIUS}, "contact_radius": 0.0}],
                            "obstacle": [{"type": "plane", "point": [1, 0, 0], "normal": [-1, 0, 0], "frictoin": 0.2}]})


def test_not_combined_with_cable_friction():
    model = solver.build_model(solver.parse_scene({
        "segment": [{"type": "beam", "count": 4, "length": 0.01, "youngs_modulus": 1e9,
                     "section": {"shape": "circle", "radius": RADIUS}, "contact_radius": 0.0}],
        "cable": [{"name": "c", "radius": 0.005, "angle_deg": 0.0, "to": 4, "tension": 1.0, "friction": 0.1}],
        "obstacle": [{"type": "plane", "point": [0.02, 0, 0], "normal": [-1, 0, 0], "friction": 0.2}]}))
    with pytest.raises(OptionError, match="not combined"):
        model.solve()


def test_json_reports_friction_and_sliding():
    from vertebra.solver.report import static_report

    model, first = pressed(0.3)
    load(model, [P, 0.5 * 0.3 * P, 0.0])
    result = model.solve(history=first.friction)
    document = static_report(model, result)
    (tip,) = [c for c in document["contacts"] if c["force"] > 0.0]
    assert tip["sliding"] == "stick" and math.isclose(-tip["friction"][1], 0.15 * P, rel_tol=1e-9)
    assert all(c["sliding"] == "open" and c["friction"] == [0.0, 0.0, 0.0]
               for c in document["contacts"] if c["force"] == 0.0)


# --- inverse and control ticks ----------------------------------------------------------------------


def wall_robot(mu, wall=0.02, tendons=None):
    """The gallery's 16-tendon robot with 12 mm discs beside a wall x = ``wall`` with friction μ
    (``tendons``: the only ones allowed to pull)."""
    import dataclasses

    from test_contact import wall_robot as frictionless_wall

    scene = frictionless_wall(wall).scene
    cables = scene.cables if tendons is None else tuple(
        dataclasses.replace(c, max_tension=c.max_tension if k in tendons else 0.0) for k, c in enumerate(scene.cables))
    obstacles = tuple(dataclasses.replace(o, friction=mu) for o in scene.obstacles)
    return solver.build_model(dataclasses.replace(scene, cables=cables, obstacles=obstacles))


def test_inverse_reaches_targets_that_need_friction():
    # tendons 0 and 4 pull the robot onto a wall with μ = 0.5: its discs hold where they touched,
    # so the tip ends where the frictionless robot's two tendons cannot take it (its inverse stops
    # 2–15 µm short). The converged inverse, each equilibrium the command applied to the friction
    # state it started from and the contacts' tangential forces in its QP, reaches them to 1e-6 m,
    # leaning on the wall with friction, nothing in it
    from vertebra.solver import contact
    from vertebra.solver.inverse import InverseController, InverseSettings

    model, free = wall_robot(0.5, tendons=(0, 4)), wall_robot(0.0, tendons=(0, 4))
    rng = np.random.default_rng(3)
    commands = []
    for _ in range(3):
        a = np.zeros(16)
        a[[0, 4]] = rng.uniform(2.0, 15.0, 2)
        commands.append(a)
    for a in (commands[0], commands[2]):
        result = model.solve(a)
        target = model.effector_positions(result.state)[0]
        assert any(c.force > 0.0 and np.linalg.norm(c.friction) > 0.0 for c in result.contacts)
        controller = InverseController(model, InverseSettings(mode="converged", tolerance=1e-6, time_budget=120.0))
        step = controller.step(target[None])
        assert step.reached and step.equilibrium, (step.status, step.errors)
        assert contact.evaluate(model.trunk.contact, step.state).gap.min() >= -1e-9
        reached = model.solve(step.actuation, history=contact_friction.at_state(model.rest_state))
        assert any(c.force > 0.0 and np.linalg.norm(c.friction) > 0.0 for c in reached.contacts)
        frictionless = InverseController(free, InverseSettings(mode="converged", tolerance=1e-6, time_budget=120.0))
        assert not frictionless.step(target[None]).reached


def test_tick_mode_on_a_frictional_wall_does_not_enter_it():
    # tip targets from rest through a wall with μ = 0.3 (2 cm beyond it) and along it: every tick
    # (an increment from the last, the contacts' tangential forces in its QP) stays out of the
    # wall to 1e-6 m, and the robot reaches the wall
    from test_contact import wall_path

    from vertebra.solver import contact
    from vertebra.solver.inverse import InverseController, InverseSettings

    wall = 0.02
    model = wall_robot(0.3, wall)
    controller = InverseController(model, InverseSettings(mode="tick", tolerance=1e-4))
    path = wall_path(model.effector_positions(controller.state)[0], wall)[:44]
    touched = False
    for k, target in enumerate(path):
        step = controller.step(target[None])
        gaps = contact.evaluate(model.trunk.contact, step.state).gap
        assert gaps.min() >= -1e-6, k
        touched |= bool(gaps.min() <= 1e-6)
        assert isinstance(step.friction, contact_friction.ContactFriction)
    assert touched


def test_a_cabled_robot_on_a_frictional_wall_reports_and_writes():
    # result.friction is the contacts' state, not a cable's: the JSON lists the cables with their
    # tension, the contacts with their friction, and the ParaView file is written
    from vertebra.solver.paraview import trunk_polydata
    from vertebra.solver.report import static_report

    model = wall_robot(0.5, tendons=(0, 4))
    a = np.zeros(16)
    a[[0, 4]] = 3.0, 5.0
    result = model.solve(a)
    document = static_report(model, result)
    assert len(document["cables"]) == 16
    assert any(c["force"] > 0.0 and c["sliding"] in ("stick", "slip") for c in document["contacts"])
    data = trunk_polydata(model, result.state, result.actuation, friction=result.friction, contacts=result.contacts)
    assert data is not None


# --- the frictional problem in constraint space (contact_friction.coulomb) ----------------------

def frictional_problem(rng, pressing=3, far=12, mu=0.3):
    """A constraint-space problem ``w = b + Wλ``: ``pressing`` frictional contacts whose linearised
    gaps are negative, then ``far`` frictionless candidates well open; ``W`` positive definite
    with its normal–tangential coupling (a lever arm), as ``G K⁻¹ Gᵀ`` is."""
    m = pressing + far
    n = m + 2 * pressing
    G = rng.normal(size=(n, 3 * n))
    W = G @ G.T / (3 * n) + 0.05 * np.eye(n)
    b = np.concatenate([-rng.uniform(0.5, 1.0, pressing), rng.uniform(5.0, 10.0, far),
                        rng.normal(scale=0.5, size=2 * pressing)])
    return W, b, m, np.arange(pressing), np.full(pressing, mu)


def law_violation(W, b, m, fr, mu, lam, status):
    """How far ``lam`` is from the frictional law (forces and gaps of the scale 1)."""
    w = b + W @ lam
    worst = max(float(np.abs(np.minimum(lam[:m], w[:m])).max()), float(-lam[:m].min()), float(-w[:m].min()))
    for c, i in enumerate(fr.tolist()):
        f_t, w_t = lam[m + 2 * c:m + 2 * c + 2], w[m + 2 * c:m + 2 * c + 2]
        worst = max(worst, float(np.hypot(*f_t)) - mu[c] * lam[i])          # inside the cone
        if status.closed[i] and status.slip[c]:
            d = status.direction[c]
            worst = max(worst, float(np.abs(f_t + mu[c] * lam[i] * d).max()),      # on its edge, against d
                        abs(w_t[0] * d[1] - w_t[1] * d[0]), -float(w_t @ d))     # sliding along d
        elif status.closed[i]:
            worst = max(worst, float(np.abs(w_t).max()))                          # stuck
    return worst


@pytest.mark.parametrize("mu", [0.1, 0.3, 1.0])
def test_the_frictional_problem_is_solved_to_the_law_and_agrees_with_the_active_set(mu):
    # semismooth Newton on the Alart–Curnier equations (on the working set of the contacts that
    # press) answers within the rounding of the law; where the answer is unique (small μ), it is
    # the active set's on the whole problem
    rng = np.random.default_rng(11)
    for _ in range(20):
        W, b, m, fr, mu_c = frictional_problem(rng, mu=mu)
        lam, status = contact_friction.coulomb(W, b, m, fr, mu_c)
        assert law_violation(W, b, m, fr, mu_c, lam, status) <= 1e-12
        assert np.all(lam[3:m] == 0.0) and not status.closed[3:].any()           # far contacts: no force
        if mu <= 0.1:
            other, _ = contact_friction._active_set(W, b, m, fr, mu_c)
            assert np.allclose(lam, other, rtol=0.0, atol=1e-10)


def test_a_contact_outside_the_working_set_joins_when_the_answer_closes_it():
    # contact 1 is open at no force (b > 0) but pressing contact 0 pulls it shut (W₁₀ < 0): the
    # working set starts with contact 0 alone and takes 1 in when the answer closes it
    W = np.array([[1.0, -0.8, 0.1, 0.0], [-0.8, 1.0, 0.0, 0.05], [0.1, 0.0, 2.0, 0.2], [0.0, 0.05, 0.2, 2.0]])
    b = np.array([-1.0, 0.2, 0.3, -0.1])
    lam, status = contact_friction.coulomb(W, b, 2, np.array([0]), np.array([0.5]))
    assert status.closed.tolist() == [True, True]
    assert law_violation(W, b, 2, np.array([0]), np.array([0.5]), lam, status) <= 1e-12


def test_slip_directions_converge_with_the_exact_jacobian(monkeypatch):
    # the slipping contacts' directions by Newton on w_t × d with ∂λ/∂θ = −A⁻¹(∂A/∂θ)λ: quadratic,
    # a handful of factorisations for three sliding contacts, each started opposite its stuck
    # tangential force as the active set starts it (differences took one more solve per contact
    # each iteration, and stopped at their own accuracy)
    import scipy.linalg

    rng = np.random.default_rng(5)
    W, b, m, fr, mu = frictional_problem(rng, far=0, mu=0.2)
    b[m:] *= 20.0                                       # far beyond the cone: all three slide
    stuck = contact_friction.Friction(np.ones(m, bool), np.zeros(3, bool), np.tile([1.0, 0.0], (3, 1)))
    f_t = contact_friction._solve_set(W, b, m, fr, mu, stuck)[m:].reshape(-1, 2)
    status = contact_friction.Friction(np.ones(m, bool), np.ones(3, bool), -f_t / np.linalg.norm(f_t, axis=1)[:, None])
    calls = []
    factor = scipy.linalg.lu_factor
    monkeypatch.setattr(scipy.linalg, "lu_factor", lambda *args, **kwargs: calls.append(1) or factor(*args, **kwargs))
    lam = contact_friction._directions(W, b, m, fr, mu, status, float(np.abs(b).max()))
    w = b + W @ lam
    d = status.direction
    cross = w[m::2] * d[:, 1] - w[m + 1::2] * d[:, 0]
    assert np.abs(cross).max() <= contact_friction.DIRECTION_TOLERANCE * np.abs(b).max()
    assert np.all(np.add.reduce(w[m:].reshape(-1, 2) * d, 1) > 0.0)        # slip along d
    assert np.allclose(lam[m:].reshape(-1, 2), -mu[:, None] * lam[:m, None] * d, rtol=0.0, atol=1e-12)
    assert len(calls) <= 8


def test_springs_on_frictional_contacts_leave_the_step_its_forces():
    # an indefinite tangent is factored with stiff springs along the pressed contacts (docs/contact.md,
    # Solver, item 3). About the step Gp, a spring along a contact whose gap c ≠ 0 carries −k·c of
    # its force, and the multiplier k·c more — which the friction law then takes for the normal
    # force: a cone k·c/f_n times too wide. Centred on the linearised gap c + Gp it carries
    # nothing where the step closes the gap. A state 1e-12 m into the box (as near convergence,
    # where the gaps are closed to ~1e-12 of the length): the stiffened step's normal force is the
    # step's without springs to 2e-3 (the factor with springs 1e11 N/m stiff resolves k·c to ~1e-6
    # of itself), about the step it was 190 times the force
    from vertebra.solver.potential import evaluate, tangent

    model, first = pressed(0.3)
    load(model, [P, 0.5 * 0.3 * P, 0.0])
    trunk = model.trunk
    state = first.state.copy()
    state.positions[1:, 0] += 1e-12
    loads = model.loads(model.actuation(None), 1.0)
    constraints = contact_friction.Session(trunk, first.state, first.friction).constraints(trunk)
    ev = evaluate(trunk, state, loads)
    r = -ev.gradient[1:].reshape(-1)
    constraints.accept(constraints.step(constraints.lagrangian(tangent(trunk, ev), state).factor(0.0)[0], r, state))
    matrix = constraints.lagrangian(tangent(trunk, ev), state)
    free = constraints.step(matrix.factor(0.0)[0], r, state)
    stiff = constraints.stiffened(matrix, state, contact.STABILITY_SPRING)
    sprung = constraints.step(stiff.factor(0.0)[0], r, state)
    constraints.centre = None
    about_the_step = constraints.step(stiff.factor(0.0)[0], r, state)

    def forces(step):
        return {tuple(k): f for k, f in zip(step.contacts.key.tolist(), step.multipliers) if f != 0.0}

    normal = tuple(constraints.keys[0].tolist())
    assert forces(free).keys() == forces(sprung).keys() and len(forces(free)) == 3     # pressed, two tangential
    assert math.isclose(forces(free)[normal], P, rel_tol=1e-9)
    assert math.isclose(forces(sprung)[normal], P, rel_tol=2e-3)
    assert forces(about_the_step)[normal] > 100.0 * P


def test_a_slipping_contact_keeps_the_direction_solved_with_its_forces():
    # the contact fuzz's seed 59 (a tendon robot's disc slipping on a box, μ = 1): the step's
    # exact solve turns the slip direction by ~1e-8 rad from the Alart–Curnier one; the status
    # must keep that direction, else the converged slip lies off it beyond ACTIVE_GAP and the
    # state is never feasible (1000 iterations at a residual of 1e-11)
    import json
    from pathlib import Path

    scene = json.loads((Path(__file__).parent / "reference" / "contact_fuzz_seed59.json").read_text())
    model = solver.build_model(solver.parse_scene(scene))
    result = model.solve(max_iterations=30, raise_on_failure=False)
    assert result.converged and result.iterations <= 20, result.message
    sliding = [c for c in result.contacts if c.force > 0.0 and c.sliding == "slip"]
    assert sliding
    for c in sliding:
        assert math.hypot(*c.friction) <= c.force * (1 + 1e-9)


def test_a_slipping_contact_stiffens_the_tangent_across_its_slip():
    # the contact fuzz's seed 62 (a capsule trunk slipping over a capsule, μ = 1): the Lagrangian's
    # tangent is indefinite on the free directions where the friction's stiffness across the slip
    # (μ f_n/|s|) is left out; springs to the stability value did not help, the shift damped every
    # step (100-iteration stages at a residual of 1e-5, over 20 s)
    import json
    from pathlib import Path

    scene = json.loads((Path(__file__).parent / "reference" / "contact_fuzz_seed62.json").read_text())
    model = solver.build_model(solver.parse_scene(scene))
    result = model.solve(max_iterations=40, raise_on_failure=False)
    assert result.converged and result.iterations <= 30, result.message
    (c,) = [c for c in result.contacts if c.force > 0.0]
    assert c.sliding == "slip" and math.isclose(math.hypot(*c.friction), c.force, rel_tol=1e-9)



def test_a_trial_that_takes_an_open_contact_into_its_obstacle_has_outrun_the_step():
    # the line search refuses a trial that takes an obstacle contact the step's problem left open
    # (no force) into its obstacle beyond the tolerance, deeper than it was: its linearised gap
    # kept it open, so the step outran the linearisation (the contact fuzz's seed 36, a disc in a
    # wedge between a box and a mesh pressed on each in turn: 140 iterations → 62; seed 74 over
    # 20 s → 39 iterations); a pressed contact, a contact moved out, or one no deeper are not refused
    from types import SimpleNamespace

    from vertebra.solver import globalise

    model = rod()
    trunk = model.trunk
    constraints = contact.Constraints(trunk)
    stage = SimpleNamespace(constraints=constraints, trunk=trunk)
    state = trunk.rest_state.copy()
    tip = contact.evaluate(trunk.contact, state)
    assert tip.count and abs(float(tip.gap.min())) <= 1e-12          # the tip on the box's face

    def moved(dx):
        trial = state.copy()
        trial.positions[-1, 0] += dx
        return trial

    outrun = globalise._outrun_check(stage, state)
    assert outrun(moved(1e-6))                    # 1 µm into the box, the contact open in the step
    assert not outrun(moved(-1e-6))               # away from it
    assert not outrun(moved(1e-14))               # within the converged states' tolerance
    constraints.keys = tip.key[np.argmin(tip.gap)][None]
    constraints.multipliers = np.array([1.0])
    assert not globalise._outrun_check(stage, state)(moved(1e-6))   # pressed in the step: its gap is held
