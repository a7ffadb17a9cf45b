"""No hang: implausible design parameters, meshes too large to finish, scene sizes that underflow.

Each case must end quickly in a clear error naming the parameter. The CLI cases run in a
subprocess with a deadline (120 s, far above the second or so they take) that only detects a
hang; nothing is timed.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from vertebra import designer
from vertebra.designer.geometry import mesh_segment
from vertebra.core.errors import GeometryError, SceneError

ROD = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
DEADLINE_S = 120


def _vertebra(*argv, catalogue):
    return subprocess.run([sys.executable, "-m", "vertebra", *argv, "--catalogue", str(catalogue)],
                          capture_output=True, text=True, timeout=DEADLINE_S)


@pytest.mark.parametrize("override, parameter, reason", [
    ({"radius": 1e300}, "radius", "1e+300 m is outside the plausible range"),
    ({"length": 1e-300}, "length", "1e-300 m is outside the plausible range"),
    ({"radius": 10.0, "length": 1e-4}, "radius", "radius / length = 1e+05 > 10000"),
    ({"youngs_modulus": 1e30}, "youngs_modulus", "1e+30 Pa is outside the plausible range"),
    ({"density": 1e9}, "density", "1e+09 kg/m^3 is above any material"),
])
def test_implausible_parameters_are_refused_before_meshing(override, parameter, reason):
    with pytest.raises(GeometryError) as info:
        designer.canonical_parameters("rod", {**ROD, **override})
    assert str(info.value).startswith(f"parameter '{parameter}': {reason}"), str(info.value)


def test_radius_1e300_through_the_cli(tmp_path):
    run = _vertebra("design", "rod", "--set", "radius=1e300", "--set", "length=0.04", "--set", "youngs_modulus=1e6",
                    "--set", "poisson_ratio=0.3", catalogue=tmp_path / "c.h5")
    assert run.returncode == 2 and "parameter 'radius'" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "c.h5").exists()


def test_a_mesh_too_large_is_refused_with_its_estimate(tmp_path):
    """h = 0.4 mm on a 10 mm × 40 mm rod: ~900,000 tetrahedra estimated (gmsh would mesh for
    minutes and the second-order assembly would need ~20 GB); refused before meshing, naming the
    estimate and the option that raises the cap."""
    run = _vertebra("design", "rod", "--set", "radius=0.01", "--set", "length=0.04", "--set", "youngs_modulus=1e6",
                    "--set", "poisson_ratio=0.3", "--mesh-size", "0.0004", "--order", "2",
                    catalogue=tmp_path / "c.h5")
    assert run.returncode == 2, run.stderr
    assert "tetrahedra" in run.stderr and "--max-elements" in run.stderr and "Traceback" not in run.stderr
    estimate = int(run.stderr.split("about ")[1].split(" tetrahedra")[0].replace(",", ""))
    assert 500_000 < estimate < 2_000_000


def test_max_elements_option_caps_and_the_estimate_is_close(tmp_path):
    """The estimate is within a factor 1.5 of what gmsh makes (fitted on every family from 5,000
    to 720,000 tetrahedra; this mesh has ~4,000)."""
    fam = designer.FAMILIES["rod"]
    p = designer.canonical_parameters(fam, ROD)
    messages = []
    mesh = mesh_segment(fam, p, 0.0025, 1, progress=messages.append)
    estimate = int(messages[0].split("about ")[1].split(" tetrahedra")[0].replace(",", ""))
    assert 1 / 1.5 < estimate / mesh.tets.shape[0] < 1.5, (estimate, mesh.tets.shape)
    with pytest.raises(GeometryError, match=r"more than max_elements = 1,000; use a larger mesh size"):
        mesh_segment(fam, p, 0.0025, 1, max_elements=1000)
    run = _vertebra("design", "rod", *[f"--set={k}={v}" for k, v in ROD.items()], "--mesh-size", "0.0025",
                    "--order", "1", "--max-elements", "1000", "--no-accuracy", catalogue=tmp_path / "c.h5")
    assert run.returncode == 2 and "max_elements = 1,000" in run.stderr


def test_scene_length_that_underflows_is_a_scene_error(tmp_path):
    from vertebra import solver

    scene = tmp_path / "tiny.toml"
    scene.write_text("""
[[segment]]
type = "beam"
count = 2
length = 1e-300
youngs_modulus = 1e6
poisson_ratio = 0.3
section = { shape = "circle", radius = 0.001 }
""")
    with pytest.raises(SceneError, match=r"segment\[0\]\.length: magnitude 1e-300 is below 1e-100"):
        solver.load_scene(scene)
