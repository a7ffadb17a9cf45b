"""Hostile inputs end in a domain error that names the file, the field and the limit — never a
traceback, never an allocation beyond the stated limit.

Each case is one a user (or a fuzzer) met: a scene saved as Latin-1, a binary file, ``/dev/zero``,
TOML nested thousands deep, a sweep of a million tasks, a name template that reads attributes,
NaN in a grid, 5,000 effectors (the effector compliance formed a 6.7 GB product), a negative
workspace seed. The CLI runs in-process (an uncaught exception would be a traceback) and, where
memory matters, in a subprocess capped at 2 GiB of address space.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main as cli_main
from vertebra.core.errors import OptionError, SceneError, SpecError, TrajectoryError
from vertebra.core.inputs import MAX_DEPTH, check_depth, load_toml, read_text
from vertebra.designer.sweep.samplers import MAX_TASKS
from vertebra.designer.sweep.spec import NameFormatter, parse_spec

GALLERY = Path(solver.__file__).with_name("gallery")
ROD = {"family": "rod", "mesh_size": 0.004, "parameters": {"youngs_modulus": 1e6, "poisson_ratio": 0.45,
                                                           "length": 0.02}}


def _cli(argv, capsys):
    code = cli_main([str(a) for a in argv])
    err = capsys.readouterr().err.strip()
    return code, err


# ---------------------------------------------------------------------------- reading files
def test_latin1_and_binary_files_are_input_errors(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "caf\xe9"\n'.encode("latin-1"))
    with pytest.raises(SceneError, match=r"not UTF-8 text: byte 0xe9 on line 1") as error:
        solver.load_scene(latin)
    assert error.value.file == str(latin)
    binary = tmp_path / "picture.toml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(SpecError, match="a binary file, not text"):
        load_toml(binary, SpecError)


def test_nul_in_a_path_and_directories(tmp_path):
    with pytest.raises(SceneError, match="NUL byte"):
        solver.load_scene("scene\x00.toml")
    with pytest.raises(SceneError, match="is a directory"):
        solver.load_scene(tmp_path)
    with pytest.raises(OptionError, match="NUL"):
        from vertebra.cli.outputs import output_file
        output_file("a\x00.png", "--plot", (".png",))


def test_dev_zero_is_refused_at_the_limit():
    with pytest.raises(SceneError, match=r"at most 1000 bytes; got more"):
        read_text("/dev/zero", SceneError, limit=1000)


@pytest.mark.parametrize("text", ["a = " + "[" * 5000 + "]" * 5000, "a = " + "{b = " * 3000 + "1" + "}" * 3000,
                                  "a = " + "[" * (MAX_DEPTH + 2) + "]" * (MAX_DEPTH + 2)])
def test_deep_nesting_is_refused(tmp_path, text):
    path = tmp_path / "deep.toml"
    path.write_text(text + "\n")
    with pytest.raises(SceneError, match=f"nested too deeply \\(at most {MAX_DEPTH} levels"):
        solver.load_scene(path)


def test_depth_check_of_dictionaries_given_in_code():
    deep = current = {}
    for _ in range(100):
        current["a"] = {}
        current = current["a"]
    with pytest.raises(SceneError, match="nested too deeply"):
        solver.parse_scene(deep)
    check_depth({"a": [1, [2, {"b": 3}]]}, SceneError)        # shallow: passes


def test_nul_in_a_scene_string_is_named(tmp_path):
    text = (GALLERY / "cantilever.toml").read_text()
    path = tmp_path / "nul.toml"
    path.write_text('[catalogue]\npath = "a\\u0000b.h5"\n' + text)
    with pytest.raises(SceneError, match="NUL character") as error:
        solver.load_scene(path)
    assert error.value.field == "catalogue.path"


def test_trajectory_limits(tmp_path):
    from vertebra.solver.inverse.trajectory import read_trajectory

    path = tmp_path / "t.csv"
    path.write_bytes("tip.x,tip.y,tip.z\n0.1,0,\xe90.3\n".encode("latin-1"))
    with pytest.raises(TrajectoryError, match="not UTF-8 text: byte 0xe9 on line 2"):
        read_trajectory(path, ["tip"])
    path.write_text("tip.x,tip.y,tip.z\n0.1,0.0,0.3\n")
    assert read_trajectory(path, ["tip"]).targets.shape == (1, 1, 3)


# ---------------------------------------------------------------------------- sweep specs
@pytest.mark.parametrize("template,reason", [
    ("{radius:999999999}", "width or precision at most 40; got 999,999,999"),
    ("{radius.__class__.__mro__}", "plain names"),
    ("{radius[0]}", "plain names"),
    ("{0}", "plain names"),
    ("{radius:{length}}", "nested fields"),
    ("x" * 500, "at most 200 characters; got 500"),
])
def test_name_templates_are_restricted(template, reason):
    with pytest.raises(SpecError, match=reason) as error:
        parse_spec({**ROD, "name": template, "grid": {"radius": [0.005]}})
    assert error.value.field == "name"


def test_name_formatter_fills_plain_templates():
    assert NameFormatter().fill("rod-r{radius:.3g}-{index:03d}-{family!r}", radius=0.00512, index=7,
                                family="rod") == "rod-r0.00512-007-'rod'"
    with pytest.raises(ValueError, match="plain names"):
        NameFormatter().fill("{radius.real}", radius=1.0)


def test_task_counts_are_bounded():
    with pytest.raises(SpecError, match=f"1,000,000 tasks; at most {MAX_TASKS:,}") as error:
        parse_spec({**ROD, "grid": {"radius": list(np.linspace(1e-3, 2e-3, 1000)),
                                    "youngs_modulus": list(np.linspace(1e6, 2e6, 1000))}})
    assert error.value.field == "grid"
    with pytest.raises(SpecError, match="100,000,000 tasks") as error:
        parse_spec({**ROD, "lhs": {"samples": 10**8, "seed": 1, "ranges": {"radius": [0.005, 0.01]}}})
    assert error.value.field == "lhs.samples"


def test_non_finite_values_in_a_sweep_are_refused():
    with pytest.raises(SpecError, match="finite number, got nan") as error:
        parse_spec({**ROD, "grid": {"radius": [float("nan"), 0.01]}})
    assert error.value.field == "grid.radius[0]"
    with pytest.raises(SpecError, match="finite number, got inf"):
        parse_spec({**ROD, "parameters": {**ROD["parameters"], "density": float("inf")}, "grid": {"radius": [0.01]}})


@pytest.mark.parametrize("setting,reason", [("paths", "at most 1,000; got 100,000,000"),
                                            ("steps", "at most 100; got 100,000,000"),
                                            ("hessian_weight", "finite number, got inf"),
                                            ("shear", "finite number, got inf")])
def test_sampling_settings_are_bounded(setting, reason):
    value = 10**8 if setting in ("paths", "steps") else float("inf")
    with pytest.raises(SpecError, match=reason) as error:
        parse_spec({**ROD, "material": "neo_hookean", "sampling": {setting: value}, "grid": {"radius": [0.01]}})
    assert error.value.field == "sampling"


# ---------------------------------------------------------------------------- workspace, effectors
def test_workspace_samples_and_seed(capsys):
    from vertebra.solver.workspace import MAX_SAMPLES, sample_unit

    with pytest.raises(OptionError, match=f"at most {MAX_SAMPLES:,} samples; got 100,000,000"):
        sample_unit(10**8, 4)
    with pytest.raises(OptionError, match="from 0 to 2\\*\\*63"):
        sample_unit(8, 4, seed=-1)
    code, err = _cli(["workspace", "gallery:paper_3v_4t", "--seed", "-1", "--samples", "8"], capsys)
    assert code == 2 and err == ("vertebra workspace: error: --seed: must be a whole number from 0 to 2**63 - 1, "
                                 "got -1")
    code, err = _cli(["workspace", "gallery:paper_3v_4t", "--samples", "100000000"], capsys)
    assert code == 2 and "--samples" in err and "at most 1,000,000" in err and "\n" not in err


def test_effector_compliance_of_many_effectors_in_chunks(monkeypatch):
    """The diagonal blocks only, a chunk of effectors at a time: the same numbers as the full
    product ``J K⁻¹ Jᵀ`` (to rounding: the same dot products, summed in the same order)."""
    from vertebra.solver import compliance

    scene = solver.load_scene(GALLERY / "paper_3v_4t.toml")
    import dataclasses
    from vertebra.solver.scene import EffectorSpec

    effectors = tuple(EffectorSpec(f"e{k}", 1 + k % 3, offset=(1e-3 * k, 0.0, 0.0)) for k in range(40))
    model = solver.build_model(dataclasses.replace(scene, effectors=effectors))
    result = model.solve()
    lin = model.linearise(result.state, result.actuation)
    J = compliance.effector_wrench_jacobian(model, result.state, lin)
    product = (J @ lin.solve(J.T)).reshape(40, 6, 40, 6)
    expected = product[np.arange(40), :, np.arange(40), :]
    monkeypatch.setattr(compliance, "CHUNK_VALUES", 6 * model.n_dof * 7)     # chunks of 7 effectors
    full = compliance.effector_compliance(model, result.state, result.actuation).full
    np.testing.assert_allclose(full, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


# ---------------------------------------------------------------------------- in a capped subprocess
def _capped(argv, cwd, seconds=60):
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "vertebra", *argv], capture_output=True, text=True, cwd=cwd,
                          timeout=seconds, preexec_fn=limit, env=env)


@pytest.mark.parametrize("argv", [["simulate", "/dev/zero"], ["sweep", "/dev/zero", "--catalogue", "c.h5"],
                                  ["invert", "gallery:paper_3v_4t", "--trajectory", "/dev/zero"]],
                         ids=["scene", "sweep", "trajectory"])
def test_dev_zero_in_two_gibibytes(argv, tmp_path):
    done = _capped(argv, tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "/dev/zero: larger than" in done.stderr and "at most" in done.stderr


def test_five_thousand_effectors_in_two_gibibytes(tmp_path):
    text = (GALLERY / "paper_3v_4t.toml").read_text().split("[[effector]]")[0]
    text += "".join(f'\n[[effector]]\nname = "e{k}"\nvertebra = -1\noffset = [{k * 1e-5}, 0.0, 0.0]\n'
                    for k in range(5000))
    (tmp_path / "many.toml").write_text(text)
    done = _capped(["simulate", "many.toml", "--json"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
