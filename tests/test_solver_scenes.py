"""Scene validation, the gallery, the CLI contract and the light import of the runtime."""

import json
import subprocess
import sys

import numpy as np
import pytest

from vertebra import solver
from vertebra.cli.main import main
from vertebra.solver import gallery
from vertebra.core.errors import SceneError

BEAM = {"type": "beam", "count": 2, "length": 0.02, "youngs_modulus": 54e9, "poisson_ratio": 0.3,
        "section": {"shape": "circle", "radius": 7e-4}}


def scene(**extra):
    data = {"segment": [dict(BEAM)]}
    data.update(extra)
    return data


@pytest.mark.parametrize("data,field,reason", [
    (scene(colour="red"), "colour", "unknown field"),
    ({"segment": [dict(BEAM, elastic=1)]}, "segment[0].elastic", "unknown field"),
    ({"segment": [dict(BEAM, count=0)]}, "segment[0].count", "must be > 0"),
    ({"segment": [dict(BEAM, count=1.5)]}, "segment[0].count", "expected an integer"),
    ({"segment": [dict(BEAM, youngs_modulus="steel")]}, "segment[0].youngs_modulus", "expected a number"),
    ({"segment": [dict(BEAM, poisson_ratio=0.5)]}, "segment[0].poisson_ratio", "must lie in"),
    ({"segment": [dict(BEAM, type="spring")]}, "segment[0].type", "must be one of"),
    ({"segment": [dict(BEAM, section={"shape": "tube", "outer_radius": 1e-3, "inner_radius": 2e-3})]},
     "segment[0].section.inner_radius", "must be smaller"),
    ({"segment": [{k: v for k, v in BEAM.items() if k != "length"}]}, "segment[0].length", "missing"),
    ({"segment": [{"type": "entry", "entry": "x"}]}, "catalogue.path", "need a [catalogue]"),
    ({"segment": []}, "segment", "at least one"),
    (scene(base={"quaternion": [1.0, 1.0, 0.0, 0.0]}), "base.quaternion", "unit norm"),
    (scene(gravity={"vector": [0.0, -9.81]}), "gravity.vector", "list of 3 numbers"),
    (scene(load=[{"vertebra": 3, "force": [1.0, 0, 0]}]), "load[0].vertebra", "out of range"),
    (scene(load=[{"vertebra": 0, "force": [1.0, 0, 0]}]), "load[0].vertebra", "clamped base"),
    (scene(cable=[{"name": "t", "radius": 0.01, "from": 2, "to": 1}]), "cable[0].to", "comes before"),
    (scene(cable=[{"name": "t", "radius": 0.01, "to": 2, "min_tension": 5.0, "max_tension": 1.0}]),
     "cable[0].min_tension", "exceeds"),
    (scene(cable=[{"name": "t", "radius": 0.01, "to": 2}, {"name": "t", "radius": 0.01, "to": 2}]),
     "cable[1].name", "duplicate"),
    (scene(solver={"tolerance": -1.0}), "solver.tolerance", "must be > 0"),
    (scene(version=2), "version", "unsupported"),
    ({"segment": [{k: v for k, v in BEAM.items() if k != "poisson_ratio"} | {"shear_modulus": 1e3}]},
     "segment[0].shear_modulus", "implies a Poisson ratio"),
    ({"segment": [dict(BEAM, vertebra={"inertia": ["a", "b", "c"]})]}, "segment[0].vertebra.inertia", "finite numbers"),
    ({"segment": [dict(BEAM, count=10**6, elements=1)]}, "segment", "at most 200000"),
    (scene(cable=[{"name": "t", "radius": float("inf"), "to": 2}]), "cable[0].radius", "finite"),
    (scene(cable=[{"name": "t", "radius": 0.01, "to": 2, "max_tension": float("inf")}]), None, None),
    (scene(effector=[{"name": "d", "axis": [0.0, 0.0, 0.0]}]), "effector[0].axis", "zero vector"),
    (scene(effector=[{"name": "d", "axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.01]}]), "effector[0].offset",
     "not both"),
])
def test_invalid_scenes_name_the_field_and_the_reason(data, field, reason):
    if field is None:       # a valid counterpart: infinity is accepted as an actuator bound
        assert solver.parse_scene(data, source="robot.toml").cables[0].max_tension == float("inf")
        return
    with pytest.raises(SceneError) as info:
        solver.parse_scene(data, source="robot.toml")
    assert info.value.file == "robot.toml" and info.value.field == field
    assert reason in info.value.reason
    assert str(info.value).startswith(f"robot.toml: {field}: ")


def test_negative_vertebra_indices_count_from_the_tip():
    parsed = solver.parse_scene(scene(effector=[{"name": "tip"}], load=[{"vertebra": -2, "force": [0, 0, 1.0]}]))
    assert parsed.effectors[0].vertebra == 2 and parsed.loads[0].vertebra == 1


def test_bad_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[segment]\n")
    with pytest.raises(SceneError, match="not valid TOML"):
        solver.load_scene(bad)
    with pytest.raises(SceneError, match="file not found"):
        solver.load_scene(tmp_path / "missing.toml")


RUNTIME_SCENES = [name for name in gallery.names() if not gallery.load(name).design_segments]


@pytest.mark.parametrize("name", RUNTIME_SCENES)
def test_every_gallery_scene_solves(name):
    model = solver.build_model(gallery.load(name))
    result = model.solve()
    assert result.converged and np.all(np.isfinite(result.state.positions))


def test_gallery_scenes_of_design_segments_need_prepare():
    # those are solved after `vertebra prepare` (tests/test_designer_gallery.py)
    designed = sorted(set(gallery.names()) - set(RUNTIME_SCENES))
    assert designed == ["cbha_design"]
    with pytest.raises(SceneError, match="segment\\[0\\].*vertebra prepare"):
        solver.build_model(gallery.load("cbha_design"))


def test_model_solves_many_times_with_new_inputs_without_recompiling():
    model = solver.build_model(gallery.load("paper_5v_16t"))
    trunk = model.trunk
    previous = None
    for k in range(3):
        actuation = np.zeros(16)
        actuation[k] = 2.0
        result = model.solve(actuation, initial=previous)
        previous = result.state
        assert result.converged
    assert model.trunk is trunk


def test_simulate_json_contract(tmp_path, capsys):
    path = gallery.path("tendon_two_section")
    code = main(["simulate", str(path), "--json", "--plot", str(tmp_path / "p.png"), "--vtk", str(tmp_path / "p.vtp")])
    out = capsys.readouterr().out
    document = json.loads(out)
    assert code == 0 and document["converged"] is True
    assert {"converged", "iterations", "residual", "vertebrae", "frames", "effectors", "cables", "chambers",
            "timing"} <= set(document)
    assert len(document["vertebrae"]) == 21 and len(document["frames"]) == 41
    cable = document["cables"]["s1-0"]
    assert set(cable) == {"tension", "length", "stroke", "route", "tensions", "stick"}
    # the route runs through the holes (proximal end first): one tension per span, one flag per interior hole
    assert len(cable["route"]) == len(cable["tensions"]) + 1 == len(cable["stick"]) + 2
    assert all(len(point) == 3 for point in cable["route"])
    assert cable["tensions"] == [cable["tension"]] * len(cable["tensions"])   # no friction: one tension
    assert not any(cable["stick"])
    assert document["timing"]["solve_s"] > 0
    assert (tmp_path / "p.png").stat().st_size > 10000
    from vtk_xml import read_vtp
    assert len(read_vtp(tmp_path / "p.vtp").points) >= 41


def test_simulate_bad_input_exits_2_and_non_convergence_exits_1(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[segment]]\ntype = "beam"\ncount = 1\nlength = 0.1\nyoungs_modulus = 1e9\nradius = 1\n')
    assert main(["simulate", str(bad)]) == 2
    assert "bad.toml: segment[0]" in capsys.readouterr().err
    hard = tmp_path / "hard.toml"
    hard.write_text('[solver]\nmax_iterations = 1\n[[segment]]\ntype = "beam"\nlength = 0.5\nelements = 10\n'
                    'youngs_modulus = 2e11\nsection = { shape = "circle", radius = 0.001 }\n'
                    '[[load]]\nvertebra = -1\nforce = [100.0, 0.0, 0.0]\n')
    assert main(["simulate", str(hard), "--json"]) == 1
    document = json.loads(capsys.readouterr().out)
    assert document["converged"] is False


def test_importing_the_runtime_pulls_in_no_heavy_stack():
    code = ("import sys, vertebra.solver, vertebra.solver.gallery, vertebra.solver.report; "
            "heavy = [m for m in ('gmsh','skfem','meshio','pyamg','matplotlib','dask','h5py') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""


def test_beam_only_scenes_never_touch_the_catalogue():
    code = ("import sys; from vertebra import solver; from vertebra.solver import gallery; "
            "solver.build_model(gallery.load('cantilever')).solve(); "
            "print('h5py' in sys.modules, 'vertebra.store.catalogue' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False False"


def test_the_documented_scene_example_is_valid():
    # docs/scenes.md shows every field; it must stay a valid scene (the entry name aside)
    import tomllib
    from pathlib import Path
    text = (Path(__file__).parents[1] / "docs" / "scenes.md").read_text()
    block = text.split("```toml")[1].split("```")[0]
    data = tomllib.loads(block.replace('"<catalogue key, unique key prefix or name>"', '"x"'))
    scene = solver.parse_scene(data, source="docs/scenes.md")
    assert scene.n_vertebrae == 23 and len(scene.cables) == 2 and scene.cables[1].stroke_driven and len(scene.chambers) == 1
    assert scene.design_segments == (2,) and scene.segments[2].design.material == "linear"
    assert scene.effectors[1].axis == (0.0, 0.0, 1.0) and abs(sum(v * v for v in scene.effectors[1].target) - 1) < 1e-12
    assert [o.type for o in scene.obstacles] == ["plane", "sphere"] and scene.segments[0].vertebra.disc_radius == 0.012
