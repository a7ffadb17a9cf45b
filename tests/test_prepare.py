"""Scenes that name designs, and ``vertebra prepare``: design only the missing entries, reuse the rest.

Real designs (gmsh + scikit-fem) of coarse P2 rods (mesh_size 4 mm on 3-5 mm radii, ~1e3 DoFs,
no accuracy estimate): well under a second each, run in this process (serial executor).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from vertebra import designer, solver
from vertebra.cli.main import main
from vertebra.designer import prepare
from vertebra.designer.preparation import design_tasks, scene_designs
from vertebra.designer.sweep import DESIGN_OPTIONS, FiniteElementDesigner, parse_spec, plan_sweep
from vertebra.solver.scene import scene_toml
from vertebra.store import catalogue
from vertebra.core.errors import SceneError

MATERIAL = {"length": 0.02, "youngs_modulus": 1.0e6, "poisson_ratio": 0.3}
FAST = {"executor": "serial", "estimate_accuracy": False, "progress": False}


def rod(radius, count=1, **extra):
    return {"type": "design", "family": "rod", "parameters": {"radius": radius, **MATERIAL}, "mesh_size": 0.004,
            "count": count, **extra}


def scene_dict(*segments, catalogue="cat.h5", load=1e-3):
    data = {"name": "rods", "segment": list(segments),
            "load": [{"vertebra": -1, "force": [load, 0.0, 0.0]}], "effector": [{"name": "tip"}]}
    if catalogue is not None:
        data["catalogue"] = {"path": catalogue}
    return data


def write(path, data):
    path.write_text(scene_toml(data))
    return path


# ------------------------------------------------------------------ the scene side (no designer)

def test_design_segments_parse_as_data():
    scene = solver.parse_scene(scene_dict(rod(0.004, count=3, order=1, material="linear"), rod(0.003)))
    assert scene.n_vertebrae == 5 and scene.design_segments == (0, 1)
    design = scene.segments[0].design
    assert design.family == "rod" and design.parameter_dict() == {"radius": 0.004, **MATERIAL}
    assert design.options() == {"mesh_size": 0.004, "order": 1, "material": "linear"}
    assert scene.segments[1].design.options() == {"mesh_size": 0.004}          # the rest: designer defaults
    assert not scene.segments[0].resolved


@pytest.mark.parametrize("change,field,words", [
    ({"family": None}, "segment[0].family", "required"),
    ({"parameters": None}, "segment[0].parameters", "required"),
    ({"parameters": {}}, "segment[0].parameters", "missing"),
    ({"parameters": {"radius": "wide"}}, "segment[0].parameters.radius", "expected a number"),
    ({"order": 3}, "segment[0].order", "1 or 2"),
    ({"mesh_size": -0.001}, "segment[0].mesh_size", "> 0"),
    ({"material": "rubber"}, "segment[0].material", "linear, svk, neo_hookean"),
    ({"elements": 2}, "segment[0].elements", "must be 1"),
    ({"entry": "x"}, "segment[0].entry", "unknown field"),
])
def test_design_segment_errors_name_the_field(change, field, words):
    segment = rod(0.004)
    for key, value in change.items():
        if value is None:
            del segment[key]
        else:
            segment[key] = value
    with pytest.raises(SceneError) as info:
        solver.parse_scene(scene_dict(segment), source="s.toml")
    assert info.value.file == "s.toml" and info.value.field == field and words in info.value.reason


def test_an_unresolved_design_segment_cannot_be_built():
    scene = solver.parse_scene(scene_dict(rod(0.004), rod(0.003)), source="s.toml")
    with pytest.raises(SceneError) as info:
        solver.build_model(scene)
    assert info.value.field == "segment[0]" and "vertebra prepare" in info.value.reason


def test_the_runtime_reads_design_scenes_without_the_designer_or_the_fe_stack(tmp_path):
    # parsing a design scene and refusing to build it happen in the runtime alone
    path = write(tmp_path / "s.toml", scene_dict(rod(0.004)))
    code = ("import sys; from vertebra import solver; s = solver.load_scene(sys.argv[1]); "
            "assert s.design_segments == (0,)\n"
            "try:\n    solver.build_model(s)\nexcept Exception as e:\n    print(type(e).__name__)\n"
            "print([m for m in ('gmsh','skfem','meshio','pyamg','h5py','vertebra.designer') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["SceneError", "[]"]


# ------------------------------------------------------------------ keys: one computation for every caller

def test_a_sweep_and_a_scene_naming_the_same_design_share_the_key(tmp_path):
    # pneumatic: an integer parameter (chambers) that TOML scenes read as a number
    parameters = {"outer_radius": 0.02, "length": 0.015, "chamber_radius": 0.004, "chamber_offset": 0.011,
                  "youngs_modulus": 1.0e6, "poisson_ratio": 0.45, "chambers": 3}
    scene = solver.parse_scene({"segment": [{"type": "design", "family": "pneumatic", "parameters": parameters,
                                             "mesh_size": 0.003, "order": 1}]})
    [task] = design_tasks(scene_designs(scene), scene.source).tasks
    spec = parse_spec({"family": "pneumatic", "mesh_size": 0.003, "order": 1, "list": [parameters]})
    [planned] = plan_sweep(spec, tmp_path / "cat.h5").tasks
    scene_key = FiniteElementDesigner().key(dataclasses.replace(
        task, parameters=designer.canonical_parameters("pneumatic", task.parameters)))
    assert scene_key == planned.key == designer.entry_key("pneumatic", parameters, mesh_size=0.003, order=1)
    # and prepare reports that key without designing anything
    _, report = prepare(scene, tmp_path / "cat.h5", dry_run=True, **FAST)
    assert report.planned == [scene_key] and not (tmp_path / "cat.h5").exists()


def test_design_options_come_from_the_sweep_table():
    scene = solver.parse_scene(scene_dict(rod(0.004, order=1)))
    [task] = design_tasks(scene_designs(scene), scene.source, estimate_accuracy=False).tasks
    assert set(task.options) == {option.name for option in DESIGN_OPTIONS}
    assert task.options["order"] == 1 and task.options["mesh_size"] == 0.004
    assert task.options["estimate_accuracy"] is False and task.options["linear_solver"] == "auto"


# ------------------------------------------------------------------ prepare errors, before any design

@pytest.mark.parametrize("segment,field,words", [
    (rod(0.004) | {"family": "spring"}, "segment[0].family", "known: bellows, pneumatic, rod"),
    (rod(0.004) | {"parameters": {"raduis": 0.004, **MATERIAL}}, "segment[0].parameters",
     "unknown parameter 'raduis' (known: density, length, poisson_ratio, radius, youngs_modulus)"),
    (rod(0.004) | {"parameters": {"radius": -0.004, **MATERIAL}}, "segment[0].parameters", "'radius'"),
])
def test_prepare_refuses_what_the_family_refuses(tmp_path, segment, field, words):
    scene = solver.parse_scene(scene_dict(rod(0.003), segment), source="s.toml")
    scene = dataclasses.replace(scene, segments=(scene.segments[1], scene.segments[0]))
    with pytest.raises(SceneError) as info:
        prepare(scene, tmp_path / "cat.h5", **FAST)
    assert info.value.file == "s.toml" and info.value.field == field and words in info.value.reason
    assert not (tmp_path / "cat.h5").exists()                                    # nothing designed


def test_prepare_needs_a_catalogue(tmp_path):
    scene = solver.parse_scene(scene_dict(rod(0.004), catalogue=None), source="s.toml")
    with pytest.raises(SceneError) as info:
        prepare(scene, **FAST)
    assert info.value.field == "catalogue.path" and "--catalogue" in info.value.reason
    resolved, report = prepare(scene, tmp_path / "cat.h5", dry_run=True, **FAST)     # given one, it plans
    assert report.planned and resolved.catalogue == str(tmp_path / "cat.h5")


def test_a_nonlinear_material_is_planned_with_its_own_key(tmp_path):
    """A design segment with ``material = "neo_hookean"`` is planned under the nonlinear entry's key
    (material and sampling settings in it: the defaults, since this scene's 1 mN tip load stays far
    inside them); ``"linear"`` keeps the plain key."""
    nonlinear = solver.parse_scene(scene_dict(rod(0.004, material="neo_hookean")))
    linear = solver.parse_scene(scene_dict(rod(0.004, material="linear")))
    plain = solver.parse_scene(scene_dict(rod(0.004)))
    reports = [prepare(s, tmp_path / "cat.h5", dry_run=True, build_model=solver.build_model, **FAST)[1]
               for s in (nonlinear, linear, plain)]
    keys = [r.segments[0].key for r in reports]
    parameters = reports[0].segments[0].parameters
    assert keys[1] == keys[2] != keys[0]
    assert keys[0] == designer.entry_key("rod", parameters, mesh_size=0.004, material="neo_hookean")


# ------------------------------------------------------------------ acceptance, end to end

def test_a_design_scene_simulates_with_prepare_and_a_second_run_designs_nothing(tmp_path, capsys):
    # segments 0 and 2 are the same design: one entry serves both
    path = write(tmp_path / "rods.toml", scene_dict(rod(0.004, count=2), rod(0.003), rod(0.004)))
    assert main(["simulate", str(path), "--json"]) == 2                          # not prepared: bad input
    assert "segment[0]" in capsys.readouterr().err
    code = main(["simulate", str(path), "--prepare", "--executor", "serial", "--no-accuracy", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    forward = json.loads(captured.out)
    assert forward["converged"] and len(forward["vertebrae"]) == 5
    assert forward["effectors"]["tip"]["position"][0] > 1e-4                     # bent along +x by the tip load
    assert "2 designed" in captured.err and "0 reused" in captured.err

    assert main(["prepare", str(path), "--json", "--executor", "serial"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["designed"] == [] and len(again["reused"]) == 2 and "vertebra_version" in again
    assert [s["status"] for s in again["segments"]] == ["reused"] * 3
    assert again["segments"][0]["key"] == again["segments"][2]["key"] != again["segments"][1]["key"]
    with catalogue.open_catalogue(tmp_path / "cat.h5") as cat:
        assert sorted(cat.keys()) == sorted(again["reused"])

    # the resolved scene is an ordinary scene of entries: the same equilibrium, bit for bit
    resolved, _ = prepare(solver.load_scene(path), **FAST)
    assert [s.type for s in resolved.segments] == ["entry"] * 3 and resolved.segments[0].design is not None
    entries = scene_dict(*[{"type": "entry", "entry": s["key"], "count": s0["count"]}
                           for s, s0 in zip(again["segments"], [rod(0.004, count=2), rod(0.003), rod(0.004)])])
    plain = solver.build_model(solver.parse_scene(entries, base_dir=tmp_path)).solve()
    assert np.array_equal(solver.build_model(resolved).solve().state.positions, plain.state.positions)
    assert np.allclose(plain.state.positions[-1], forward["vertebrae"][-1]["position"], rtol=0, atol=1e-15)


def test_scenes_sharing_a_design_share_its_entry_and_one_edit_designs_one_entry(tmp_path):
    first = solver.parse_scene(scene_dict(rod(0.004), rod(0.003)), base_dir=tmp_path)
    _, report = prepare(first, **FAST)
    assert len(report.designed) == 2 and report.reused == []
    second = solver.parse_scene(scene_dict(rod(0.003), rod(0.005)), base_dir=tmp_path)
    _, report = prepare(second, **FAST)
    assert report.reused == [report.segments[0].key] and len(report.designed) == 1
    with catalogue.open_catalogue(tmp_path / "cat.h5") as cat:
        assert len(cat.keys()) == 3
    # editing one parameter of one segment: exactly one new entry
    edited = scene_dict(rod(0.004), rod(0.003))
    edited["segment"][1]["parameters"]["youngs_modulus"] = 2.0e6
    _, report = prepare(solver.parse_scene(edited, base_dir=tmp_path), **FAST)
    assert len(report.designed) == 1 and len(report.reused) == 1
    assert report.segments[0].status == "reused" and report.segments[1].status == "designed"


@dataclasses.dataclass(frozen=True)
class ThinRodsFail(FiniteElementDesigner):
    """The real designer, except that rods thinner than 3.5 mm fail (a design that breaks)."""

    def design(self, task):
        if task.parameters["radius"] < 0.0035:
            raise RuntimeError("meshing failed")
        return super().design(task)


def test_a_failed_design_is_reported_and_leaves_its_segment_unresolved(tmp_path):
    scene = solver.parse_scene(scene_dict(rod(0.004), rod(0.003)), base_dir=tmp_path)
    resolved, report = prepare(scene, designer=ThinRodsFail(), **FAST)
    assert report.exit_code == 1 and [s.status for s in report.segments] == ["designed", "failed"]
    assert resolved.segments[0].type == "entry" and resolved.segments[1].type == "design"
    assert "segment[1] failed [design] RuntimeError: meshing failed" in report.summary()
    record = json.loads((tmp_path / "cat.h5.failures.jsonl").read_text().splitlines()[-1])
    assert record["scene"] == scene.source and record["index"] == 1 and record["stage"] == "design"


def test_prepare_command_dry_run_and_catalogue_option(tmp_path, capsys):
    data = scene_dict(rod(0.004), catalogue=None)
    data["cable"] = [{"name": "pull", "radius": 0.003, "to": 1, "max_tension": 0.01}]
    data["effector"][0]["target"] = [0.0005, 0.0, 0.02]
    path = write(tmp_path / "rods.toml", data)
    assert main(["prepare", str(path), "--dry-run"]) == 2                        # no catalogue anywhere
    assert "catalogue.path" in capsys.readouterr().err
    other = tmp_path / "other.h5"
    assert main(["prepare", str(path), "--catalogue", str(other), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "0 reused, 1 to design" in out and "planned" in out and not other.exists()
    assert main(["simulate", str(path), "--prepare", "--catalogue", str(other), "--executor", "serial",
                 "--no-accuracy"]) == 0
    assert other.exists()
    assert main(["simulate", str(path), "--catalogue", str(other)]) == 0        # resolves from what prepare designed
    assert main(["invert", str(path), "--prepare", "--catalogue", str(other), "--json"]) in (0, 1)
    captured = capsys.readouterr()
    assert "1 reused, 0 designed" in captured.err and json.loads(captured.out.splitlines()[-1])["steps"]


def test_the_designer_never_imports_the_solver():
    """Dependency direction designer → store only: the designer reads scenes as data."""
    code = ("import sys, vertebra.designer, vertebra.designer.preparation, vertebra.designer.gallery, "
            "vertebra.designer.sweep, vertebra.designer.scene_range; "
            "print(','.join(m for m in sys.modules if m.startswith('vertebra.solver')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
