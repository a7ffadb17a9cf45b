"""Nonlinear condensation on a stand-in FE with a known energy (tests/energy_oracle.py): charts,
symmetry, the least-squares fit, the sampling and the inflation limit point, the chain check."""

import dataclasses
import math

import numpy as np
import pytest

from vertebra.designer.energy_fit import (FitResult, Samples, evaluate_fit, fit_energy, fit_errors,
                                          invariant_basis, pose_derivatives, strain_derivatives, symmetry_group)
from vertebra.designer.energy_sampling import SamplingSettings
from vertebra.designer.families import AXISYMMETRIC, FAMILIES, SegmentSymmetry
from vertebra.designer.nonlinear_condensation import condense_energy
from vertebra.core.energy import Monomials, linear_terms
from vertebra.core.errors import OptionError
from energy_oracle import OracleEnergy, OracleSpec, rod_entry
from reference.energy_chain import EntryEnergy, PointLoad, solve_chain

THREE = SegmentSymmetry(order=3, mirror=True, mirror_angle=0.3, end_flip=True,
                        cavity_angles=tuple(0.3 + 2 * math.pi * k / 3 for k in range(3)))


def test_pose_chart_derivatives_match_differences_of_the_composed_log():
    """wrench and tangent of ψ(log(exp(ζ^) T) − ξ₀) at ζ = 0, by central differences in ζ (step 1e-5:
    errors ~1e-9 relative), equal pose_derivatives; strain_derivatives inverts it to round-off."""
    from vertebra.core.lie import qmul, qrotate, se3_exp, se3_log

    rng = np.random.default_rng(0)
    d0 = np.array([0.0, 0.0, 0.04])
    K = np.diag([1e3, 1e3, 5e3, 0.2, 0.2, 0.1])
    c3 = rng.normal(size=(6, 6, 6))
    sym = sum(c3.transpose(p) for p in [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]) / 6
    psi = lambda s: 0.5 * s @ K @ s + np.einsum("ijk,i,j,k", sym, s, s, s)          # noqa: E731
    s = rng.normal(size=(2, 6)) * np.array([0.01, 0.01, 0.01, 0.5, 0.5, 0.5])
    grad = s @ K + 3 * np.einsum("ijk,nj,nk->ni", sym, s, s)
    hess = K + 6 * np.einsum("ijk,nk->nij", sym, s)
    wrench, tangent, _ = pose_derivatives(s, d0, grad, hess)
    h = 1e-5
    for n in range(2):
        q, t = se3_exp(s[n] + np.concatenate([d0, np.zeros(3)]))

        def f(zeta):
            qz, tz = se3_exp(zeta)
            return psi(se3_log(qmul(qz, q), qrotate(qz, t) + tz)[0] - np.concatenate([d0, np.zeros(3)]))
        eye = np.eye(6) * h
        g = np.array([(f(e) - f(-e)) / (2 * h) for e in eye])
        H = np.array([[(f(a + b) - f(a - b) - f(b - a) + f(-a - b)) / (4 * h * h) for b in eye] for a in eye])
        assert np.allclose(g, wrench[n], rtol=1e-7, atol=1e-8 * np.abs(wrench[n]).max())
        assert np.allclose(H, tangent[n], rtol=1e-5, atol=1e-6 * np.abs(tangent[n]).max())
    g2, H2, _ = strain_derivatives(s, d0, wrench, tangent)
    assert np.allclose(g2, grad, rtol=1e-12, atol=1e-13 * np.abs(grad).max())
    assert np.allclose(H2, hess, rtol=1e-12, atol=1e-13 * np.abs(hess).max())


@pytest.mark.parametrize("symmetry, m, degree, unknowns", [(AXISYMMETRIC, 0, 6, 60), (AXISYMMETRIC, 0, 4, 17),
                                                           (SegmentSymmetry(), 0, 4, 182), (THREE, 3, 4, 80)])
