"""``vertebra design``: the DESIGN.md §5 JSON document, reuse by content key, exit codes,
and four processes designing into one catalogue at the same moment."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

ROD = ["--set", "radius=0.01", "--set", "length=0.04", "--set", "youngs_modulus=1e6", "--set", "poisson_ratio=0.3"]


def _command(*args) -> list[str]:
    """``vertebra <args>`` as a separate process (the installed entry point's module)."""
    return [sys.executable, "-m", "vertebra.cli.main", *args]


def _run(*args, timeout=300):
    return subprocess.run(_command(*args), capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_design_json_document_and_reuse(tmp_path):
    catalogue = str(tmp_path / "cat.h5")
    vtu = tmp_path / "rod.vtu"
    first = _run("design", "rod", *ROD, "--mesh-size", "0.01", "--catalogue", catalogue, "--json", "--name", "rod-a",
                 "--export-mesh", str(vtu))
    assert first.returncode == 0, first.stderr
    document = json.loads(first.stdout)                       # stdout holds one JSON document only
    assert set(document) == {"vertebra_version", "key", "name", "compliance", "cavity_volumes", "mass", "dofs",
                             "accuracy", "timing", "material"}
    assert document["vertebra_version"] == __import__("vertebra").__version__
    assert document["material"] == "linear"
    assert set(document["timing"]) == {"mesh_s", "assemble_s", "solve_s", "total_s"}
    C = np.array(document["compliance"])
    assert C.shape == (6, 6) and np.array_equal(C, C.T)
    assert document["name"] == "rod-a" and document["cavity_volumes"] == [] and document["dofs"] > 0
    assert document["accuracy"]["method"] == "richardson" and document["accuracy"]["relative_error"] > 0
    from vertebra import designer
    assert document["key"] == designer.entry_key("rod", {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6,
                                                         "poisson_ratio": 0.3}, mesh_size=0.01)
    assert "meshing" in first.stderr                           # progress goes to stderr
    # the exported mesh is the one that was condensed: same element and node counts (round trip)
    import meshio
    from vertebra.store import catalogue as store_catalogue
    with store_catalogue.open_catalogue(catalogue) as cat:
        stored = cat.load(document["key"])
    mesh = meshio.read(vtu)
    assert len(mesh.cells_dict["tetra10"]) == stored.mesh["elements"] and len(mesh.points) == stored.mesh["nodes"]
    assert set(np.unique(np.concatenate(mesh.cell_data["group"]))) == {0, 1, 2, 3}   # volume, bottom, top, wall
    again = _run("design", "rod", *ROD, "--mesh-size", "0.01", "--catalogue", catalogue, "--json")
    assert again.returncode == 0, again.stderr
    assert "already in" in again.stderr and "meshing" not in again.stderr
    assert json.loads(again.stdout)["compliance"] == document["compliance"]


def test_design_bad_input_exits_2_naming_the_parameter(tmp_path):
    result = _run("design", "pneumatic", "--set", "outer_radius=0.01", "--set", "chamber_radius=0.004",
                  "--set", "chamber_offset=0.007", "--set", "length=0.02", "--set", "youngs_modulus=1e6",
                  "--set", "poisson_ratio=0.45", "--catalogue", str(tmp_path / "c.h5"))
    assert result.returncode == 2
    assert "'chamber_offset'" in result.stderr and "pierce" in result.stderr
    assert result.stdout == "" and not (tmp_path / "c.h5").exists()     # rejected before any work


@pytest.mark.parametrize("argv, field", [
    (["design", "rod", *ROD], "--catalogue"),                          # nowhere to put the entry
    (["design", "rod", "--set", "radius", "--catalogue", "c.h5"], "--set"),
    (["design", "rod", "--set", "radius=ten", "--catalogue", "c.h5"], "--set"),
    (["design", "spring", *ROD, "--catalogue", "c.h5"], "FAMILY"),
])
def test_design_bad_options_are_option_errors_and_exit_2(argv, field, capsys):
    # Command-line mistakes are OptionErrors naming the option (before any meshing);
    # cli.main alone turns them into exit code 2 and a one-line message.
    from vertebra.cli.main import build_parser, main
    from vertebra.core.errors import OptionError

    args = build_parser().parse_args(argv)
    with pytest.raises(OptionError) as info:
        args._run(args)
    assert info.value.field == field
    assert main(argv) == 2
    assert capsys.readouterr().err.startswith(f"vertebra design: error: {field}: ")


def test_design_vertebra_prints_scene_snippet():
    result = _run("design", "vertebra", "--set", "radius=0.02", "--set", "thickness=0.003", "--set", "density=1200",
                  "--set", "holes=3", "--set", "hole_radius=0.001", "--set", "hole_offset=0.015")
    assert result.returncode == 0, result.stderr
    import tomllib
    vertebra = tomllib.loads(result.stdout)["vertebra"]
    assert vertebra["mass"] == pytest.approx(1200 * 0.003 * np.pi * (0.02 ** 2 - 3 * 0.001 ** 2), rel=1e-5)


@pytest.mark.slow
def test_four_simultaneous_design_processes_on_one_catalogue(tmp_path):
    catalogue = str(tmp_path / "shared.h5")
    radii = ["0.008", "0.009", "0.010", "0.011"]
    processes = [subprocess.Popen(_command("design", "rod", "--set", f"radius={r}", "--set", "length=0.03",
                                           "--set", "youngs_modulus=1e6", "--set", "poisson_ratio=0.3",
                                           "--mesh-size", "0.01", "--order", "1", "--no-accuracy",
                                           "--catalogue", catalogue, "--json"),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for r in radii]
    outputs = [p.communicate(timeout=300) for p in processes]
    for p, (out, err) in zip(processes, outputs):
        assert p.returncode == 0, err
    keys = {json.loads(out)["key"] for out, _ in outputs}
    assert len(keys) == 4
    listing = _run("catalogue", "ls", catalogue, "--json")
    assert listing.returncode == 0, listing.stderr
    assert {row["key"] for row in json.loads(listing.stdout)} == keys
    verify = _run("catalogue", "verify", catalogue)
    assert verify.returncode == 0, verify.stdout + verify.stderr


def test_pressurised_option_names_the_sampled_cavities():
    """``--pressurised``: all (the default settings), none, or indices; anything else is refused
    naming the option."""
    from vertebra.cli.design import parse_pressurised
    from vertebra.core.errors import OptionError

    assert parse_pressurised("all") is None and parse_pressurised("NONE") == []
    assert parse_pressurised("0,2") == [0, 2]
    for bad in ("zero", "-1", "0,,1"):
        with pytest.raises(OptionError, match="--pressurised"):
            parse_pressurised(bad)
