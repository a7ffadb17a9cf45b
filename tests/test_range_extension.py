"""ψ beyond the fitted strain box (core/energy.py, FixedPressures._extend) and how a solve reports
and advises when a state leaves the range.

Checked here: inside the box the energy is the polynomial bit for bit; outside, the gradient is
the derivative of the energy, the Hessian the derivative of the gradient and the pressure
derivatives those of ψ (central differences), ψ is C¹ across the boundary, the fitted correction's
force stays bounded far out while the polynomial's grows; a trunk of a designed neo-Hookean rod
entry whose box is cut to a fraction of its sampled bending solves where it leaves the box, is
reported out of range there in degrees, and is no farther from the full nonlinear FE than the
linear entries; an entry segment that turns towards π is told what applies to an entry.

The energies are the synthetic fits of :mod:`fitted_energies` (fast) and the coarse designed rod
(~6 s, once per process).
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from fitted_energies import ROD, ROD_MESH, nonlinear_rod, with_energy
from test_solver_actuation import synthetic_entry
from vertebra import solver
from vertebra.core.energy import EnergyModel
from vertebra.core.errors import ConvergenceError

FITTED = with_energy(synthetic_entry(), strength=0.3)
PRESSURES = np.array([4e4, 1.5e4])


def _states(rng, n, spread):
    scales = FITTED.energy.scales[:6]
    return rng.normal(size=(n, 6)) * scales * spread


def test_inside_the_box_the_energy_is_the_polynomial_bit_for_bit():
    model = EnergyModel.of_entry(FITTED)
    s = _states(np.random.default_rng(0), 200, 0.5)
    rho, _ = FITTED.energy.range.gauge(s)
    inside = s[rho <= 1.0]
    assert 20 < inside.shape[0] < 180                 # both kinds present in the draw
    p = np.tile(PRESSURES, (inside.shape[0], 1))
    a = model.at(p).evaluate(inside)
    b = model.at(p).evaluate(inside, extend=False)
    for name in ("energy", "gradient", "hessian", "pressure_gradient", "mixed_hessian", "pressure_hessian"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    # and the range test says inside wherever the strain box and the load box do
    assert np.array_equal(a.range_excess, b.range_excess)


def test_outside_the_derivatives_are_those_of_the_extended_energy():
    # central differences of the energy, the gradient and the pressure derivatives; measured
    # ≤ 2e-9 relative (differences of step 1e-6 of each scale), 1e-6 would catch a missing term
    model = EnergyModel.of_entry(FITTED)
    s = _states(np.random.default_rng(1), 12, 1.5)
    rho, _ = FITTED.energy.range.gauge(s)
    s = s[rho > 1.05]
    n = s.shape[0]
    assert n >= 6
    p = np.tile(PRESSURES, (n, 1))
    at = model.at(p)
    v = at.evaluate(s)
    scales = FITTED.energy.scales[:6]
    for j in range(6):
        step = np.zeros(6)
        step[j] = 1e-6 * scales[j]
        up, down = at.evaluate(s + step), at.evaluate(s - step)
        force = (up.energy - down.energy) / (2 * step[j])
        assert np.abs(force - v.gradient[:, j]).max() <= 1e-6 * np.abs(v.gradient).max()
        column = (up.gradient - down.gradient) / (2 * step[j])
        assert np.abs(column - v.hessian[:, :, j]).max() <= 1e-6 * np.abs(v.hessian).max()
    assert np.allclose(v.hessian, v.hessian.transpose(0, 2, 1), rtol=0, atol=1e-12 * np.abs(v.hessian).max())
    for c in range(2):
        dp = np.zeros(2)
        dp[c] = 1.0
        up, down = model.at(p + dp).evaluate(s), model.at(p - dp).evaluate(s)
        assert np.abs((up.energy - down.energy) / 2 - v.pressure_gradient[:, c]).max() <= \
            1e-6 * np.abs(v.pressure_gradient).max()
        assert np.abs((up.gradient - down.gradient) / 2 - v.mixed_hessian[:, :, c]).max() <= \
            1e-6 * np.abs(v.mixed_hessian).max()
        assert np.abs((up.pressure_gradient - down.pressure_gradient) / 2 - v.pressure_hessian[:, :, c]).max() <= \
            1e-6 * np.abs(v.pressure_hessian).max()


def test_the_extension_is_c1_across_the_boundary_and_its_correction_force_bounded():
    model = EnergyModel.of_entry(FITTED)
    K = model.stiffness
    s = _states(np.random.default_rng(2), 50, 1.0)
    boundary = s / FITTED.energy.range.ratios(s).max(axis=1)[:, None]     # on the box's surface
    at = model.at(None)
    outside, inside = at.evaluate(boundary * (1 + 1e-9)), at.evaluate(boundary * (1 - 1e-9))
    scale = np.abs(inside.gradient).max()
    assert np.abs(outside.gradient - inside.gradient).max() <= 1e-6 * scale          # C¹
    assert np.abs(outside.energy - inside.energy).max() <= 1e-6 * np.abs(inside.energy).max()
    # far out: the correction's force (ψ − ψ_lin) stays within a few times its size just outside,
    # the polynomial's grows with the fifth power of the distance
    near, far = at.evaluate(boundary * 2.0), at.evaluate(boundary * 50.0)
    polynomial = at.evaluate(boundary * 50.0, extend=False)
    correction = lambda v, t: np.linalg.norm(v.gradient - (t * boundary) @ K, axis=1)  # noqa: E731
    assert np.all(correction(far, 50.0) <= 3.0 * correction(near, 2.0) + 1e-12 * scale)
    assert np.median(correction(polynomial, 50.0) / correction(far, 50.0)) > 1e3


def _model(entry, count, forces):
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": count}],
            "load": [{"vertebra": k, "force": f} for k, f in forces.items()],
            "effector": [{"name": "tip", "vertebra": -1}]}
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


def _cut(entry, fraction):
    """``entry`` whose strain box admits only ``fraction`` of its sampled bending."""
    fitted = entry.energy.range
    upper = fitted.pose_upper.copy()
    upper[2] *= fraction
    cut = dataclasses.replace(fitted, pose_upper=upper)
    return dataclasses.replace(entry, energy=dataclasses.replace(entry.energy, range=cut))


@pytest.fixture(scope="module")
def rod():
    return nonlinear_rod()


def test_a_trunk_beyond_its_box_solves_is_reported_and_is_no_worse_than_linear(rod):
    """Three repetitions of the coarse rod under a tip force that bends them 27°, 15° and 5°, the
    box cut to a sixth of the sampled bending (11°): the two lower links leave it. The solve
    converges, reports the bending strain of the links outside (in degrees), and its tip is no
    farther from the full nonlinear FE than the linear entries' (measured, in % of the length:
    0.005 with the whole box, 0.11 cut to a third, 0.25 cut to a sixth, 0.31 for the linear
    entries)."""
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads
    from vertebra.designer.nonlinear_condensation import FamilySolid

    forces = {3: [1.2, 0.0, 0.0]}
    cut = _cut(rod, 1.0 / 6.0)
    whole = _model(rod, 3, forces).solve()
    beyond = _model(cut, 3, forces).solve()
    linear = _model(dataclasses.replace(rod, energy=None), 3, forces).solve()
    segment = FamilySolid("rod", json.dumps(rod.parameters, sort_keys=True), ROD_MESH, 2, "neo_hookean").build()
    reference = NonlinearTrunk([segment] * 3).solve(TrunkLoads(forces={k: np.array(f) for k, f in forces.items()}))
    assert whole.converged and beyond.converged and linear.converged and reference.converged
    length = 3 * ROD["length"]
    error = {name: float(np.linalg.norm(r.state.positions[-1] - reference.positions[-1])) / length
             for name, r in (("whole", whole), ("beyond", beyond), ("linear", linear))}
    assert error["beyond"] <= error["linear"]
    assert error["whole"] <= 1e-3
    bent = beyond.state.carried_strains().xi[:, 3:]
    bending = np.hypot(bent[:, 0], bent[:, 1])
    limit = cut.energy.range.pose_upper[2]
    flagged = [e for e in beyond.out_of_range if e.quantity == "bending strain"]
    assert sorted(e.link for e in flagged) == np.flatnonzero(bending > limit).tolist() == [0, 1]
    worst = max(flagged, key=lambda e: e.value)
    assert worst.unit == ("°", pytest.approx(180 / math.pi))
    assert f"{math.degrees(worst.value):.4g}°" in str(worst)
    assert worst.to_dict()["upper_in_unit"] == pytest.approx(math.degrees(limit))


def test_design_states_the_sampled_range_in_physical_terms(rod):
    from vertebra.cli.design import entry_document

    sampled = entry_document(rod)["energy"]["sampled"]
    fitted = rod.energy.range
    assert sampled["bending_deg"] == pytest.approx(math.degrees(fitted.pose_upper[2]))
    assert sampled["bending_moment_Nm"] == pytest.approx(fitted.load_upper[2])
    assert sampled["lateral_force_N"] == pytest.approx(fitted.load_upper[0])
    # ROD is long (L/r 4): the 75° bending setting, not the outer-fibre strain (0.4 · 4), bounds it
    assert sampled["bending_bounded_by"] == "bending" and "--sampling bending=" in sampled["widen"]
    assert "vertebra prepare" in sampled["widen"]


def test_an_entry_segment_turning_towards_pi_is_told_what_applies_to_an_entry():
    entry = synthetic_entry()
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": 2}],
            "load": [{"vertebra": -1, "moment": [0.0, 40.0, 0.0]}]}
    model = solver.build_model(solver.parse_scene(data), {entry.name: entry})
    with pytest.raises(ConvergenceError) as info:
        model.solve()
    message = str(info.value)
    assert "one link per repetition" in message and "shorter entry repeated more often" in message
    assert "elements =" not in message
    assert "--sampling" not in message          # a linear entry has no sampled range to widen
    fitted = with_energy(entry)
    model = solver.build_model(solver.parse_scene(data), {entry.name: fitted})
    with pytest.raises(ConvergenceError) as info:
        model.solve()
    assert "shorter entry repeated more often" in str(info.value) and "--sampling bending=" in str(info.value)


def test_design_says_when_the_energy_fit_misses_its_held_out_samples():
    """A fit whose held-out load error exceeds FIT_WARNING is flagged at design time with what to
    change (the default St Venant–Kirchhoff rod's 28 % and the neo-Hookean rod's 0.45 %, as
    measured in docs/nonlinear-condensation.md)."""
    from types import SimpleNamespace

    from vertebra.cli.design import FIT_WARNING, fit_warning

    def energy(error, model):
        return SimpleNamespace(fit_error={"held_out": {"load_max": error, "load_rms": error / 3}},
                               material={"model": model})

    assert fit_warning(energy(0.0045, "neo_hookean")) is None
    assert fit_warning(energy(FIT_WARNING, "neo_hookean")) is None
    svk = fit_warning(energy(0.28, "svk"))
    assert "0.28" in svk and "compressive limit point" in svk and "--sampling" in svk
    assert "compressive" not in fit_warning(energy(0.2, "neo_hookean"))
    assert fit_warning(SimpleNamespace(fit_error={}, material={})) is None


def test_prepare_refuses_a_fit_by_its_error_where_the_scene_goes():
    """The refusal reads the held-out errors by load and pressure level: only the samples within
    the part of the sampled box the scene needs count (the lowest-lying ones when none lies that
    low); an entry without them is judged by its error over the whole box; a scene beyond the
    box, an unbounded pressure or no estimate needs the whole box."""
    from types import SimpleNamespace

    from vertebra.core.energy import EnergyRange
    from vertebra.designer.energy_fit import FIT_LIMIT, error_up_to
    from vertebra.designer.preparation import fit_refusal, needed_level
    from vertebra.designer.scene_range import SegmentRange
    from vertebra.cli.design import FIT_WARNING

    assert FIT_WARNING == FIT_LIMIT
    by_level = [[0.17, 0.0, 0.001], [0.5, 0.0, 0.01], [0.83, 0.0, 0.12], [1.0, 0.0, 0.28]]
    assert error_up_to(by_level, 0.6) == (0.01, 2)
    assert error_up_to(by_level, 0.1) == (0.001, 1) and error_up_to(by_level, 2.0) == (0.28, 4)
    assert error_up_to([], 1.0) is None and error_up_to([[0.1, 0.001]], 1.0) is None    # an older form
    # pressurised: large loads at the top pressure miss, a pressure-driven use (small loads) does not
    pneumatic = [[0.1, 1.0, 0.002], [0.2, 0.5, 0.001], [1.0, 1.0, 0.11], [1.0, 0.2, 0.03]]
    assert error_up_to(pneumatic, 0.2, 1.0) == (0.002, 2) and error_up_to(pneumatic, 1.0, 1.0) == (0.11, 4)
    assert error_up_to(pneumatic, 1.0, 0.3) == (0.03, 1) and error_up_to(pneumatic, 0.05, 0.1) == (0.001, 1)
    fitted = EnergyRange(np.zeros(4), np.ones(4), np.array([0.0, -2.0, 0.0, -1.0]), np.array([4.0, 2.0, 0.5, 1.0]),
                         np.zeros(1), np.array([1e5]))
    half = SegmentRange(0, np.zeros(4), np.ones(4), np.array([0.0, -0.5, 0.0, 0.0]), np.array([1.0, 0.2, 0.3, 0.0]),
                        {0: (0.0, 2e4)})
    assert needed_level(half, fitted) == pytest.approx((0.6, 0.2))           # the bending moment: 0.3 / 0.5
    assert needed_level(dataclasses.replace(half, pressures={0: (0.0, np.inf)}), fitted)[1] == np.inf
    assert needed_level(dataclasses.replace(half, pressures={}), fitted) == pytest.approx((0.6, 0.0))
    assert needed_level(None, fitted) == (np.inf, np.inf)

    def energy(held, model="svk"):
        return SimpleNamespace(fit_error={"held_out": held}, material={"model": model}, range=SimpleNamespace(n_cavities=0))

    svk = energy({"load_max": 0.28, "load_rms": 0.08, "by_level": by_level})
    assert fit_refusal(svk, (0.6, 0.0), FIT_LIMIT) is None                  # the scene stays where the fit holds
    reason = fit_refusal(svk, (1.2, 0.0), FIT_LIMIT)
    assert "0.28" in reason and "whole sampled box" in reason and "compressive limit point" in reason
    assert "--max-fit-error" in reason and "strain" in reason and "neo_hookean" in reason
    assert "3 of its 4 held-out samples" in fit_refusal(svk, (0.9, 0.0), FIT_LIMIT)
    assert fit_refusal(svk, (1.2, 0.0), 0.3) is None
    old = energy({"load_max": 0.28, "load_rms": 0.08}, "neo_hookean")       # stored before the per-sample errors
    assert "whole sampled box" in fit_refusal(old, (0.1, 0.0), FIT_LIMIT)
    assert "compressive" not in fit_refusal(old, (0.1, 0.0), FIT_LIMIT)
    assert fit_refusal(energy({"samples": 0}), (1.0, 0.0), FIT_LIMIT) is None
