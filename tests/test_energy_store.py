"""The energy of nonlinear entries (core.energy, catalogue schema v2): kernel, linear part, range, storage."""

import dataclasses
import json
import shutil

import h5py
import numpy as np
import pytest

from vertebra.store import catalogue, schema
from vertebra.core.energy import (EnergyFit, EnergyModel, EnergyRange, linear_terms, monomial_exponents,
                                  rest_strain)
from vertebra.core.lie import qexp, qmul, se3_log
from vertebra.core.errors import CatalogueError
from energy_oracle import rod_entry


def _range(m, top=1.0):
    return EnergyRange(pose_lower=[0.0, -0.01, 0.0, -1.0], pose_upper=[0.02, 0.01, 1.2, 1.0],
                       load_lower=[0.0, -50.0, 0.0, -1.0], load_upper=[20.0, 50.0, 1.0, 1.0],
                       pressure_lower=np.zeros(m), pressure_upper=np.full(m, top))


def _fit(m=0, degree=5, seed=0, fold=None, top=1e5):
    rng = np.random.default_rng(seed)
    exponents = monomial_exponents(6 + m, degree, 3, tail=m, tail_degree=4)
    scales = np.array([0.01, 0.01, 0.005, 0.8, 0.8, 0.5] + [top] * m)
    return EnergyFit(exponents=exponents, coefficients=0.01 * rng.normal(size=len(exponents)), scales=scales,
                     range=_range(m, top), fit_error={"held_out": {"load_max": 0.01}},
                     material={"model": "neo_hookean"}, sampling={"samples": 3}, fold_pressure=fold)


def _entry(m=0, **fit):
    entry = rod_entry(cavities=m)
    return dataclasses.replace(entry, energy=_fit(m, **fit))


def _stack(values, m):
    grad = np.concatenate([values.gradient, values.pressure_gradient], 1)
    top = np.concatenate([values.hessian, values.mixed_hessian], 2)
    bottom = np.concatenate([values.mixed_hessian.mT, values.pressure_hessian], 2)
    return grad, np.concatenate([top, bottom], 1)


@pytest.mark.parametrize("m, fold", [(0, None), (3, None), (3, 1.6e5)])
def test_kernel_derivatives_match_differences(m, fold):
    """Energy, gradient and Hessian of the kernel agree with central differences of each other
    (step 1e-6 of each variable's scale: truncation and round-off both near 1e-9 relative)."""
    entry = _entry(m, fold=fold)
    model = EnergyModel.of_entry(entry)
    rng = np.random.default_rng(1)
    scales = entry.energy.scales
    z = rng.uniform(-0.7, 0.7, size=(4, 6 + m)) * scales
    z[:, 6:] = np.abs(z[:, 6:])
    values = model.evaluate(z[:, :6], z[:, 6:])
    grad, hess = _stack(values, m)
    for j in range(6 + m):
        h = 1e-6 * scales[j]
        step = np.zeros(6 + m)
        step[j] = h
        plus = model.evaluate((z + step)[:, :6], (z + step)[:, 6:])
        minus = model.evaluate((z - step)[:, :6], (z - step)[:, 6:])
        assert np.allclose((plus.energy - minus.energy) / (2 * h), grad[:, j], rtol=1e-6,
                           atol=1e-7 * np.abs(grad).max())
        column = (_stack(plus, m)[0] - _stack(minus, m)[0]) / (2 * h)
        assert np.allclose(column, hess[:, :, j], rtol=1e-6, atol=1e-7 * np.abs(hess).max())
    assert np.allclose(hess, hess.mT, rtol=0, atol=1e-12 * np.abs(hess).max())


@pytest.mark.parametrize("m, fold", [(0, None), (3, 1.6e5)])
def test_hessian_at_rest_is_the_linear_compliance_exactly(m, fold):
    """No term of ψ_nl is below degree 3 (the fold map w = p + O(p²) included): at rest the
    gradient is zero and the Hessian is bit-for-bit the linear one built from [[C, G], [Gᵀ, V]]."""
    entry = _entry(m, fold=fold)
    model = EnergyModel.of_entry(entry)
    K, S, V = linear_terms(entry.compliance, entry.rest_translation)
    rest = model.evaluate(np.zeros((1, 6)), np.zeros((1, m)))
    assert np.all(rest.gradient == 0) and np.all(rest.pressure_gradient == 0) and rest.energy[0] == 0
    assert np.array_equal(rest.hessian[0], K)
    assert np.array_equal(rest.mixed_hessian[0], -(K @ S))
    assert np.allclose(rest.pressure_hessian[0], S.T @ K @ S - V, rtol=1e-14, atol=0)
    assert entry.energy.check(entry.compliance, entry.rest_translation) == []


