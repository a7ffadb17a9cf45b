"""The nonlinear-entry link kind (vertebra.solver.kinds.fitted): links that store a catalogue
entry's fitted energy ψ(s, p).

Checked here: its forces and exact tangent against the complex-step reference of the same
polynomial energy (an independent, term-by-term implementation), rest and small-load results
against the linear entry, objectivity, the chambers' Jacobian and volume growth against finite
differences of forward solves, the chain against the fitted energies' own yardstick chain and
against the full nonlinear FE of the same trunk, and the range diagnostics (result, JSON, CLI,
inverse steps, the inflation limit point).

The energies are the synthetic fits of :mod:`fitted_energies` (a convex quartic plus seeded
cubic and quartic terms, pressure couplings included), except the FE comparison, which designs a
coarse neo-Hookean rod entry (~6 s).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from fitted_energies import ROD, ROD_MESH, nonlinear_rod, with_energy
from reference.complex_step import pair_tangent, polynomial_link_gradient
from test_solver_actuation import synthetic_entry
from vertebra import solver
from vertebra.core import lie
from vertebra.solver.kinds import RangeExcess
from vertebra.solver.kinds.fitted import FittedEnergy
from vertebra.core.lie import qexp, qmul, qrotate, se3_exp
from vertebra.solver.links import Links, link_tangent
from vertebra.solver.report import static_report
from vertebra.core.energy import fold_map, linear_terms
from vertebra.core.errors import ConvergenceError

SLICE = synthetic_entry()                       # 2 cavities, 30 mm, soft rod-like compliance
FITTED = with_energy(SLICE, strength=0.3)


def _model(entry, count=4, *, chambers=(), loads=(), gravity=None, base=None, solver_settings=None, extra=None):
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": count, "vertebra": {"mass": 0.005}}],
            "chamber": [dict(c) for c in chambers],
            "load": [dict(load) for load in loads],
            "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.004, 0.0]}]}
    if gravity is not None:
        data["gravity"] = {"vector": list(gravity)}
    if base is not None:
        data["base"] = base
    if solver_settings is not None:
        data["solver"] = solver_settings
    data.update(extra or {})
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


CHAMBERS = ({"name": "c0", "cavity": 0, "from": 1, "to": 4, "pressure": 4e4, "max_pressure": 1.4e5},
            {"name": "c1", "cavity": 1, "from": 2, "to": 3, "pressure": 1.5e4, "max_pressure": 1.4e5})


def test_nonlinear_entries_make_fitted_links_and_linear_entries_stay_quadratic():
    fitted = _model(FITTED)
    assert [type(e).__name__ for e in fitted.trunk.links.energies] == ["FittedEnergy"]
    linear = _model(SLICE)
    assert [type(e).__name__ for e in linear.trunk.links.energies] == ["QuadraticEnergy"]
    # stripping the energy (what a study of linear vs nonlinear entries does) gives the linear links
    stripped = _model(dataclasses.replace(FITTED, energy=None))
    assert [type(e).__name__ for e in stripped.trunk.links.energies] == ["QuadraticEnergy"]


def _frame_pairs(rng, rest, angle, n):
    """Frames a at random poses and b = a·exp(ξ₀ + δ) with |δ_φ| ~ angle."""
    qa = qexp(rng.normal(size=(n, 3)))
    xa = rng.normal(size=(n, 3)) * 0.02
    delta = rng.normal(size=(n, 6)) * np.r_[[0.002] * 3, [angle] * 3]
    q, p = se3_exp(rest + delta)
    return qa, xa, qmul(qa, q), xa + qrotate(qa, p)


@pytest.mark.parametrize("angle", [0.0, 0.3, 0.9])
def test_fitted_link_forces_and_tangent_equal_the_complex_step_reference(angle):
    # the links of a fitted entry at two chambers' pressures (three distinct pressure rows:
    # 0/0, c0 only, c0 + c1); the reference restricts ψ to each link's pressures term by term
    # and differentiates its gradient by the complex step. Same physics, different rounding:
    # measured ≤ 3e-15 (gradient, energy) and ≤ 1e-13 (tangent) relative; 1e-12 catches any error.
    # The strain box is widened tenfold: the reference is the polynomial, and no state here takes
    # the tail beyond the box (test_range_extension.py checks the tail)
    model = _model(_widened(FITTED, 10.0), count=5, chambers=CHAMBERS)
    energy = model.trunk.links.energies[0]
    pressures = np.array([4e4, 1.5e4])
    prepared = energy.prepare(pressures)
    n = energy.links.size
    qa, xa, qb, xb = _frame_pairs(np.random.default_rng(int(10 * angle) + 1), energy.rest, angle, n)
    links = Links.of(qa, xa, qb, xb)
    total, w, kept = energy.response(links.xi, prepared)
    g = links.gradient(w)
    H = link_tangent(links, w, energy.material_tangent(links.xi, prepared, kept), g)

    fit = FITTED.energy
    K, S, V = linear_terms(FITTED.compliance, FITTED.rest_translation)
    cavity = model.trunk.links.energies[0].groups
    p_link = np.zeros((n, 2))
    for group in cavity:
        p_link[group.rows] = group.incidence @ pressures
    g_ref, H_ref, energies = np.empty((n, 12)), np.empty((n, 12, 12)), np.empty(n)
    for k in range(n):
        u_p = p_link[k] / fit.scales[6:]
        coefficients = fit.coefficients * np.prod(u_p ** fit.exponents[:, 6:], axis=1)
        args = (fit.exponents[:, :6], coefficients, fit.scales[:6], K[None], energy.rest[k:k + 1],
                (S @ p_link[k])[None])
        g_ref[k], e_k, H_ref[k] = pair_tangent(polynomial_link_gradient, qa[k:k + 1], xa[k:k + 1], qb[k:k + 1],
                                               xb[k:k + 1], *args)[:3]
        energies[k] = float(np.ravel(e_k)[0]) - 0.5 * p_link[k] @ V @ p_link[k]
    assert np.abs(g - g_ref).max() <= 1e-12 * np.abs(g_ref).max()
    assert abs(total - energies.sum()) <= 1e-12 * np.abs(energies).sum()
    assert np.abs(H - H_ref).max() <= 1e-12 * np.abs(H_ref).max()
    # and the fit matters here: the linear entry's tangent differs (measured ≥ 1e-3 relative at 0.3 rad)
    if angle > 0.0:
        linear = K[None] + np.zeros((n, 6, 6))
        H_lin = link_tangent(links, w, linear, g)
        assert np.abs(H_lin - H).max() > 1e-4 * np.abs(H).max()


def test_fitted_links_are_objective():
    # a rigid motion of both frames changes no link energy: the forces of a link balance
    # (Σ f = 0, Σ (m + x × f) = 0 about the world origin) to rounding
    model = _model(FITTED, count=5, chambers=CHAMBERS)
    energy = model.trunk.links.energies[0]
    prepared = energy.prepare(np.array([4e4, 1.5e4]))
    qa, xa, qb, xb = _frame_pairs(np.random.default_rng(5), energy.rest, 0.7, energy.links.size)
    links = Links.of(qa, xa, qb, xb)
    total, w, _ = energy.response(links.xi, prepared)
    g = links.gradient(w)
    force = g[:, 0:3] + g[:, 6:9]
    moment = g[:, 3:6] + g[:, 9:12] + np.cross(xa, g[:, 0:3]) + np.cross(xb, g[:, 6:9])
    scale = np.abs(g[:, :3]).max()
    assert np.abs(force).max() <= 1e-13 * scale
    assert np.abs(moment).max() <= 1e-13 * scale * (1.0 + np.abs(np.r_[xa, xb]).max())
    # the same relative poses turned and moved as a whole: the same energy
    turn, shift = qexp(np.array([0.3, -1.1, 0.5])), np.array([0.1, -0.2, 0.05])
    moved = Links.of(qmul(np.broadcast_to(turn, qa.shape), qa), qrotate(turn, xa) + shift,
                     qmul(np.broadcast_to(turn, qb.shape), qb), qrotate(turn, xb) + shift)
    assert energy.response(moved.xi, prepared)[0] == pytest.approx(total, rel=1e-13)


def test_a_turned_and_moved_trunk_finds_the_turned_equilibrium():
    # base pose, gravity and dead loads turned by R and moved by t: the equilibrium is R x + t
    # (Newton to 1e-12; measured ≤ 1e-14 of the length)
    loads = ({"vertebra": -1, "force": [6.0, 1.8, -1.2]}, {"vertebra": 2, "force": [0.0, -3.6, 0.0]})
    gravity = np.array([0.0, -9.81, -2.0])
    settings = {"tolerance": 1e-12}
    first = _model(FITTED, chambers=CHAMBERS, loads=loads, gravity=gravity, solver_settings=settings)
    turn, shift = qexp(np.array([0.4, 0.2, -0.9])), np.array([0.2, 0.1, -0.3])
    turned_loads = tuple({"vertebra": load["vertebra"], "force": qrotate(turn, np.array(load["force"])).tolist()}
                         for load in loads)
    second = _model(FITTED, chambers=CHAMBERS, loads=turned_loads, gravity=qrotate(turn, gravity),
                    solver_settings=settings, base={"position": shift.tolist(), "quaternion": turn.tolist()})
    a, b = first.solve(), second.solve()
    assert a.converged and b.converged
    bend = np.degrees(np.linalg.norm(lie.qlog(a.state.quaternions[-1])))
    assert bend > 20.0                                   # a nonlinear state, not the rest pose
    assert np.abs(qrotate(turn, a.state.positions) + shift - b.state.positions).max() <= 1e-12 * first.length_scale


def test_rest_linearisation_is_the_linear_entry_and_small_loads_differ_at_second_order():
    # ψ_nl has no term below degree 3: at rest the tangent, the chamber columns and the effector
    # compliance are the linear entry's to rounding (K from the same compliance through two
    # codes: measured ≤ 3e-15 relative)
    chambers = CHAMBERS
    fitted, linear = _model(FITTED, chambers=chambers), _model(SLICE, chambers=chambers)
    zero = np.zeros(2)
    a, b = fitted.linearise(fitted.rest_state, zero), linear.linearise(linear.rest_state, zero)
    assert np.abs(a.actuator_forces - b.actuator_forces).max() <= 1e-13 * np.abs(b.actuator_forces).max()
    rhs = np.random.default_rng(2).normal(size=fitted.n_dof)
    assert np.abs(a.solve(rhs) - b.solve(rhs)).max() <= 1e-12 * np.abs(b.solve(rhs)).max()
    # small loads: the links' rotations (carried strains, exact relative to themselves) differ
    # from the linear entry's by the fit's cubic terms, in proportion to the load (second order:
    # the ratio of the relative differences is the ratio of the loads, 10, within the quartic
    # terms' share; measured 0.054 × the rotation per link); at 1e-6 N (3e-8 rad) that is below
    # 1e-9, where Newton's correction of the linear step is below the resolution of the poses
    differences = []
    for force in (1e-4, 1e-3, 1e-2, 1e-6):
        settings = {"tolerance": 1e-13}
        loads = ({"vertebra": -1, "force": [force, 0.5 * force, 0.0]},)
        rot = []
        for entry in (FITTED, SLICE):
            result = _model(entry, loads=loads, solver_settings=settings).solve()
            rot.append(result.state.carried_strains().xi[:, 3:])
        differences.append(np.abs(rot[0] - rot[1]).max() / np.abs(rot[1]).max())
    assert differences[3] <= 1e-9
    assert 9.0 < differences[1] / differences[0] < 11.0 and 9.0 < differences[2] / differences[1] < 11.0


def _solve(model, actuation, initial=None):
    return model.solve(actuation, initial=initial, tolerance=1e-13)


def test_chamber_jacobian_and_volume_growth_match_differences_of_forward_solves():
    # at a bent equilibrium under two chambers and a tip load: the effector sensitivity
    # Je K⁻¹ B predicted by the linearisation, and the volume growth's total derivative
    # Ja K⁻¹ B + ∂ΔV/∂p, against central differences of forward solves (h = 1e-3 of the pressure:
    # truncation ~1e-6 relative, solves to 1e-13); tolerance 1e-5 relative
    model = _model(FITTED, chambers=CHAMBERS, loads=({"vertebra": -1, "force": [2.0, 0.0, 0.0]},))
    actuation = np.array([6e4, 2.5e4])
    result = _solve(model, actuation)
    lin = model.linearise(result.state, actuation)
    dq = lin.solve(lin.actuator_forces)                       # (n_dof, 2)
    predicted = lin.effector_jacobian @ dq
    growth = model.chamber_volume_growth(result.state, actuation)
    for j in range(2):
        h = 1e-3 * actuation[j]
        step = np.eye(2)[j] * h
        plus, minus = _solve(model, actuation + step, result.state), _solve(model, actuation - step, result.state)
        numeric = (model.effector_positions(plus.state) - model.effector_positions(minus.state)) / (2 * h)
        assert np.abs(numeric.reshape(-1) - predicted[:, j]).max() <= 1e-5 * np.abs(predicted[:, j]).max()
        # ∂ΔV/∂p at the fixed state, then the total derivative
        direct = (model.chamber_volume_growth(result.state, actuation + step)
                  - model.chamber_volume_growth(result.state, actuation - step)) / (2 * h)
        total = lin.actuator_jacobian @ dq[:, j] + direct
        numeric = (model.chamber_volume_growth(plus.state, actuation + step)
                   - model.chamber_volume_growth(minus.state, actuation - step)) / (2 * h)
        assert np.abs(numeric - total).max() <= 1e-5 * np.abs(total).max()
    # the fit's pressure dependence is used: the linear entry's growth differs (measured 6 %)
    linear = _model(SLICE, chambers=CHAMBERS, loads=({"vertebra": -1, "force": [2.0, 0.0, 0.0]},))
    linear_growth = linear.chamber_volume_growth(_solve(linear, actuation).state, actuation)
    assert np.abs(linear_growth - growth).max() > 1e-3 * np.abs(growth).max()


def test_pressurised_chain_equals_the_yardstick_chain_of_the_same_energies():
    # the runtime (frames, links, chambers → cavities, banded Newton) against tests/reference/energy_chain.py
    # (strains as unknowns, dense Newton, no runtime code), the same fitted energies: tip pose and
    # volume growth to solver tolerance (measured ≤ 4e-15 of the length, ≤ 1e-11 relative)
    from reference.energy_chain import EntryEnergy, PointLoad, solve_chain

    force = [2.0, -3.0, 0.5]
    model = _model(FITTED, chambers=CHAMBERS, loads=({"vertebra": -1, "force": force},),
                   solver_settings={"tolerance": 1e-13})
    actuation = np.array([8e4, 3e4])
    result = model.solve(actuation)
    cavities = [np.array([8e4, 0.0]), np.array([8e4, 3e4]), np.array([8e4, 3e4]), np.array([8e4, 0.0])]
    chain = solve_chain([EntryEnergy(FITTED)] * 4, [PointLoad(-1, tuple(force))], pressures=cavities,
                        tolerance=1e-14)
    assert np.abs(result.state.positions[model.vertebra_frames] - chain.positions).max() <= 1e-12 * model.length_scale
    growth = model.chamber_volume_growth(result.state, actuation)
    expected = [sum(v[0] for v in chain.volume_growth), sum(v[1] for v in chain.volume_growth[1:3])]  # c1: 2–3
    assert growth == pytest.approx(expected, rel=1e-9)
    assert np.degrees(np.linalg.norm(lie.qlog(result.state.quaternions[-1]))) > 15.0


def _widened(entry, factor):
    """``entry`` whose fitted strain box is ``factor`` times as wide."""
    fitted_range = dataclasses.replace(entry.energy.range, pose_lower=factor * entry.energy.range.pose_lower,
                                       pose_upper=factor * entry.energy.range.pose_upper)
    return dataclasses.replace(entry, energy=dataclasses.replace(entry.energy, range=fitted_range))


def _narrow(entry, bending):
    """``entry`` whose fitted range admits only ``bending`` rad of bending strain."""
    fitted_range = dataclasses.replace(entry.energy.range,
                                       pose_upper=np.r_[entry.energy.range.pose_upper[:2], bending,
                                                        entry.energy.range.pose_upper[3]])
    return dataclasses.replace(entry, energy=dataclasses.replace(entry.energy, range=fitted_range))


def test_states_outside_the_fitted_range_are_reported():
    entry = _narrow(FITTED, 0.05)
    tip = ({"vertebra": -1, "moment": [0.0, 0.25, 0.0]},)
    model = _model(entry, loads=tip, chambers=CHAMBERS)
    small = model.solve(np.zeros(2))
    quiet = _model(entry, loads=({"vertebra": -1, "moment": [0.0, 1e-4, 0.0]},)).solve()
    assert quiet.out_of_range == ()
    bent = small.state.carried_strains().xi[:, 3:]
    bending = np.hypot(bent[:, 0], bent[:, 1])
    assert bending.max() > 0.05                            # the tip moment bends every link beyond it
    flagged = [e for e in small.out_of_range if e.quantity == "bending strain"]
    assert sorted(e.link for e in flagged) == np.flatnonzero(bending > 0.05).tolist()
    worst = max(flagged, key=lambda e: e.excess)
    assert worst.value == pytest.approx(bending.max(), rel=1e-12)
    assert worst.upper == pytest.approx(0.05) and worst.excess == pytest.approx((bending.max() - 0.05) / 0.05)
    assert (worst.segment, worst.source) == (0, entry.name)
    assert worst.vertebrae == (worst.link, worst.link + 1)             # one link per repetition
    # in the simulate JSON, machine-readable
    document = json.loads(json.dumps(static_report(model, small)))
    rows = document["diagnostics"]["out_of_range"]
    assert len(rows) == len(small.out_of_range) and rows[0].keys() >= {"link", "segment", "vertebrae", "entry",
                                                                        "quantity", "value", "lower", "upper", "excess"}
    # pressures beyond the sampled ones (below the limit point): the cavity pressure is flagged
    high = model.solve(np.array([1.6e5, 0.0]))
    pressed = [e for e in high.out_of_range if e.quantity == "cavity 0 pressure"]
    assert sorted(e.link for e in pressed) == [0, 1, 2, 3] and pressed[0].value == pytest.approx(1.6e5)
    assert isinstance(pressed[0], RangeExcess) and "cavity 0 pressure" in str(pressed[0])


def test_pressures_beyond_the_inflation_limit_point_are_refused():
    entry = with_energy(SLICE, strength=0.3, pressure=1.0e5, fold_pressure=1.3e5)
    model = _model(entry, chambers=CHAMBERS)
    below = model.solve(np.array([1.2e5, 0.0]))
    assert below.converged
    assert {e.quantity for e in below.out_of_range} == {"cavity 0 pressure"}
    # the entry stores no limit point met while sampling: the refusal names the fit's fold
    # pressure and the pressures sampled, and claims no ballooning
    with pytest.raises(ConvergenceError, match="fold pressure of its fitted energy's pressure map") as refused:
        model.solve(np.array([1.3e5, 0.0]))
    message = str(refused.value)
    assert "130000 Pa" in message and "no limit point was met while sampling, which reached 100000 Pa" in message
    assert "balloons" not in message
    # the fold map is what the kernel uses below the limit (its derivative grows without bound)
    assert fold_map(np.array([1.29e5]), 1.3e5)[1][0] > 10.0
    # an entry whose sampling met the limit point says so
    met = _model(with_energy(SLICE, strength=0.3, pressure=1.0e5, fold_pressure=1.3e5, limit_pressure=1.25e5),
                 chambers=CHAMBERS)
    with pytest.raises(ConvergenceError, match=r"inflation limit point met while its energy was sampled \(125000 Pa"):
        met.solve(np.array([1.26e5, 0.0]))


def test_inverse_steps_report_the_range():
    # a chamber bends the trunk towards a target beyond the fitted bending (0.01 rad per link;
    # reaching it takes ~0.015): the steps say so, at their states (tick: settled equilibria)
    from vertebra.solver.inverse import InverseController, InverseSettings

    model = _model(_narrow(FITTED, 0.01), chambers=CHAMBERS)
    rest_tip = model.effector_positions(model.rest_state)[0]
    for mode in ("tick", "converged"):
        controller = InverseController(model, InverseSettings(mode=mode), actuation=np.zeros(2))
        steps = controller.track([[rest_tip + np.array([0.003, 0.0, 0.0])]] * 4, settle=True)
        assert steps[-1].equilibrium
        assert any(e.quantity == "bending strain" for e in steps[-1].out_of_range)
        again = model.solve(steps[-1].actuation).out_of_range            # the same equilibrium, solved again
        assert [(e.link, e.quantity) for e in steps[-1].out_of_range] == [(e.link, e.quantity) for e in again]
        assert [e.value for e in steps[-1].out_of_range] == pytest.approx([e.value for e in again], rel=1e-9)
    near = InverseController(model, InverseSettings(), actuation=np.zeros(2)).step([rest_tip + [0.0005, 0.0, 0.0]])
    assert near.equilibrium and near.out_of_range == ()         # a small bend stays inside


# ---------------------------------------------------------------------------- against the FE

@pytest.fixture(scope="module")
def rod():
    return nonlinear_rod()


@pytest.mark.parametrize("case", ["3d-two", "planar-three"])
def test_chain_of_nonlinear_entries_against_the_full_nonlinear_fe(rod, case):
    """Trunks of the designed rod entry against the full nonlinear FE of the same trunk (same
    mesh and material, rigid vertebrae): the runtime's tip within 0.1 % of the trunk length.
    Why 0.1 %: the fit's held-out load error on this coarse sampling is ~0.7 % of the load
    range (stored in the entry, checked ≤ 2 % below), and a load error of that size moves a
    tip by well under 0.1 % of the length at these angles (measured 0.009 % at 44°, 0.02 % at
    the planar case's ~60°); the linear entries are ≥ 0.3 % off (measured 0.54 % and 1.2 %), so
    the test tells the two apart. The runtime equals the fit's yardstick chain to solver
    tolerance (the same energies: 1e-9 of the length)."""
    from reference.energy_chain import EntryEnergy, PointLoad, solve_chain
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads
    from vertebra.designer.nonlinear_condensation import FamilySolid

    assert rod.energy.fit_error["held_out"]["load_max"] < 0.02
    if case == "3d-two":
        count, forces = 2, {1: [0.0, 1.5, 0.0], 2: [2.0, 0.0, -0.5]}
    else:
        count, forces = 3, {3: [1.2, 0.0, 0.0]}
    loads = tuple({"vertebra": k, "force": f} for k, f in forces.items())
    nonlinear = _model(rod, count=count, loads=loads).solve()
    linear = _model(dataclasses.replace(rod, energy=None), count=count, loads=loads).solve()
    segment = FamilySolid("rod", json.dumps(rod.parameters, sort_keys=True), ROD_MESH, 2, "neo_hookean").build()
    reference = NonlinearTrunk([segment] * count).solve(TrunkLoads(forces={k: np.array(f) for k, f in forces.items()}))
    chain = solve_chain([EntryEnergy(rod)] * count, [PointLoad(k, tuple(f)) for k, f in forces.items()])
    length = count * ROD["length"]
    tip = nonlinear.state.positions[-1]
    angle = np.degrees(np.linalg.norm(lie.qlog(nonlinear.state.quaternions[-1])))
    assert reference.converged and nonlinear.converged and 35.0 < angle < 80.0
    assert np.linalg.norm(tip - chain.tip_position) <= 1e-9 * length
    assert np.linalg.norm(tip - reference.positions[-1]) <= 1e-3 * length
    assert np.linalg.norm(linear.state.positions[-1] - reference.positions[-1]) >= 3e-3 * length
    assert nonlinear.out_of_range == ()


def test_simulate_cli_warns_and_reports_the_range(tmp_path):
    """``vertebra simulate``: a warning on stderr naming the link, segment, vertebrae and quantity;
    the JSON's ``diagnostics.out_of_range``; the exit code stays that of convergence."""
    import subprocess
    import sys

    from vertebra.store import catalogue

    entry = _narrow(FITTED, 0.05)
    catalogue.add_entry(tmp_path / "cat.h5", entry)
    (tmp_path / "scene.toml").write_text(f"""
[catalogue]
path = "cat.h5"
[[segment]]
type = "entry"
entry = "{entry.name}"
count = 4
[[load]]
vertebra = -1
moment = [0.0, 0.25, 0.0]
[[effector]]
name = "tip"
vertebra = -1
""")

    def run(*extra):
        return subprocess.run([sys.executable, "-m", "vertebra", "simulate", str(tmp_path / "scene.toml"), *extra],
                              capture_output=True, text=True, timeout=120)

    text = run()
    assert text.returncode == 0, text.stderr
    assert "warning: 4 quantities of 4 link(s) outside the range" in text.stderr
    assert "link 0 (segment 0, vertebrae 0–1, entry 'slice-nl'): bending strain" in text.stderr
    document = json.loads(run("--json").stdout)
    rows = document["diagnostics"]["out_of_range"]
    assert [row["link"] for row in rows] == [0, 1, 2, 3] and {row["quantity"] for row in rows} == {"bending strain"}
