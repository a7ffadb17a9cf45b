"""The nonlinear mesh chosen by the design above a DoF threshold (designer.multifidelity): the
choice is made before meshing and is part of the key, recorded in the entry with the check's
verdict, and a failed check falls back to sampling the entry's own mesh. Below the threshold
nothing changes (settings, keys)."""

import numpy as np
import pytest

from vertebra import designer
from vertebra.designer import multifidelity
from vertebra.designer.energy_sampling import SamplingSettings
from vertebra.designer.families import canonical_parameters, family_of

from fitted_energies import ROD

FINE = 0.006                              # P2 rod: 2.1k DoFs (estimated 1.5k)
CBHA = {"outer_radius": 0.04, "chamber_radius": 0.01, "chamber_offset": 0.0215, "length": 0.03, "chambers": 3,
        "youngs_modulus": 5e5, "poisson_ratio": 0.45}
SAMPLING = {"paths": 4, "steps": 3, "degree": 4, "check_paths": 1}


@pytest.fixture
def low_threshold(monkeypatch):
    """Thresholds scaled down so that a 2k-DoF rod is 'large' and its chosen mesh about 8 mm."""
    monkeypatch.setattr(multifidelity, "AUTO_DOFS", 1_000)
    monkeypatch.setattr(multifidelity, "NONLINEAR_DOFS", 600)


def test_choice_threshold_and_unchanged_keys_below_it():
    """Below AUTO_DOFS the settings and keys are those of the policy switched off (and of the
    settings before the policy existed: no new field in the description); above it the chosen
    coarser mesh is in the key; an explicit mesh or auto_nonlinear_mesh=False is kept, and a
    segment with a cavity sampled under pressure is not given a coarser mesh."""
    fam = family_of("rod")
    p = canonical_parameters(fam, ROD)
    below, above = 0.0035, 0.0018                   # estimated 7.3k and 54k DoFs (P2)
    assert multifidelity.estimated_dofs(fam, p, below, 2) < multifidelity.AUTO_DOFS
    assert multifidelity.estimated_dofs(fam, p, above, 2) >= multifidelity.AUTO_DOFS
    assert multifidelity.estimated_dofs(fam, p, above, 1) < multifidelity.AUTO_DOFS      # P1: fewer DoFs
    default = SamplingSettings()
    assert set(default.describe()) == set(SamplingSettings.__dataclass_fields__) - {
        "auto_nonlinear_mesh", "nonlinear_mesh_chosen", "check_tolerance", "nonlinear_mesh_size", "check_paths",
        "cavities"}
    assert multifidelity.choose_nonlinear_mesh(fam, p, below, 2, default) is default
    chosen = multifidelity.choose_nonlinear_mesh(fam, p, above, 2, default)
    assert chosen.nonlinear_mesh_chosen and chosen.nonlinear_mesh_size == multifidelity.chosen_mesh_size(fam, p, 2)
    assert above < chosen.nonlinear_mesh_size < 0.005
    assert chosen.describe()["nonlinear_mesh_chosen"] is True
    explicit = SamplingSettings(nonlinear_mesh_size=0.005)
    assert multifidelity.choose_nonlinear_mesh(fam, p, above, 2, explicit) is explicit
    off = SamplingSettings(auto_nonlinear_mesh=False)
    assert multifidelity.choose_nonlinear_mesh(fam, p, above, 2, off) is off
    pneumatic = family_of("pneumatic")
    q = canonical_parameters(pneumatic, CBHA)
    assert multifidelity.estimated_dofs(pneumatic, q, 0.005, 2) >= multifidelity.AUTO_DOFS
    assert multifidelity.choose_nonlinear_mesh(pneumatic, q, 0.005, 2, default) is default    # pressurised
    unpressurised = multifidelity.choose_nonlinear_mesh(pneumatic, q, 0.005, 2, SamplingSettings(cavities=()))
    assert unpressurised.nonlinear_mesh_chosen and unpressurised.nonlinear_mesh_size > 0.005
    key = dict(material="neo_hookean")
    for h in (None, 0.008, 0.005, below):
        assert designer.entry_key("rod", ROD, mesh_size=h, **key) == designer.entry_key(
            "rod", ROD, mesh_size=h, sampling={"auto_nonlinear_mesh": False}, **key)
    auto = designer.entry_key("rod", ROD, mesh_size=above, **key)
    assert auto != designer.entry_key("rod", ROD, mesh_size=above, sampling={"auto_nonlinear_mesh": False}, **key)
    assert auto != designer.entry_key("rod", ROD, mesh_size=above, sampling={
        "nonlinear_mesh_size": chosen.nonlinear_mesh_size}, **key)      # the chosen one may fall back
    assert designer.entry_key("rod", ROD, mesh_size=above) == designer.entry_key(
        "rod", ROD, mesh_size=above, sampling={"nonlinear_mesh_size": 0.004})   # linear: no sampling at all