@pytest.mark.parametrize("turned", [False, True])
def test_strain_map_is_the_derivative_of_the_log_at_rest(turned):
    """A = ∂ξ/∂δ: moving b by δ = [Δx; Δθ] in a's axes (Δθ a rotation vector applied on the left of
    the rest rotation) moves ξ = log_SE3(T_a⁻¹ T_b) by A δ. Central differences with steps 1e-6:
    truncation ~1e-12, round-off ~1e-10 of the entries (≤ 1 in size); 1e-8 separates a wrong
    column (≥ 1e-3) from rounding. At the identity rotation A is [[I, ½ d̂₀], [0, I]] exactly."""
    d0 = np.array([0.003, -0.002, 0.04])
    q0 = qexp(np.array([0.2, -0.4, 0.3])) if turned else np.array([1.0, 0.0, 0.0, 0.0])
    xi0, A = rest_strain(d0, q0)
    assert np.allclose(xi0, se3_log(q0, d0)[0], rtol=0, atol=1e-15)
    h = 1e-6
    columns = []
    for j in range(6):
        delta = np.zeros(6)
        delta[j] = h
        moved = [se3_log(_rotated(q0, sign * delta[3:]), d0 + sign * delta[:3])[0] for sign in (1.0, -1.0)]
        columns.append((moved[0] - moved[1]) / (2 * h))
    assert np.allclose(np.array(columns).T, A, rtol=0, atol=1e-8)
    if not turned:
        closed = np.eye(6)
        closed[:3, 3:] = 0.5 * np.array([[0.0, -d0[2], d0[1]], [d0[2], 0.0, -d0[0]], [-d0[1], d0[0], 0.0]])
        assert np.array_equal(A, closed)


def _rotated(q, phi):
    return qmul(qexp(phi), q)


