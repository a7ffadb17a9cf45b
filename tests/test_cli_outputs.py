"""Command-line polish: output files checked before any work, a closed stdout pipe, and
rounding-level actuator values printed as 0."""

from __future__ import annotations

import subprocess
import sys
import tomllib

import numpy as np
import pytest

from vertebra.cli.main import BROKEN_PIPE, main
from vertebra.cli.outputs import output_file, shown
from vertebra.solver import gallery
from vertebra.solver.scene import scene_toml
from vertebra.core.errors import OptionError


@pytest.mark.parametrize("argv, option", [
    (["simulate", "missing.toml", "--vtk", "shape.txt"], "--vtk"),
    (["simulate", "missing.toml", "--plot", "shape.vtu"], "--plot"),
    (["simulate", "missing.toml", "--plot", "no/such/dir/shape.png"], "--plot"),
    (["workspace", "missing.toml", "--points", "cloud.json"], "--points"),
    (["design", "rod", "--catalogue", "no/such/dir/parts.h5"], "--catalogue"),
    (["design", "rod", "--catalogue", "parts.h5", "--export-mesh", "mesh.stl"], "--export-mesh"),
])
def test_bad_output_files_are_refused_before_any_work(argv, option, capsys, tmp_path, monkeypatch):
    # the scene does not even exist: the option is checked first, so no solve or mesh can start
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and option in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_output_file_accepts_writable_paths(tmp_path):
    assert output_file(str(tmp_path / "a.PNG"), "--plot", (".png",)) == tmp_path / "a.PNG"
    assert output_file(None, "--plot", (".png",)) is None
    with pytest.raises(OptionError, match="is a directory"):
        output_file(str(tmp_path), "--points", None)


def test_closed_stdout_pipe_exits_quietly(tmp_path):
    # `vertebra simulate … --json | head -c 0`: the reader is gone before the document is
    # written; the command stops with the SIGPIPE convention and no traceback
    process = subprocess.Popen([sys.executable, "-m", "vertebra", "simulate", "gallery:tendon_two_section", "--json"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()
    err = process.stderr.read().decode()
    assert process.wait(timeout=120) == BROKEN_PIPE
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_rounding_level_values_print_as_zero():
    # below 1e-9 × 20 N = 2e-8 N is rounding; above it the value stays
    assert shown([5.0, 3.68e-31, -2e-10, 1e-8, 3e-8], 20.0, 1e-9).tolist() == [5.0, 0.0, 0.0, 0.0, 3e-8]


def test_simulate_prints_negligible_tension_as_zero(tmp_path, capsys):
    data = tomllib.loads(gallery.path("paper_3v_4t").read_text())
    data["cable"][0]["tension"] = 2.0
    data["cable"][1]["tension"] = 3.68e-31
    path = tmp_path / "robot.toml"
    path.write_text(scene_toml(data))
    assert main(["simulate", str(path)]) == 0
    lines = {line.split(":")[0].strip(): line for line in capsys.readouterr().out.splitlines()}
    assert "tension 2 N" in lines["cable t1"] and "tension 0 N" in lines["cable t2"]
    assert "e-31" not in lines["cable t2"]