@pytest.mark.slow
def test_chosen_mesh_is_recorded_and_a_failed_check_falls_back(low_threshold):
    """Above the (lowered) threshold the design samples the chosen mesh and records the choice
    and the check's verdict; with a tolerance no check can meet it samples its own mesh instead
    and records why, with the same linear part; the verdict follows the check's numbers."""
    fam = family_of("rod")
    h = multifidelity.chosen_mesh_size(fam, canonical_parameters(fam, ROD), 2)
    assert FINE < h < 0.01
    options = dict(mesh_size=FINE, material="neo_hookean", estimate_accuracy=False)
    kept = designer.design_segment("rod", ROD, sampling={**SAMPLING, "check_tolerance": 10.0}, **options)
    coarse = kept.energy.sampling["nonlinear_mesh"]
    assert coarse["chosen"] and coarse["mesh_size"] == h and coarse["dofs"] < kept.mesh["dofs"]
    assert coarse["auto_dofs"] == 1_000 and coarse["estimated_entry_dofs"] >= 1_000
    verdict = kept.energy.sampling["entry_mesh_check"]["verdict"]
    assert verdict["passed"] and verdict["tolerance"] == 10.0
    assert kept.provenance["nonlinear"]["nonlinear_mesh_size"] == h
    assert kept.energy.sampling["settings"]["nonlinear_mesh_chosen"] is True

    fell = designer.design_segment("rod", ROD, sampling={**SAMPLING, "check_tolerance": 1e-9}, **options)
    energy = fell.energy
    assert "nonlinear_mesh" not in energy.sampling and "entry_mesh_check" not in energy.sampling
    assert "nonlinear_mesh_held_out" not in energy.fit_error
    fallback = energy.sampling["nonlinear_mesh_fallback"]
    assert not fallback["entry_mesh_check"]["verdict"]["passed"]
    assert "> 1e-09 (the tolerance)" in fallback["entry_mesh_check"]["verdict"]["why"]
    assert fallback["nonlinear_mesh"]["mesh_size"] == h
    assert "nonlinear_mesh_size" not in fell.provenance["nonlinear"] and fell.timings["fallback_s"] > 0
    assert np.array_equal(fell.compliance, kept.compliance)
    assert energy.sampling["solves"] > 0 and energy.fit_error["held_out"]["samples"] > 0
    assert fell.key != kept.key                              # the tolerance is part of the key

    default = designer.design_segment("rod", ROD, sampling=SAMPLING, **options)
    check = (default.energy.sampling.get("entry_mesh_check")
             or default.energy.sampling["nonlinear_mesh_fallback"]["entry_mesh_check"])
    held = (default.energy.fit_error["held_out"] if "entry_mesh_check" in default.energy.sampling
            else default.energy.sampling["nonlinear_mesh_fallback"]["held_out"])
    own = (default.energy.fit_error.get("nonlinear_mesh_held_out")
           or default.energy.sampling.get("nonlinear_mesh_fallback", {}).get("nonlinear_mesh_held_out"))
    passed = held["load_max"] <= multifidelity.CHECK_FACTOR * own["load_max"]
    assert check["verdict"]["passed"] == passed and check["verdict"]["factor"] == multifidelity.CHECK_FACTOR


def test_the_check_path_that_inflates_a_cavity_alone():
    """For a segment with a pressurised cavity the check adds the path that inflates the first
    pressurised cavity alone (no load, top pressure); none without one."""
    from vertebra.designer.energy_sampling import path_endpoints, pressure_path

    settings = SamplingSettings().resolved(3, "neo_hookean")
    endpoints, held = path_endpoints(3, settings)
    index = pressure_path(3, settings)
    assert not held[index] and np.array_equal(endpoints[index], [0, 0, 0, 0, 0, 0, 1, 0, 0])
    second = SamplingSettings(cavities=(1, 2)).resolved(3, "neo_hookean")
    endpoints, _ = path_endpoints(3, second)
    assert np.array_equal(endpoints[pressure_path(3, second)], [0, 0, 0, 0, 0, 0, 0, 1, 0])
    assert pressure_path(3, SamplingSettings(cavities=())) is None and pressure_path(0, SamplingSettings()) is None


def test_verdict_reads_the_free_inflation_response():
    """The verdict fails on the free inflation response even when the held-out errors pass
    (numbers of the CBHA-like slice at 12 mm with ψ_nl from 16 mm), and on a check path that
    stopped on a failed solve; a pose cap is no failure."""
    held, own = {"load_max": 0.0173, "volume_max": 0.0118}, {"load_max": 0.0869, "volume_max": 0.0193}
    inflation = {"entry_mesh": {"samples": 10, "pose_max": 0.0393, "volume_max": 0.0229},
                 "nonlinear_mesh": {"samples": 10, "pose_max": 0.0094, "volume_max": 0.0075}}
    passed, why = multifidelity.check_verdict({"held": held, "stopped": {"14": "pose beyond the caps"}}, own, None)
    assert passed
    passed, why = multifidelity.check_verdict({"held": held, "stopped": {}, "inflation": inflation}, own, None)
    assert not passed and "free inflation pose error 0.0393 > 0.0141" in why and "volume error 0.0229" in why
    passed, why = multifidelity.check_verdict({"held": held, "stopped": {"3": "no convergence"}}, own, None)
    assert not passed and "path 3 stopped" in why
    assert multifidelity.check_verdict({"held": held, "stopped": {}, "inflation": inflation}, own, 0.05)[0]
