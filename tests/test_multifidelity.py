"""Multi-fidelity nonlinear entries: the energy's nonlinear part sampled and fitted on a coarser
mesh of the segment, its linear part the exact one of the entry's mesh, its held-out error
measured with the FE of the entry's mesh (designer.nonlinear_condensation.check_on_mesh)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from vertebra import designer
from vertebra.core.energy import EnergyModel, linear_terms
from vertebra.core.errors import OptionError
from vertebra.designer.energy_sampling import SamplingSettings
from vertebra.store import catalogue

from fitted_energies import ROD

FINE, COARSE = 0.006, 0.008              # P2 rod: 2.1k and 1.1k DoFs
SAMPLING = {"paths": 6, "steps": 3, "degree": 6}


@pytest.fixture(scope="module")
def entries():
    multi = designer.design_segment("rod", ROD, mesh_size=FINE, material="neo_hookean", sampling=SAMPLING,
                                    estimate_accuracy=False, nonlinear_mesh_size=COARSE)
    fine_linear = designer.design_segment("rod", ROD, mesh_size=FINE, estimate_accuracy=False)
    coarse_linear = designer.design_segment("rod", ROD, mesh_size=COARSE, estimate_accuracy=False)
    return multi, fine_linear, coarse_linear


def _rest_hessian(entry) -> np.ndarray:
    model = EnergyModel.of_entry(entry)
    rest = model.evaluate(np.zeros((1, 6)), np.zeros((1, entry.n_cavities)))
    return rest.hessian[0]


@pytest.mark.slow
def test_linear_part_is_the_fine_mesh_one(entries):
    """The Hessian at rest is the fine mesh's K to 1e-12 (not the coarse one's: they differ by
    more than 1e-3), the compliance is the fine linear entry's, the nonlinear part came from the
    coarse mesh and the held-out error was measured on fine-mesh samples."""
    multi, fine, coarse = entries
    K_fine = linear_terms(fine.compliance, fine.rest_translation).stiffness
    K_coarse = linear_terms(coarse.compliance, coarse.rest_translation).stiffness
    H = _rest_hessian(multi)
    scale = np.abs(K_fine).max()
    assert np.abs(H - K_fine).max() <= 1e-12 * scale
    assert np.abs(K_coarse - K_fine).max() > 1e-3 * scale
    assert np.array_equal(multi.compliance, fine.compliance) and multi.mesh["dofs"] == fine.mesh["dofs"]
    energy = multi.energy
    assert energy.sampling["nonlinear_mesh"]["mesh_size"] == COARSE
    assert energy.sampling["nonlinear_mesh"]["dofs"] == coarse.mesh["dofs"]
    check = energy.sampling["entry_mesh_check"]
    assert check["mesh_size"] == FINE and len(check["paths"]) == 2 and check["solves"] > 0
    held, own = energy.fit_error["held_out"], energy.fit_error["nonlinear_mesh_held_out"]
    assert held["samples"] == check["samples"] > 0 and len(held["by_level"]) == held["samples"]
    assert held["load_max"] != own["load_max"]           # measured on other samples
    assert held["load_max"] < 0.3 * held["linear_load_max"]
    assert multi.provenance["nonlinear"]["nonlinear_mesh_size"] == COARSE
    assert multi.timings["check_s"] > 0 and multi.timings["nonlinear_mesh_s"] > 0


@pytest.mark.slow
def test_option_round_trips_in_the_catalogue(entries, tmp_path):
    """The option is part of the key (the same design without it is another entry) and survives
    the catalogue with its metadata; verify accepts the entry."""
    multi = entries[0]
    assert multi.key == designer.entry_key("rod", ROD, mesh_size=FINE, material="neo_hookean",
                                           sampling={**SAMPLING, "nonlinear_mesh_size": COARSE})
    assert multi.key != designer.entry_key("rod", ROD, mesh_size=FINE, material="neo_hookean", sampling=SAMPLING)
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, multi)
    with catalogue.open_catalogue(path) as cat:
        loaded = cat.load(multi.key)
    assert loaded.energy == multi.energy and np.array_equal(loaded.compliance, multi.compliance)
    assert loaded.energy.sampling["settings"]["nonlinear_mesh_size"] == COARSE
    assert SamplingSettings.from_dict(loaded.energy.sampling["settings"]).nonlinear_mesh_size == COARSE
    assert catalogue.verify(path) == []
    shown = subprocess.run([sys.executable, "-m", "vertebra", "catalogue", "show", str(path), multi.key],
                           capture_output=True, text=True, timeout=120)
    assert shown.returncode == 0, shown.stderr
    assert f"coarser mesh, asked for: h = {COARSE} m" in shown.stdout


def test_default_key_and_bad_options():
    """Without the option the settings' description (and so every existing key) is unchanged; a
    mesh that is not coarser, a linear material or a non-number is refused before meshing."""
    assert "nonlinear_mesh_size" not in SamplingSettings().describe()
    assert "check_paths" not in SamplingSettings(check_paths=3).describe()
    assert SamplingSettings(nonlinear_mesh_size=0.01).describe()["check_paths"] == 2
    with pytest.raises(OptionError, match="not coarser") as caught:
        designer.design_segment("rod", ROD, mesh_size=FINE, material="neo_hookean", nonlinear_mesh_size=FINE)
    assert caught.value.field == "sampling.nonlinear_mesh_size"
    with pytest.raises(OptionError, match="no nonlinear part"):
        designer.design_segment("rod", ROD, mesh_size=FINE, nonlinear_mesh_size=COARSE)
    with pytest.raises(OptionError, match="sampling.nonlinear_mesh_size"):
        SamplingSettings(nonlinear_mesh_size=-1.0)
    with pytest.raises(OptionError, match="sampling.check_paths"):
        SamplingSettings(nonlinear_mesh_size=0.01, check_paths=0)
    bad = subprocess.run([sys.executable, "-m", "vertebra", "design", "rod",
                          *sum((["--set", f"{k}={v}"] for k, v in ROD.items()), []), "--mesh-size", str(FINE),
                          "--nonlinear-mesh-size", str(COARSE), "--catalogue", "unused.h5"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "no nonlinear part" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.slow
def test_design_cli_nonlinear_mesh_size(tmp_path):
    """``vertebra design --nonlinear-mesh-size`` stores the option; the JSON shows the coarse mesh
    and the check on the entry's mesh."""
    path = tmp_path / "cat.h5"
    args = ["design", "rod", *sum((["--set", f"{k}={v}"] for k, v in ROD.items()), []), "--mesh-size", str(FINE),
            "--material", "neo_hookean", "--nonlinear-mesh-size", str(COARSE), "--sampling", "paths=2",
            "--sampling", "steps=2", "--sampling", "degree=4", "--sampling", "check_paths=1", "--no-accuracy",
            "--workers", "2", "--catalogue", str(path), "--json"]
    run = subprocess.run([sys.executable, "-m", "vertebra", *args], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    document = json.loads(run.stdout)
    sampling = document["energy"]["sampling"]
    assert sampling["nonlinear_mesh"]["mesh_size"] == COARSE and len(sampling["entry_mesh_check"]["paths"]) == 1
    assert "check_s" in document["timing"] and "check on the entry's mesh" in run.stderr