def test_linear_part_reproduces_the_compliance():
    """ψ_lin is the linear condensation in the strain: the displacement δ of b under a wrench f
    and pressures p, δ = C f + G p, is the strain A δ where ∂ψ_lin/∂s balances the strain-space
    force A⁻ᵀ f (the wrench's work f·δ is the load's work on s), and −∂ψ_lin/∂p is the volume
    growth Gᵀ f + V p (to round-off: 1e-12 of the largest term)."""
    entry = rod_entry(cavities=2)
    K, S, V = linear_terms(entry.compliance, entry.rest_translation)
    _, A = rest_strain(entry.rest_translation)
    f, p = np.array([0.3, -0.2, 1.0, 0.004, 0.01, -0.002]), np.array([2e4, 5e3])
    delta = entry.C @ f + entry.G @ p
    s = A @ delta
    load = K @ (s - S @ p)
    assert np.allclose(load, np.linalg.solve(A.T, f), rtol=0, atol=1e-12 * np.abs(load).max())
    growth = S.T @ K @ (s - S @ p) + V @ p
    expected = entry.G.T @ f + entry.V @ p
    assert np.allclose(growth, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_range_excess_is_rotation_invariant_and_bounded():
    """Inside: excess ≤ 0; leaving one bound by a fraction f of its interval gives excess f; the
    groups are norms of (x, y) pairs, so turning a state about the axis does not change it."""
    r = _range(1, top=1e5)
    s = np.array([[0.01, 0.0, 0.002, 0.5, 0.0, 0.2]])
    load = np.array([[5.0, 0.0, 10.0, 0.5, 0.0, 0.1]])
    assert r.excess(s, load, np.array([[5e4]]))[0] <= 0
    c, d = np.cos(1.0), np.sin(1.0)
    turned = s.copy()
    turned[0, [0, 1]] = [c * 0.01, d * 0.01]
    turned[0, [3, 4]] = [c * 0.5, d * 0.5]
    assert np.isclose(r.excess(turned, load, np.array([[5e4]]))[0], r.excess(s, load, np.array([[5e4]]))[0])
    bent = s.copy()
    bent[0, 3] = 1.2 + 0.1 * 1.2                  # bending 10 % of its interval beyond the bound
    assert np.isclose(r.excess(bent, load, np.array([[5e4]]))[0], 0.1)
    assert np.isclose(r.excess(s, load, np.array([[1.2e5]]))[0], 0.2)


def test_fit_validation_refuses_low_degree_terms_and_bad_ranges():
    fit = _fit()
    with pytest.raises(CatalogueError, match="no term below degree 3"):
        dataclasses.replace(fit, exponents=np.vstack([fit.exponents, [[1, 1, 0, 0, 0, 0]]]),
                            coefficients=np.append(fit.coefficients, 1.0))
    with pytest.raises(CatalogueError, match="repeated rows"):
        dataclasses.replace(fit, exponents=np.vstack([fit.exponents, fit.exponents[:1]]),
                            coefficients=np.append(fit.coefficients, 1.0))
    with pytest.raises(CatalogueError, match="empty"):
        EnergyRange([0, 0, 0, 0], [1, 0, 1, 1], [0, -1, 0, -1], [1, 1, 1, 1])
    with pytest.raises(CatalogueError, match="fold_pressure"):
        _fit(m=2, fold=0.5e5, top=1e5)                     # the fold must lie above the sampled pressures
    with pytest.raises(CatalogueError, match="cavities"):
        dataclasses.replace(rod_entry(cavities=1), energy=_fit(m=2))


def test_nonlinear_entry_roundtrip_checksum_and_schema_version(tmp_path):
    """A v2 entry round-trips bit for bit through HDF5, JSON and NPZ; the checksum covers the energy
    (a flipped coefficient is reported corrupt); the file is stamped version 2 only once it holds
    an energy; verify checks the energy against its entry."""
    path = tmp_path / "cat.h5"
    linear = dataclasses.replace(rod_entry(), key="lin0", name="lin")
    catalogue.add_entry(path, linear)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["schema_version"]) == 1                # a v1 file, readable by older vertebra
    entry = dataclasses.replace(_entry(3, fold=1.6e5), key="nl0", name="nl")
    catalogue.add_entry(path, entry)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["schema_version"]) == schema.ENERGY_SCHEMA_VERSION
        group = f["entries/nl0/energy"]
        assert group["exponents"].dtype == np.int64 and group["coefficients"].shape == entry.energy.coefficients.shape
        assert json.loads(group.attrs["range"].decode())["limit_pressure"] is None
    with catalogue.open_catalogue(path) as cat:
        back = cat.load("nl")
        assert cat.load("lin").energy is None
    assert back.energy == entry.energy
    assert np.array_equal(back.energy.coefficients, entry.energy.coefficients)
    assert catalogue.verify(path) == []
    assert catalogue.entry_from_dict(json.loads(json.dumps(catalogue.entry_to_dict(back)))).energy == entry.energy
    npz = catalogue.export(path, "nl", "npz", tmp_path / "nl.npz")
    assert catalogue.entry_from_npz(npz).energy == entry.energy
    with h5py.File(path, "r+") as f:
        data = f["entries/nl0/energy/coefficients"]
        values = data[()]
        values[3] += 1e-9
        data[...] = values
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "checksum mismatch" in problems[0]


def test_verify_reports_an_energy_inconsistent_with_its_entry(tmp_path):
    """An energy whose range does not contain the rest state is reported by verify."""
    path = tmp_path / "cat.h5"
    fit = _fit()
    shifted = dataclasses.replace(fit.range, pose_lower=np.array([0.0, 0.001, 0.0, -1.0]))
    with pytest.raises(CatalogueError, match="does not contain the rest state"):      # every reader refuses it
        dataclasses.replace(rod_entry(), key="nl1", name="nl", energy=dataclasses.replace(fit, range=shifted))
    from tampering import _raw_replace, write_resigned

    entry = _raw_replace(rod_entry(), key="nl1", name="nl", energy=_raw_replace(fit, range=shifted))
    write_resigned(path, entry)                   # a file holding it, its checksum recomputed
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "does not contain the rest state" in problems[0]