def test_invariant_basis_is_invariant_and_small(symmetry, m, degree, unknowns):
    """Every basis polynomial takes the same value at z and at g z for every group element (to
    round-off); the counts are the dimensions of the invariant spaces (a rod of degree 6: 60 of 896)."""
    group = symmetry_group(symmetry, degree)
    scales = np.array([0.01, 0.01, 0.004, 0.9, 0.9, 0.5] + [1e5] * m)
    exponents, basis = invariant_basis(6 + m, m, degree, degree, group, scales)
    assert basis.shape[1] == unknowns
    table = Monomials(exponents)
    index = [table.index[tuple(a)] for a in exponents]
    z = np.random.default_rng(2).normal(size=(5, 6 + m)) * scales
    values = table.values(z / scales)[:, index] @ basis
    for g in group:
        moved = table.values(z @ g.T / scales)[:, index] @ basis
        assert np.abs(moved - values).max() < 1e-11 * np.abs(values).max()


def test_family_symmetries_are_groups_of_the_right_size():
    """Rod: 2(d+1) rotations·mirrors × the end flip; pneumatic with 3 chambers: D3 × flip = 12;
    tapered: D3 = 6 (its ends differ); bellows: the bore on the axis stays itself."""
    p = {"outer_radius": 0.04, "length": 0.03, "chamber_radius": 0.01, "chamber_offset": 0.0215,
         "youngs_modulus": 5e5, "poisson_ratio": 0.45}
    assert len(symmetry_group(FAMILIES["rod"].symmetry({}), 6)) == 28
    assert len(symmetry_group(FAMILIES["pneumatic"].symmetry(FAMILIES["pneumatic"].canonical(p)), 6)) == 12
    tapered = {"bottom_outer_radius": 0.04, "top_outer_radius": 0.035, "length": 0.03, "bottom_chamber_radius": 0.01,
               "top_chamber_radius": 0.009, "bottom_chamber_offset": 0.0215, "top_chamber_offset": 0.02,
               "youngs_modulus": 5e5, "poisson_ratio": 0.45}
    assert len(symmetry_group(FAMILIES["tapered_pneumatic"].symmetry(
        FAMILIES["tapered_pneumatic"].canonical(tapered)), 6)) == 6
    group = symmetry_group(FAMILIES["bellows"].symmetry({}), 4)
    assert all(g[6, 6] == 1.0 for g in group)


