"""The shipped examples run as tests (small settings), ship with the package, and
``vertebra examples DIR`` copies them out without overwriting anything."""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

import numpy as np
import pytest

from vertebra.cli.examples import example_files
from vertebra.cli.main import main

REPOSITORY = Path(__file__).resolve().parents[1]
EXAMPLES = REPOSITORY / "examples"

# scripts run by other test modules (too slow or too specific to repeat here)
RUN_ELSEWHERE = {"inverse/track_circle.py": "test_inverse_examples.py",
                 "cbha/design_cbha.py": "test_designer_gallery.py"}


def load(relative: str):
    path = EXAMPLES / relative
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_forward_example(tmp_path):
    # a tip tendon bends the robot towards its side (+x); the tip's stiffest direction is along
    # its backbone, the tip vertebra's z axis (axial compliance ~1e-5 m/N against ~3e-2 m/N
    # sideways: the direction is that axis to within the bending-axial coupling, a few degrees)
    summary = load("forward/bend_tendon_robot.py").run(tension=4.0, plot=tmp_path / "bend.png", quiet=True)
    assert summary["converged"]
    tip = np.array(summary["effectors"]["tip"])
    assert tip[0] > 0.01 and abs(tip[1]) < 0.25 * tip[0]
    values = summary["tip_principal_compliances_m_per_N"]
    assert 0 < values[0] < 1e-3 * values[-1]
    along, axis = np.array(summary["tip_stiffest_direction"]), np.array(summary["tip_axis"])
    assert abs(along @ axis) > np.cos(np.radians(5)) and axis[0] > 0.1     # tilted towards +x
    assert (tmp_path / "bend.png").stat().st_size > 0


@pytest.mark.parametrize("mode, tolerance", [("tick", 1e-4), ("converged", 1e-5)])
def test_trajectory_example(tmp_path, mode, tolerance):
    # the shipped circle was made by forward solves of the same robot: converged mode reaches it
    # to the micrometres of backbone compression between tendon directions. Tick mode starts at
    # rest, 1 cm from the first row, which needs ~10 N on a tendon — more than one tick may
    # change it (a quarter of its 0–20 N range): the first tick approaches (measured 5.3 mm
    # left, under the 1 cm it started from), then ticks lag the moving target by one
    # linearised step (well under 0.1 mm for this 10° spacing; measured 6e-6 m).
    summary = load("trajectory/follow_trajectory.py").run(mode=mode, steps=5, plot=tmp_path / "t.png", quiet=True)
    if mode == "tick":
        assert summary["steps"] == 5 and summary["final_error_m"] <= tolerance and summary["max_error_m"] < 0.01
    else:
        assert summary["steps"] == 5 and summary["max_error_m"] <= tolerance
    assert 0 < summary["max_tension_N"] <= 20.0
    assert (tmp_path / "t.png").stat().st_size > 0


def test_workspace_example(tmp_path):
    # every sample converges; the tip's reach is about symmetric about the axis (four tendons
    # at 90°), and its sideways compliance varies over the workspace (tension stiffens it)
    summary = load("workspace/map_workspace.py").run(samples=48, stiffness_samples=6, plot=tmp_path / "w.png",
                                                     quiet=True)
    assert summary["converged"] == 48 and summary["hull_volume_m3"] > 0
    lower, upper = np.array(summary["lower_m"]), np.array(summary["upper_m"])
    assert lower[0] < -0.02 and upper[0] > 0.02 and upper[2] <= 0.15 + 1e-9
    low, high = summary["tip_x_compliance_m_per_N"]
    assert 0 < low < high
    assert (tmp_path / "w.png").stat().st_size > 0


def test_design_sweep_example(tmp_path):
    # one coarse rod: its FE compliance is a little stiffer than the beam formulas (rigid end
    # faces restrain Poisson contraction and shear warping), within 15 %; a trunk of four solves
    module = load("sweeps/design_sweep.py")
    summary = module.run(catalogue=tmp_path / "parts.h5", first=1, executor="serial", quiet=True)
    (row,) = summary["entries"]
    assert 0.85 < row["axial_over_formula"] < 1.0 and 0.85 < row["bending_over_timoshenko"] < 1.0
    assert summary["converged"] and summary["tip"][0] > 0
    again = module.run(catalogue=tmp_path / "parts.h5", first=1, executor="serial", quiet=True)
    assert again["entries"] == summary["entries"]        # reused, not designed again


def test_every_example_script_is_run_by_a_test():
    scripts = sorted(str(p.relative_to(EXAMPLES)) for p in EXAMPLES.rglob("*.py"))
    here = Path(__file__).read_text()
    for script in scripts:
        if script in RUN_ELSEWHERE:
            assert Path(script).name in (Path(__file__).parent / RUN_ELSEWHERE[script]).read_text(), script
        else:
            assert f'load("{script}")' in here, f"{script} is run by no test"


def test_examples_ship_with_the_package():
    # every example folder is a listed package of the distribution, every data file matches its
    # package-data patterns, and the installed package finds them all
    config = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {p.parent for p in EXAMPLES.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    for folder in folders:
        package = ".".join(["vertebra", *folder.relative_to(REPOSITORY).parts])
        assert package in config["packages"], f"{package} missing from pyproject.toml packages"
        patterns = config["package-data"].get(package, [])
        for data in (p for p in folder.iterdir() if p.is_file() and p.suffix != ".py"):
            assert any(data.match(pattern) for pattern in patterns), f"{data} not in package-data of {package}"
    shipped = {name for name, _ in example_files()}
    expected = {str(p.relative_to(EXAMPLES)) for p in EXAMPLES.rglob("*")
                if p.is_file() and "__pycache__" not in p.parts}
    assert shipped == expected


def test_examples_command_copies_and_refuses_to_overwrite(tmp_path, capsys):
    target = tmp_path / "mine"
    assert main(["examples", str(target)]) == 0
    copied = sorted(str(p.relative_to(target)) for p in target.rglob("*") if p.is_file())
    assert copied == sorted(name for name, _ in example_files())
    assert (target / "sweeps" / "rod_grid.toml").read_bytes() == (EXAMPLES / "sweeps" / "rod_grid.toml").read_bytes()
    # a copied script runs where it was copied to (it finds its data files beside it)
    spec = importlib.util.spec_from_file_location("copy", target / "trajectory" / "follow_trajectory.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.run(steps=2, quiet=True)["steps"] == 2
    # a second copy into a directory holding one of the files writes nothing and exits 2
    other = tmp_path / "other"
    (other / "forward").mkdir(parents=True)
    (other / "forward" / "bend_tendon_robot.py").write_text("mine\n")
    capsys.readouterr()
    assert main(["examples", str(other)]) == 2
    message = capsys.readouterr().err
    assert "bend_tendon_robot.py" in message and "overwrite" in message
    assert [p.name for p in other.rglob("*") if p.is_file()] == ["bend_tendon_robot.py"]
    assert (other / "forward" / "bend_tendon_robot.py").read_text() == "mine\n"
    assert main(["examples", str(tmp_path / "missing" / "dir")]) == 2
