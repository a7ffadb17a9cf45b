"""Unit slips are warned about, not refused: the warning names the file, the field, the value
and the unit the writer most likely meant; plausible values stay silent (every gallery scene).
The CLI prints each warning as one line on stderr and goes on."""

from __future__ import annotations

import copy
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.core import plausibility
from vertebra.core.errors import PlausibilityWarning
from vertebra.solver.scene import scene_toml

GALLERY = Path(solver.__file__).with_name("gallery")
TENDON = tomllib.loads((GALLERY / "paper_3v_4t.toml").read_text())
CHAMBER = {"type": "design", "family": "pneumatic", "count": 2, "mesh_size": 0.004,
           "parameters": {"outer_radius": 0.02, "length": 0.015, "chambers": 3, "chamber_radius": 0.004,
                          "chamber_offset": 0.011, "youngs_modulus": 1.0e6, "poisson_ratio": 0.45}}


def _messages(data, source="slip.toml"):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver.parse_scene(data, source=source)
    return [str(w.message) for w in caught if issubclass(w.category, PlausibilityWarning)]


@pytest.mark.parametrize("path", sorted(GALLERY.glob("*.toml")), ids=lambda p: p.stem)
def test_the_gallery_is_plausible(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        solver.load_scene(path)


def test_pressures_below_100_pa():
    data = {"catalogue": {"path": "c.h5"}, "segment": [CHAMBER],
            "chamber": [{"name": "c", "from": 1, "to": 2, "pressure": 1.5, "max_pressure": 2.0}]}
    found = _messages(data)
    assert found[0] == ("slip.toml: chamber[0].pressure = 1.5 Pa is below 100 Pa; pressures are in Pa: did you mean "
                        "1.5 bar (150000 Pa) or 1.5 kPa (1500 Pa)?")
    assert any("chamber[0].max_pressure = 2 Pa" in m for m in found) and len(found) == 2
    data["chamber"][0].update(pressure=5e4, max_pressure=1.5e5)
    assert _messages(data) == []


def test_moduli_below_1_kpa():
    data = copy.deepcopy(TENDON)
    data["segment"][0]["youngs_modulus"] = 54.0
    [message] = _messages(data)
    assert "segment[0].youngs_modulus = 54 Pa is below 1 kPa" in message and "54 GPa (5.4e+10 Pa)" in message
    design = copy.deepcopy(CHAMBER)
    design["parameters"]["youngs_modulus"] = 1.0
    [message] = _messages({"catalogue": {"path": "c.h5"}, "segment": [design]})
    assert "segment[0].parameters.youngs_modulus = 1 Pa" in message and "1 MPa (1e+06 Pa)" in message


def test_mesh_size_larger_than_the_part():
    design = {**CHAMBER, "mesh_size": 4.0}
    [message] = _messages({"catalogue": {"path": "c.h5"}, "segment": [design]})
    assert message == ("slip.toml: segment[0].mesh_size = 4 m is larger than the part (0.04 m across); lengths are "
                       "in m: did you mean 4 mm (0.004 m)?")


def test_cable_radius_beyond_the_vertebra_or_the_trunk():
    data = {"catalogue": {"path": "c.h5"}, "segment": [CHAMBER],
            "cable": [{"name": "t", "to": 2, "radius": 0.03}]}
    [message] = _messages(data)
    assert "cable[0].radius = 0.03 m puts the cable outside the vertebra (0.02 m radius)" in message
    data["cable"][0]["radius"] = 0.015
    assert _messages(data) == []
    tendon = copy.deepcopy(TENDON)
    tendon["cable"][0]["radius"] = 10.0
    [message] = _messages(tendon)
    assert "cable[0].radius = 10 m is larger than the whole trunk (0.09 m long)" in message and "10 mm" in message


def test_targets_beyond_reach():
    data = copy.deepcopy(TENDON)
    data["effector"][0]["target"] = [2.0, 1.0, 90.0]
    [message] = _messages(data)
    assert "effector[0].target lies 90.0278 m" in message and "did you mean mm" in message
    assert _messages(TENDON) == []


def test_the_cli_prints_one_line_per_warning_and_goes_on(tmp_path, capsys):
    data = copy.deepcopy(TENDON)
    data["segment"][0]["youngs_modulus"] = 54e3         # soft but plausible: silent
    path = tmp_path / "soft.toml"
    path.write_text(scene_toml(data))
    assert main(["simulate", str(path)]) in (0, 1)
    assert "warning" not in capsys.readouterr().err
    trajectory = tmp_path / "mm.csv"
    trajectory.write_text("t,tip.x,tip.y,tip.z\n0,1.9,0.9,89.9\n1,2.0,1.0,90.0\n")
    assert main(["invert", "gallery:paper_3v_4t", "--trajectory", str(trajectory), "--json"]) == 1
    warned = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warned == [f"vertebra invert: warning: {trajectory}: step 1, tip lies 90.0278 m from the base, 1000 times "
                      "the trunk's length of 0.09 m; lengths are in m: did you mean mm (0.0900278 m)?"]


def test_design_and_sweep_warn_about_their_parameters(tmp_path):
    with pytest.warns(PlausibilityWarning, match=r"--mesh-size = 4 m is larger than the part \(0\.02 m across\)"):
        plausibility.design({"radius": 0.005, "length": 0.02}, 4.0, mesh_field="--mesh-size")
    from vertebra.designer.sweep import plan_sweep
    from vertebra.designer.sweep.spec import parse_spec

    spec = parse_spec({"family": "rod", "parameters": {"length": 0.02, "poisson_ratio": 0.45},
                       "grid": {"radius": [0.005], "youngs_modulus": [5.0]}}, source="sweep.toml")
    with pytest.warns(PlausibilityWarning, match=r"sweep.toml: task 0: parameters.youngs_modulus = 5 Pa"):
        plan_sweep(spec, tmp_path / "c.h5")


def test_thresholds_leave_real_robots_alone():
    """The softest materials and pressures of real soft robots pass silently."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        plausibility.modulus(55e3, "Ecoflex 00-10")
        plausibility.pressure(2e3, "a low-pressure bellows")
        plausibility.pressure(0.0, "unpressurised")
        plausibility.reach(float(np.hypot(0.3, 0.4)), 0.5, "a target inside reach")