def _exact_samples(result, linear, m, n, seed):
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1, 1, size=(n, 6 + m)) * result.scales
    z[:, 6:] = np.abs(z[:, 6:])
    g, H = evaluate_fit(result, linear, z)
    return Samples(z[:, :6], z[:, 6:], g[:, :6], H[:, :6, :6], g[:, 6:], H[:, :6, 6:], H[:, 6:, 6:],
                   np.arange(n) // 4)


@pytest.mark.parametrize("symmetry, m, fold", [(AXISYMMETRIC, 0, None), (THREE, 3, 2e5)])
def test_fit_recovers_an_invariant_polynomial_exactly(symmetry, m, fold):
    """Samples of ψ_lin + a random invariant polynomial of degree 4 (pressures through the fold map)
    are fitted back to round-off, on samples held out of the fit too."""
    entry = rod_entry(cavities=m)
    linear = linear_terms(entry.compliance, entry.rest_translation)
    group = symmetry_group(symmetry, 4)
    scales = np.array([0.004, 0.004, 0.002, 0.8, 0.8, 0.4] + [1.5e5] * m)
    exponents, basis = invariant_basis(6 + m, m, 4, 4, group, scales)
    truth = FitResult(exponents, basis @ np.random.default_rng(3).normal(size=basis.shape[1]), scales, 0, {},
                      fold=fold)
    samples = _exact_samples(truth, linear, m, 40, seed=4)
    held = samples.path % 4 == 0
    result = fit_energy(samples, linear, degree=4, pressure_degree=4, group=group, scales=scales, held_out=held,
                        fold=fold)
    g_true, _ = evaluate_fit(truth, linear, samples.variables())
    errors = fit_errors(result, linear, samples.take(held), np.abs(g_true[:, :6]).max() * np.ones(4),
                        float(np.abs(g_true[:, 6:]).max()) if m else None)
    assert errors["load_max"] < 1e-10 and errors["tangent_max"] < 1e-10
    assert errors["linear_load_max"] > 1e-2                   # the polynomial part is not small
    if m:
        assert errors["volume_max"] < 1e-10


@pytest.fixture(scope="module")
def rod_fits():
    """Oracle rod (non-polynomial bending energy, bending-stretch coupling) sampled once, fitted at
    degrees 4 and 6 (serial executor)."""
    spec = OracleSpec(kappa=0.026, coupling=-15.7)
    entry = rod_entry()
    out = {}
    for degree in (4, 6):
        out[degree] = condense_energy(entry, spec, radius=0.01, youngs_modulus=1e6, symmetry=AXISYMMETRIC,
                                      material={"model": "oracle"}, settings=SamplingSettings(degree=degree))
    return entry, spec, out


def test_held_out_error_falls_with_the_degree(rod_fits):
    """ψ has a cosh(|φ|) part: the fit converges with the degree; a degree-6 fit is within 1 % of
    the load range on held-out paths (measured 0.29 %) where ψ_lin alone is 40 % off."""
    _, _, fits = rod_fits
    e4, e6 = (fits[d].energy.fit_error["held_out"] for d in (4, 6))
    assert e6["load_max"] < 0.3 * e4["load_max"]
    assert e6["load_max"] < 0.01 and e6["linear_load_max"] > 0.3
    assert fits[6].energy.fit_error["convexity_min_relative_eigenvalue"] > 0.2
    assert e6["samples"] > 0 and fits[6].energy.sampling["held_out_paths"] >= 3


def test_fitted_chain_matches_the_chain_of_the_true_energy(rod_fits):
    """Two segments under a dead tip force with a lever (bending in 3D with torsion, ~50°): the
    chain of fitted energies puts the tip within 0.02 % of the length of the chain of the true
    energy (measured 0.002 %); ψ_lin alone is ≥ 0.3 % off."""
    entry, spec, fits = rod_fits
    truth = spec.build()
    nonlinear = dataclasses.replace(entry, energy=fits[6].energy)

    loads = [PointLoad(-1, (2.0, 1.0, -0.5), (0.015, 0.0, 0.0))]
    reference = solve_chain([OracleEnergy(truth)] * 2, loads)
    fitted = solve_chain([EntryEnergy(nonlinear)] * 2, loads)
    linear = solve_chain([EntryEnergy(nonlinear, linear_only=True)] * 2, loads)
    length = 2 * entry.rest_translation[2]
    assert 30 < np.degrees(reference.tip_angle()) < 80
    assert np.linalg.norm(fitted.tip_position - reference.tip_position) < 2e-4 * length
    assert np.linalg.norm(linear.tip_position - reference.tip_position) > 3e-3 * length
    assert not fitted.left_range


def test_inflation_limit_point_is_found_and_kept_out_of_the_range():
    """A chamber that balloons to a limit point at 1.47 bar: the pressure ramp finds it within 1 %,
    the pressures stay below 0.9 of it, the fold map makes the volume growth exact to 0.1 % of its
    range (a polynomial in p of the same degree: > 1 %)."""
    spec = OracleSpec(cavities=3, balloon=1.3e-6, p_limit=1.47e5)
    entry = rod_entry(cavities=3)
    settings = SamplingSettings(degree=4, pressure_degree=4, paths=12, steps=4)
    folded = condense_energy(entry, spec, radius=0.01, youngs_modulus=1e6, symmetry=THREE_AT_ZERO,
                             material={"model": "oracle"}, settings=settings)
    energy = folded.energy
    assert abs(energy.range.limit_pressure - 1.47e5) < 0.01 * 1.47e5
    assert energy.fold_pressure == energy.range.limit_pressure
    assert np.all(energy.range.pressure_upper <= 0.9 * energy.range.limit_pressure + 1e-9)
    assert energy.fit_error["held_out"]["volume_max"] < 1e-3
    plain = condense_energy(entry, spec, radius=0.01, youngs_modulus=1e6, symmetry=THREE_AT_ZERO,
                            material={"model": "oracle"}, settings=dataclasses.replace(settings, fold=False))
    assert plain.energy.fit_error["held_out"]["volume_max"] > 1e-2


THREE_AT_ZERO = SegmentSymmetry(order=3, mirror=True, mirror_angle=0.0, end_flip=True,
                                cavity_angles=tuple(2 * math.pi * k / 3 for k in range(3)))


def test_linear_chain_equals_the_runtime_solver_with_linear_entries():
    """The yardstick chain with ψ_lin alone is the runtime's linear-entry trunk: same tip to 1e-12
    of the length at 50° of bending (same energy, both converged to round-off)."""
    from vertebra import solver

    entries = [dataclasses.replace(rod_entry(), name=f"e{i}", key=f"k{i}") for i in range(3)]
    force = [1.2, 0.4, -0.2]
    scene = solver.parse_scene({"solver": {"tolerance": 1e-13, "max_iterations": 100, "load_steps": 4},
                                "catalogue": {"path": "unused.h5"},
                                "segment": [{"type": "entry", "entry": e.name, "count": 1} for e in entries],
                                "load": [{"vertebra": -1, "force": force, "moment": [0, 0, 0]}]})
    model = solver.build_model(scene, entries={e.name: e for e in entries})
    result = model.solve()
    chain = solve_chain([EntryEnergy(e) for e in entries], [PointLoad(-1, tuple(force))])
    tip = result.state.positions[model.vertebra_frames[-1]]
    assert np.degrees(chain.tip_angle()) > 45
    assert np.linalg.norm(chain.tip_position - tip) < 1e-12 * 0.12


def test_automatic_sampling_settings_depend_on_material_and_cavities():
    # St Venant-Kirchhoff has a compressive limit point at the stretch 1/sqrt(3): its default box
    # stops at 25 % outer-fibre strain (40 % otherwise); an explicit setting wins, and the
    # resolved value is part of the content key
    from vertebra.designer import entry_key

    assert SamplingSettings().resolved(0, "svk").strain == 0.25
    assert SamplingSettings().resolved(0, "neo_hookean").strain == 0.4
    assert SamplingSettings(strain=0.3).resolved(0, "svk").strain == 0.3
    # segments with cavities: more paths and more levels per path (the response steepens
    # towards the inflation limit)
    assert (SamplingSettings().resolved(0, "neo_hookean").steps, SamplingSettings().resolved(3, "neo_hookean").steps) == (6, 10)
    assert SamplingSettings(steps=4).resolved(3, "neo_hookean").steps == 4
    rod = {"radius": 0.01, "length": 0.01, "youngs_modulus": 1e6, "poisson_ratio": 0.35}
    assert entry_key("rod", rod, material="svk") == entry_key("rod", rod, material="svk", sampling={"strain": 0.25})
    assert entry_key("rod", rod, material="svk") != entry_key("rod", rod, material="svk", sampling={"strain": 0.4})


def test_cavities_setting_samples_only_the_pressurised_chambers():
    """``sampling.cavities``: none pressurised — no inflation-limit ramp, every sample at zero
    pressure, no pressure terms, a range that admits no pressure; one named — its ramp finds
    the limit (within 1 %) and only it is sampled under pressure. The keys of the default
    settings do not change (``cavities`` is described only when set)."""
    spec = OracleSpec(cavities=3, balloon=1.3e-6, p_limit=1.47e5)
    entry = rod_entry(cavities=3)
    base = SamplingSettings(degree=4, pressure_degree=4, paths=12, steps=4)
    assert "cavities" not in base.describe()
    assert SamplingSettings.from_dict({"cavities": [1]}).describe()["cavities"] == [1]
    none = condense_energy(entry, spec, radius=0.01, youngs_modulus=1e6, symmetry=THREE_AT_ZERO,
                           material={"model": "oracle"}, settings=dataclasses.replace(base, cavities=()))
    assert "ramp_solves" not in none.energy.sampling
    assert np.all(none.samples.pressure == 0.0)
    assert np.all(none.energy.range.pressure_upper == 0.0) and none.energy.range.limit_pressure is None
    assert all(np.sum(e[6:]) == 0 for e in none.energy.exponents)          # no pressure terms
    assert none.energy.fit_error["held_out"]["load_max"] < 1e-6
    one = condense_energy(entry, spec, radius=0.01, youngs_modulus=1e6, symmetry=THREE_AT_ZERO,
                          material={"model": "oracle"}, settings=dataclasses.replace(base, cavities=(1,)))
    assert abs(one.energy.range.limit_pressure - 1.47e5) < 0.01 * 1.47e5
    assert np.all(one.samples.pressure[:, [0, 2]] == 0.0) and one.samples.pressure[:, 1].max() > 0
    assert one.energy.fit_error["held_out"]["volume_max"] < 1e-3
    with pytest.raises(OptionError, match="cavity 3"):
        SamplingSettings(cavities=(3,)).pressurised(3)
    with pytest.raises(OptionError, match="sampling.cavities"):
        SamplingSettings(cavities=(1, 1))
