"""Once ``vertebra prepare`` has designed a scene's entries, the same scene runs without
``--prepare``: its design segments resolve from the catalogue by the content keys prepare gave
them (the same plan, dry), nothing is designed, and a segment whose entry is missing is still
named by the error that says to run ``vertebra prepare``.

The linear rod is order 1 on a coarse mesh (~0.5 s to design); the nonlinear one is the
neo-Hookean rod of ``fitted_energies`` sampled on 8 paths × 4 steps (~6 s).
"""

from __future__ import annotations

import json

import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.core.errors import SceneError
from vertebra.designer import prepare
from vertebra.designer.preparation import resolve_prepared
from vertebra.solver.scene import scene_toml

from fitted_energies import ROD, ROD_MESH, ROD_SAMPLING

LINEAR_ROD = {"type": "design", "family": "rod", "order": 1, "mesh_size": 0.006, "count": 2,
              "parameters": {"radius": 0.005, "length": 0.02, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3}}


def _scene(directory, *segments, name="scene.toml"):
    data = {"name": "prepared rods", "catalogue": {"path": "cat.h5"}, "segment": list(segments),
            "cable": [{"name": "pull", "radius": 0.004, "to": sum(s["count"] for s in segments), "tension": 0.5,
                       "max_tension": 2.0}],
            "effector": [{"name": "tip", "target": [0.004, 0.0, 0.039]}]}
    path = directory / name
    path.write_text(scene_toml(data))
    return path


def test_prepare_then_simulate_and_invert_without_prepare(tmp_path, capsys):
    path = _scene(tmp_path, LINEAR_ROD)
    assert main(["simulate", str(path)]) == 2
    assert "has no catalogue entry yet: run `vertebra prepare" in capsys.readouterr().err
    assert main(["prepare", str(path), "--executor", "serial", "--no-accuracy", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["simulate", str(path), "--json"]) == 0
    forward = json.loads(capsys.readouterr().out)
    assert forward["converged"]
    with_prepare = main(["simulate", str(path), "--json", "--prepare", "--executor", "serial", "--no-accuracy"])
    assert with_prepare == 0
    assert json.loads(capsys.readouterr().out)["effectors"] == forward["effectors"]      # the same entry
    assert main(["invert", str(path), "--json"]) in (0, 1)
    assert json.loads(capsys.readouterr().out)["steps"]


def test_only_the_designed_entries_resolve(tmp_path):
    """An edited design (another Young's modulus) has another key: it stays unresolved and the
    error names its segment; the unchanged one resolves to the key prepare gave it."""
    path = _scene(tmp_path, LINEAR_ROD)
    resolved, report = prepare(solver.load_scene(path), executor="serial", estimate_accuracy=False, progress=False)
    [key] = report.designed
    edited = {**LINEAR_ROD, "parameters": {**LINEAR_ROD["parameters"], "youngs_modulus": 2.0e6}}
    scene = solver.load_scene(_scene(tmp_path, LINEAR_ROD, edited, name="edited.toml"))
    again = resolve_prepared(scene)
    assert again.segments[0].entry == key and again.segments[0].resolved
    assert not again.segments[1].resolved
    with pytest.raises(SceneError, match="has no catalogue entry yet") as error:
        again.check_resolved()
    assert error.value.field == "segment[1]"
    assert resolve_prepared(scene, tmp_path / "absent.h5").segments[0].resolved is False


@pytest.mark.slow
def test_nonlinear_design_segments_resolve_after_prepare(tmp_path, capsys):
    nonlinear = {"type": "design", "family": "rod", "parameters": dict(ROD), "mesh_size": ROD_MESH,
                 "material": "neo_hookean", "sampling": {"paths": ROD_SAMPLING["paths"], "steps": ROD_SAMPLING["steps"]},
                 "count": 1}
    path = _scene(tmp_path, nonlinear)
    scene = solver.load_scene(path)
    assert not resolve_prepared(scene, build_model=solver.build_model).segments[0].resolved
    prepared, report = prepare(scene, executor="serial", estimate_accuracy=False, progress=False,
                               build_model=solver.build_model)
    assert report.exit_code == 0
    resolved = resolve_prepared(scene, build_model=solver.build_model)
    assert resolved.segments == prepared.segments
    assert main(["simulate", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["converged"]