def test_the_energy_group_describes_itself_to_a_reader_with_h5py_only(tmp_path):
    """What a colleague with h5py alone needs is in the file beside the JSON: the strain's and ψ's
    definitions as text, ξ₀ and A = ∂ξ/∂δ, the range's bounds as datasets, units on every dataset
    and beside every numeric attribute. ψ_lin rebuilt from those datasets alone is the kernel's
    (same formula, same numbers: to round-off). A file without them (as written before they
    existed) reads and verifies the same; a restating dataset that disagrees is refused."""
    path = tmp_path / "cat.h5"
    entry = dataclasses.replace(_entry(2, fold=1.6e5), key="nl0", name="nl")
    catalogue.add_entry(path, entry)
    with h5py.File(path, "r") as f:
        group = f["entries/nl0"]
        energy = group["energy"]
        assert group.attrs["mass_units"].decode() == "kg"
        assert energy.attrs["fold_pressure_units"].decode() == "Pa"
        for obj, text in ((group, ("name", "family", "provenance", "checksum", "content")),
                          (energy, ("representation", "strain", "definition"))):
            quantities = [name for name in obj.attrs if not name.endswith("_units") and name not in text]
            assert quantities and all(f"{name}_units" in obj.attrs for name in quantities), quantities
        assert "log_SE3(T_a^-1 T_b)" in energy.attrs["strain"].decode()
        assert "inv(A C A^T)" in energy.attrs["definition"].decode()
        datasets = {}
        energy.visititems(lambda name, obj: datasets.__setitem__(name, obj) if isinstance(obj, h5py.Dataset) else None)
        assert set(datasets) == set(schema.ENERGY_DATASET_ATTRIBUTES) - {"range/limit_pressure"}
        for name, dataset in datasets.items():
            units, description = schema.ENERGY_DATASET_ATTRIBUTES[name]
            assert dataset.attrs["units"].decode() == units and dataset.attrs["description"].decode() == description
        assert datasets["range/load_upper"].attrs["units"].decode() == "[N, N, N m, N m]"
        A, xi0 = energy["strain_map"][()], energy["rest_strain"][()]
        compliance = group["compliance"][()]
        C, G = compliance[:6, :6], compliance[:6, 6:]
        K = np.linalg.inv(A @ C @ A.T)
        assert np.array_equal(energy["range/pressure_upper"][()], entry.energy.range.pressure_upper)
        assert "limit_pressure" not in energy["range"]                  # no limit point met while sampling
    K_kernel, S_kernel, _ = linear_terms(entry.compliance, entry.rest_translation)
    assert np.allclose(K, K_kernel, rtol=0, atol=1e-12 * np.abs(K).max())
    assert np.allclose(A @ G, S_kernel, rtol=0, atol=1e-12 * np.abs(S_kernel).max())
    assert np.array_equal(xi0, np.r_[entry.rest_translation, 0.0, 0.0, 0.0])

    bare = tmp_path / "bare.h5"
    shutil.copy(path, bare)
    with h5py.File(bare, "r+") as f:                   # as written before the restating objects existed
        energy = f["entries/nl0/energy"]
        for name in ("strain_map", "rest_strain", "range"):
            del energy[name]
        for name in ("strain", "definition") + tuple(f"{n}_units" for n in schema.ENERGY_ATTRIBUTE_UNITS):
            del energy.attrs[name]
        for name in schema.ENTRY_ATTRIBUTE_UNITS:
            del f["entries/nl0"].attrs[f"{name}_units"]
    assert catalogue.verify(bare) == []
    with catalogue.open_catalogue(bare) as cat:
        assert cat.load("nl").energy == entry.energy

    limited = dataclasses.replace(entry, key="nl1", name="nl-limited", energy=dataclasses.replace(
        entry.energy, range=dataclasses.replace(entry.energy.range, limit_pressure=1.5e5)))
    catalogue.add_entry(path, limited)
    with h5py.File(path, "r") as f:
        stored = f["entries/nl1/energy/range/limit_pressure"]
        assert stored.shape == () and stored[()] == 1.5e5 and stored.attrs["units"].decode() == "Pa"
    with h5py.File(path, "r+") as f:
        f["entries/nl0/energy/range/pose_upper"][1] += 1e-3
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "range/pose_upper" in problems[0] and "disagrees" in problems[0]
