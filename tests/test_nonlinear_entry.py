"""Nonlinear entries end to end with the real nonlinear FE on coarse meshes: design, keys, storage,
the fit against the full trunk (the chain of FE-evaluated segments: exact domain decomposition),
the command line and sweep specs."""

import json
import subprocess
import sys

import numpy as np
import pytest

from vertebra import designer
from vertebra.designer.nonlinear_condensation import FamilySolid
from vertebra.store import catalogue
from vertebra.core.errors import OptionError, SpecError

from fitted_energies import ROD, nonlinear_rod
from fitted_energies import ROD_MESH as MESH
from fitted_energies import ROD_SAMPLING as SAMPLING
from reference.energy_chain import EntryEnergy, PointLoad, solve_chain


@pytest.fixture(scope="module")
def rod_entry():
    return nonlinear_rod()


def test_keys_linear_unchanged_nonlinear_distinct():
    """A linear entry's key does not depend on whether nonlinear materials exist; the material and
    every sampling setting enter a nonlinear entry's key."""
    from vertebra.designer.keys import key_payload
    from vertebra.store.entry import content_key

    linear = designer.entry_key("rod", ROD, mesh_size=MESH)
    assert linear == designer.entry_key("rod", ROD, mesh_size=MESH, material="linear", sampling={"degree": 8})
    payload = key_payload("rod", ROD, mesh_size=MESH)
    assert set(payload) == {"family", "parameters", "mesh", "versions"} and content_key(payload) == linear
    keys = {designer.entry_key("rod", ROD, mesh_size=MESH, material=m, sampling=s)
            for m, s in (("svk", None), ("neo_hookean", None), ("neo_hookean", {"degree": 8}),
                         ("neo_hookean", {"paths": 30}))}
    assert len(keys) == 4 and linear not in keys
    with pytest.raises(OptionError, match="unknown material 'rubber'"):
        designer.entry_key("rod", ROD, material="rubber")
    with pytest.raises(OptionError, match="sampling.degre"):
        designer.entry_key("rod", ROD, material="svk", sampling={"degre": 4})


@pytest.mark.slow
def test_nonlinear_rod_entry(rod_entry, tmp_path):
    """The entry carries ψ: its linear part is the linear entry's compliance (same mesh, same
    numbers), its held-out error is well below ψ_lin's, it is convex over the samples, and it
    survives the catalogue (verify checks the energy against the compliance)."""
    linear = designer.design_segment("rod", ROD, mesh_size=MESH, estimate_accuracy=False)
    assert np.array_equal(rod_entry.compliance, linear.compliance)
    assert rod_entry.key == designer.entry_key("rod", ROD, mesh_size=MESH, material="neo_hookean", sampling=SAMPLING)
    energy = rod_entry.energy
    held = energy.fit_error["held_out"]
    assert held["samples"] > 0 and held["load_max"] < 0.2 * held["linear_load_max"]
    assert energy.fit_error["convexity_min_relative_eigenvalue"] > 0.1
    assert energy.material["model"] == "neo_hookean" and energy.material["C10"] == pytest.approx(1e6 / 2.6 / 2)
    assert rod_entry.timings["sampling_s"] > 0
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, rod_entry)
    with catalogue.open_catalogue(path) as cat:
        assert cat.load(rod_entry.key).energy == energy
    assert catalogue.verify(path) == []


@pytest.mark.slow
def test_fitted_chain_against_the_full_nonlinear_trunk(rod_entry):
    """Two neo-Hookean rod segments with dead forces at both vertebrae in perpendicular directions
    (bending in 3D, ~45° at the tip), against the full nonlinear FE of the trunk (same mesh, rigid
    vertebrae): the fitted entry's tip is within 0.1 % of the trunk length (coarse sampling: 8
    paths; measured 0.008 % at 44°), ψ_lin's ≥ 0.3 % off (measured 0.54 %)."""
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads

    spec = FamilySolid("rod", json.dumps(rod_entry.parameters, sort_keys=True), MESH, 2, "neo_hookean")
    segment = spec.build()
    forces = {1: np.array([0.0, 1.5, 0.0]), 2: np.array([2.0, 0.0, -0.5])}
    reference = NonlinearTrunk([segment, segment]).solve(TrunkLoads(forces=forces))
    loads = [PointLoad(k, tuple(f)) for k, f in forces.items()]
    fitted = solve_chain([EntryEnergy(rod_entry)] * 2, loads)
    linear = solve_chain([EntryEnergy(rod_entry, linear_only=True)] * 2, loads)
    length = 2 * ROD["length"]
    assert reference.converged and 35 < np.degrees(fitted.tip_angle()) < 70
    fit_error = np.linalg.norm(fitted.tip_position - reference.positions[-1]) / length
    linear_error = np.linalg.norm(linear.tip_position - reference.positions[-1]) / length
    assert fit_error < 1e-3 and linear_error > 3e-3
    assert not fitted.left_range


@pytest.mark.slow
def test_design_cli_material_json(tmp_path):
    """``vertebra design rod --material svk`` with a local pool of 2 workers: the JSON names the
    material and summarises the energy; the catalogue verifies."""
    path = tmp_path / "cat.h5"
    args = ["design", "rod", *sum((["--set", f"{k}={v}"] for k, v in ROD.items()), []), "--mesh-size", str(MESH),
            "--material", "svk", "--sampling", "paths=2", "--sampling", "steps=2", "--sampling", "degree=4",
            "--no-accuracy", "--workers", "2", "--catalogue", str(path), "--json"]
    run = subprocess.run([sys.executable, "-m", "vertebra", *args], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    document = json.loads(run.stdout)
    assert document["material"] == "svk"
    assert document["energy"]["degree"] == 4 and document["energy"]["material"]["model"] == "svk"
    assert document["energy"]["sampling"]["samples"] > 0 and "sampling_s" in document["timing"]
    assert "nonlinear condensation with the svk material" in run.stderr
    bad = subprocess.run([sys.executable, "-m", "vertebra", "design", "rod", "--material", "rubber",
                          *sum((["--set", f"{k}={v}"] for k, v in ROD.items()), []), "--catalogue", str(path)],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "rubber" in bad.stderr


def test_sweep_spec_material():
    """Sweeps take the material and the sampling settings as design options (both in the key)."""
    from vertebra.designer.sweep.spec import keyed_options, parse_spec
    from vertebra.designer.sweep.tasks import expand

    fixed = {k: v for k, v in ROD.items() if k != "radius"}
    spec = parse_spec({"family": "rod", "parameters": fixed, "grid": {"radius": [0.01, 0.012]}, "material": "svk",
                       "sampling": {"degree": 4}})
    tasks = expand(spec)
    assert all(t.options["material"] == "svk" and t.options["sampling"] == {"degree": 4} for t in tasks)
    assert keyed_options(tasks[0].options)["material"] == "svk"
    assert parse_spec({"family": "rod", "parameters": fixed, "grid": {"radius": [0.01]}}).options["material"] == "linear"
    with pytest.raises(SpecError, match="rubber"):
        parse_spec({"family": "rod", "parameters": fixed, "grid": {"radius": [0.01]}, "material": "rubber"})
    with pytest.raises(SpecError, match=r"sampling: steps: 0 is out of range"):
        parse_spec({"family": "rod", "parameters": fixed, "grid": {"radius": [0.01]}, "material": "svk",
                    "sampling": {"steps": 0}})
