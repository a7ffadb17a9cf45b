"""The energy of nonlinear entries (store.energy, catalogue schema v2): kernel, seam, range, storage."""

import dataclasses
import json

import h5py
import numpy as np
import pytest

from vertebra.store import catalogue, schema
from vertebra.store.energy import (EnergyFit, EnergyModel, EnergyRange, linear_terms, monomial_exponents,
                                   rest_strain_map)
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


def test_linear_terms_are_the_runtime_link_stiffness():
    """ψ_lin is the energy the runtime builds from a linear entry: same K_ξ = inv(A C Aᵀ) and
    pressure map A G as the linear-entry link kind (one link per entry), to round-off."""
    from vertebra import solver

    entry = dataclasses.replace(rod_entry(cavities=2), name="e", key="k")
    scene = solver.parse_scene({"catalogue": {"path": "unused.h5"},
                                "segment": [{"type": "entry", "entry": "e", "count": 1}],
                                "chamber": [{"name": "c", "cavity": 1, "from": 1, "to": 1, "pressure": 0.0}]})
    model = solver.build_model(scene, entries={"e": entry})
    K, S, V = linear_terms(entry.compliance, entry.rest_translation)
    quadratic = model.trunk.links.energies[0]               # the linear-entry link kind's energy
    assert np.allclose(quadratic.stiffness[0], K, rtol=1e-12, atol=1e-12 * np.abs(K).max())
    assert np.allclose(quadratic.pressure_strain[0][:, 0], S[:, 1], rtol=1e-12, atol=1e-14)
    xi0, _ = rest_strain_map(entry.rest_translation)
    assert np.allclose(model.link_rest[0], xi0, atol=1e-15)


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
    entry = dataclasses.replace(rod_entry(), key="nl1", name="nl", energy=dataclasses.replace(fit, range=shifted))
    catalogue.add_entry(path, entry)
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "does not contain the rest state" in problems[0]
