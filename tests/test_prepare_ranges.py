"""Nonlinear design segments prepared for a scene: the range their energy is sampled on comes from
the scene (its actuation corners, loads and chamber bounds), so the scene stays inside it.

Unit tests of the choice of settings use a coarse linear rod entry; the end-to-end tests design
coarse neo-Hookean rods (``fitted_energies.ROD`` on ``ROD_MESH``, 8 paths × 4 steps: ~6 s each).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pytest

from vertebra import designer, solver
from vertebra.cli.main import main
from vertebra.designer import prepare
from vertebra.designer.energy_sampling import SamplingSettings, load_box
from vertebra.designer.scene_range import (ANGLE_STEP, MAX_ANGLE, SegmentRange, actuation_box, actuation_corners,
                                           choose_sampling, round_angle, round_ratio)
from vertebra.solver.scene import scene_toml
from vertebra.store import catalogue
from vertebra.core.energy import linear_terms
from vertebra.core.errors import OptionError, SceneError

from fitted_energies import ROD, ROD_MESH, ROD_SAMPLING, nonlinear_rod

pytestmark = pytest.mark.slow      # the module designs linear and nonlinear entries (gmsh + scikit-fem, nonlinear sampling)

FAST = {"executor": "serial", "estimate_accuracy": False, "progress": False, "build_model": solver.build_model}
FIT = {"paths": ROD_SAMPLING["paths"], "steps": ROD_SAMPLING["steps"]}     # degree 6 is the default
TWIST_MOMENT = 0.1            # N m at the tip: twists each rod ~0.66 rad (linear), beyond the default 0.6 rad cap


@functools.cache
def linear_rod():
    return designer.design_segment("rod", ROD, mesh_size=ROD_MESH, estimate_accuracy=False)


def estimate(strain, load, pressures=None):
    """A SegmentRange with symmetric signed groups (axial, twist) and the given magnitudes."""
    strain, load = np.asarray(strain, float), np.asarray(load, float)
    sign = np.array([0.0, -1.0, 0.0, -1.0])
    return SegmentRange(0, sign * strain, strain, sign * load, load, pressures or {})


DEFAULTS = SamplingSettings().resolved(0, "neo_hookean")


def choose(range_, user=None, material="neo_hookean"):
    entry = linear_rod()
    return choose_sampling(range_, compliance=entry.compliance, rest_translation=entry.rest_translation,
                           radius=ROD["radius"], material=material, user=user)


# ------------------------------------------------------------------ the choice of settings

def test_grids():
    assert round_angle(math.radians(80.0)) == pytest.approx(math.radians(80.0), rel=1e-15)
    assert round_angle(math.radians(80.01)) == pytest.approx(math.radians(85.0), rel=1e-15)
    assert [round_ratio(v) for v in (0.3, 1.5e5, 1.43e5, 0.2501, 9.91)] == [0.3, 1.5e5, 1.5e5, 0.26, 10.0]


@pytest.mark.parametrize("seed", range(6))
def test_the_sampled_box_covers_the_estimate(seed):
    """Whatever the estimate (loads and strains up to ~3× what the default box holds), the load
    box and pose caps that the chosen settings give (load_box, the function the sampling uses)
    contain it — exactly, through the same linear compliance — unless a cap was clamped, which
    is then a warning. Below the default box, the defaults are kept."""
    entry = linear_rod()
    K, _, _ = linear_terms(entry.compliance, entry.rest_translation)
    length, radius = ROD["length"], ROD["radius"]
    default_box, default_caps = load_box(K, length, radius, DEFAULTS)
    rng = np.random.default_rng(seed)
    strain = default_caps * rng.uniform(0.0, 3.0, 4) * (rng.random(4) < 0.7)
    load = default_box.group_bounds() * rng.uniform(0.0, 3.0, 4) * (rng.random(4) < 0.7)
    choice = choose(estimate(strain, load))
    settings = SamplingSettings.from_dict(choice.settings).resolved(0, "neo_hookean")
    box, caps = load_box(K, length, radius, settings)
    clamped = {w.split()[4] for w in choice.warnings}                # "the scene asks for NAME ..."
    assert all("clamped" in w for w in choice.warnings)
    for g, name in enumerate(("shear", "axial", "bending", "twist")):
        if name in clamped or (name != "twist" and "bending" in clamped):   # the moment bound also bounds the forces
            continue
        assert box.group_bounds()[g] >= load[g] * (1 - 1e-12), (name, box, load)
        assert caps[g] >= strain[g] * (1 - 1e-12), (name, caps, strain)
    for name in ("bending", "twist", "strain", "shear", "axial"):
        assert choice.values[name] >= getattr(DEFAULTS, name)                       # never below the defaults
        assert (choice.sources[name] == "default") == (choice.values[name] == getattr(DEFAULTS, name))
    for name in ("bending", "twist"):
        if choice.sources[name] == "scene estimate":
            assert choice.values[name] / ANGLE_STEP == pytest.approx(round(choice.values[name] / ANGLE_STEP), abs=1e-9)


def test_inside_the_defaults_the_settings_and_the_key_are_the_defaults():
    entry = linear_rod()
    K, _, _ = linear_terms(entry.compliance, entry.rest_translation)
    box, caps = load_box(K, ROD["length"], ROD["radius"], DEFAULTS)
    choice = choose(estimate(0.5 * caps, 0.5 * box.group_bounds()))
    assert choice.settings == {} and set(choice.sources.values()) == {"default"} and choice.warnings == ()


def test_small_changes_of_the_estimate_keep_the_settings_and_beyond_pi_is_clamped():
    entry = linear_rod()
    K, _, _ = linear_terms(entry.compliance, entry.rest_translation)
    c = np.diag(np.linalg.inv(K))
    twist = math.radians(47.5)                                     # mid-step of the 5° grid
    base = choose(estimate([0, 0, 0, twist], [0, 0, 0, 0]))
    assert base.values["twist"] == pytest.approx(math.radians(50.0)) and base.sources["twist"] == "scene estimate"
    for factor in (0.97, 1.03):
        assert choose(estimate([0, 0, 0, factor * twist], [0, 0, 0, 0])).settings == base.settings
    # a load asks for the cap that carries it: twisting moment w needs the twist w·c
    by_load = choose(estimate([0, 0, 0, 0], [0, 0, 0, twist / c[5]]))
    assert by_load.settings == base.settings
    beyond = choose(estimate([0, 0, 4.0, 0], [0, 0, 0, 0]))
    assert beyond.values["bending"] == pytest.approx(MAX_ANGLE) and "clamped" in beyond.warnings[0]
    SamplingSettings.from_dict(beyond.settings)
    # St Venant-Kirchhoff softens towards a compressive limit point: its outer-fibre strain stays at
    # its default (0.25), the bending the scene asks beyond it is a warning; neo-Hooke raises it
    bent = estimate([0, 0, 1.8, 0], [0, 0, 0, 0])                      # 1.8 rad at L/r = 4: fibre strain 0.45
    svk, neo = choose(bent, material="svk"), choose(bent)
    assert svk.values["strain"] == 0.25 and svk.sources["strain"] == "default" and "svk" in svk.warnings[0]
    assert neo.values["strain"] == 0.45 and neo.sources["strain"] == "scene estimate" and neo.warnings == ()
    assert choose(estimate([0, 0, 1.2, 0], [0, 0, 0, 0])).values["strain"] == 0.4       # 0.3 < the default 0.4


def test_pressures_come_from_the_chambers():
    unbounded = choose(estimate([0] * 4, [0] * 4, {0: (0.0, math.inf), 1: (0.0, 5e4)}))
    assert unbounded.values["pressure"] is None and unbounded.sources["pressure"] == "scene chambers"
    assert "pressure" not in unbounded.settings                      # None is the default: up to the limit point
    bounded = choose(estimate([0] * 4, [0] * 4, {0: (0.0, 1.43e5), 2: (0.0, 1.0e5)}))
    assert bounded.settings["pressure"] == 1.5e5 and bounded.needed["pressure"] == 1.43e5
    vacuum = choose(estimate([0] * 4, [0] * 4, {0: (-2e4, 1e5)}))
    assert vacuum.settings["pressure"] == 1e5 and "from 0 up only" in vacuum.warnings[0]
    none = choose(estimate([0] * 4, [0] * 4))
    assert none.values["pressure"] is None and none.sources["pressure"] == "default"


def test_the_scenes_settings_win():
    choice = choose(estimate([0, 0, 0, 0.8], [0, 0, 0, 0], {0: (0.0, math.inf)}),
                    user={"twist": 0.5, "degree": 4, "pressure": 2e4})
    assert choice.values["twist"] == 0.5 and choice.sources["twist"] == "scene setting"
    assert choice.settings["degree"] == 4 and choice.settings["pressure"] == 2e4
    assert choice.sources["pressure"] == "scene setting"
    assert any("sampling.twist = 0.5" in w for w in choice.warnings)
    assert any("sampling.pressure = 20000.0" in w for w in choice.warnings)


# ------------------------------------------------------------------ end to end, real designs

def rod_segment(count=1, **parameters):
    return {"type": "design", "family": "rod", "parameters": {**ROD, **parameters}, "mesh_size": ROD_MESH,
            "material": "neo_hookean", "sampling": dict(FIT), "count": count}


def twisted_rods(*segments):
    """Rods twisted by a tip moment about the axis and bent by a cable (one actuation corner pair)."""
    return {"name": "twisted rods", "catalogue": {"path": "cat.h5"}, "segment": list(segments),
            "cable": [{"name": "pull", "radius": 0.008, "to": len(segments), "max_tension": 6.0}],
            "load": [{"vertebra": -1, "moment": [0.0, 0.0, TWIST_MOMENT]}], "effector": [{"name": "tip"}]}


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    """Two rods of one design, prepared from an empty catalogue."""
    directory = tmp_path_factory.mktemp("ranges")
    scene = solver.parse_scene(twisted_rods(rod_segment(), rod_segment()), base_dir=directory)
    resolved, report = prepare(scene, **FAST)
    return directory, scene, resolved, report


def _out_of_range_at_corners(model):
    lower, upper = actuation_box(model)
    found = []
    for actuation in np.vstack([model.default_actuation[None], actuation_corners(lower, upper)]):
        result = model.solve(actuation)
        assert result.converged
        found.extend(result.out_of_range)
    return found


def test_the_prepared_entries_cover_the_scene_at_its_actuation_corners(prepared):
    """The two rods share one design (one entry, the union of their ranges); the tip moment
    twists them beyond the default twist cap, so the estimate raises it. Solved with the
    prepared nonlinear entries, no corner leaves the fitted range; with the entry of the same
    design and fit sampled over the default range, the scene leaves it."""
    directory, scene, resolved, report = prepared
    assert report.exit_code == 0 and len(report.designed) == 1 and report.reused == []
    [counterpart] = {row.key for row in report.counterparts}
    assert counterpart == designer.entry_key("rod", ROD, mesh_size=ROD_MESH)
    row = report.segments[0]
    assert row.sampling.sources["twist"] == "scene estimate" and row.sampling.values["twist"] > 0.6
    assert row.sampling.settings["paths"] == FIT["paths"] and row.warnings == ()
    assert report.estimate is not None and report.estimate.failed == ()
    assert _out_of_range_at_corners(solver.build_model(resolved)) == []
    plain = nonlinear_rod()                                            # the same design sampled over the defaults
    assert plain.key == designer.entry_key("rod", ROD, mesh_size=ROD_MESH, material="neo_hookean", sampling=FIT)
    entries = {s.entry: plain for s in resolved.segments}
    outside = _out_of_range_at_corners(solver.build_model(resolved, entries))
    assert outside and {x.quantity for x in outside} >= {"twist strain"}


def test_a_second_run_designs_nothing_and_one_edit_designs_one_entry(prepared):
    directory, scene, _, first = prepared
    _, again = prepare(scene, **FAST)
    assert again.designed == [] and again.reused == first.designed
    assert {r.status for r in again.counterparts} == {"reused"}
    assert again.segments[0].sampling == first.segments[0].sampling
    edited = solver.parse_scene(twisted_rods(rod_segment(), rod_segment(youngs_modulus=1.2e6)), base_dir=directory)
    _, report = prepare(edited, **FAST)
    assert [s.status for s in report.segments] == ["reused", "designed"]
    assert report.segments[0].key == first.segments[0].key
    assert [r.status for r in report.counterparts] == ["reused", "designed"]       # and its new linear counterpart
    summary = report.summary()
    assert "1 reused, 1 designed" in summary and "linear counterparts" in summary
    # each nonlinear entry's fit: its held-out load error beside its linear entry's
    assert summary.count("fit: degree") == 2 and "held-out load error" in summary and "(linear entry" in summary
    with catalogue.open_catalogue(directory / "cat.h5") as cat:
        assert len(cat.keys()) == 4                                    # 2 nonlinear entries, 2 linear counterparts


def test_prepare_command_reports_the_range(prepared, capsys):
    directory = prepared[0]
    path = directory / "twisted.toml"
    path.write_text(scene_toml(twisted_rods(rod_segment(), rod_segment())))
    assert main(["prepare", str(path), "--executor", "serial"]) == 0
    out = capsys.readouterr().out
    assert "sampled for: bending" in out and "(scene estimate)" in out and "(default)" in out
    assert main(["prepare", str(path), "--executor", "serial", "--json", "--dry-run"]) == 0
    document = json.loads(capsys.readouterr().out)
    segment = document["segments"][0]
    assert segment["status"] == "reused" and segment["range"]["sources"]["twist"] == "scene estimate"
    assert document["counterparts"]["reused"] and document["range_estimate"]["actuations"] == 3


def test_the_scenes_sampling_settings_win_in_prepare(prepared):
    directory = prepared[0]
    segment = rod_segment()
    segment["sampling"]["twist"] = 0.5
    scene = solver.parse_scene(twisted_rods(segment, rod_segment()), base_dir=directory)
    _, report = prepare(scene, dry_run=True, **FAST)
    first, second = report.segments
    assert first.sampling.values["twist"] == 0.5 and first.sampling.sources["twist"] == "scene setting"
    assert any("sampling.twist = 0.5" in w for w in first.warnings)
    assert first.key != second.key and first.status == "planned" and second.status == "reused"
    assert first.key == designer.entry_key("rod", ROD, mesh_size=ROD_MESH, material="neo_hookean",
                                           sampling={**FIT, "twist": 0.5})


PNEUMATIC = {"outer_radius": 0.02, "length": 0.015, "chamber_radius": 0.004, "chamber_offset": 0.011,
             "youngs_modulus": 1.0e6, "poisson_ratio": 0.45, "chambers": 3}


@pytest.mark.parametrize("max_pressure,expected", [(math.inf, None), (4.3e4, 4.3e4)])
def test_chamber_bounds_set_the_pressure_range(tmp_path, max_pressure, expected):
    """A dry run designs the linear counterpart in memory only (nothing is written); an
    unbounded chamber samples up to the inflation limit (pressure None: the default key), a
    bounded one up to its bound."""
    data = {"catalogue": {"path": "cat.h5"},
            "segment": [{"type": "design", "family": "pneumatic", "parameters": PNEUMATIC, "mesh_size": 0.005,
                         "material": "neo_hookean", "count": 2}],
            "chamber": [{"name": "a", "cavity": 0, "from": 1, "to": 2, "max_pressure": max_pressure}]}
    scene = solver.parse_scene(data, base_dir=tmp_path)
    _, report = prepare(scene, dry_run=True, **FAST)
    [row] = report.segments
    assert row.sampling.values["pressure"] == expected and row.sampling.sources["pressure"] == "scene chambers"
    sampling = {} if expected is None else {"pressure": expected}
    assert row.key == designer.entry_key("pneumatic", PNEUMATIC, mesh_size=0.005, material="neo_hookean",
                                         sampling=sampling)
    assert "pressure" in row.sampling.describe() and not (tmp_path / "cat.h5").exists()


def test_unpressurised_cavities_are_not_sampled(tmp_path):
    """A pneumatic segment that no chamber of the scene pressurises is sampled at zero pressure
    (``sampling.cavities = []``: no inflation-limit ramp), a key of its own."""
    data = {"catalogue": {"path": "cat.h5"},
            "segment": [{"type": "design", "family": "pneumatic", "parameters": PNEUMATIC, "mesh_size": 0.005,
                         "material": "neo_hookean", "count": 2}]}
    _, report = prepare(solver.parse_scene(data, base_dir=tmp_path), dry_run=True, **FAST)
    [row] = report.segments
    assert row.sampling.settings["cavities"] == []
    assert "pressurised cavities: none" in row.sampling.describe()
    assert row.key == designer.entry_key("pneumatic", PNEUMATIC, mesh_size=0.005, material="neo_hookean",
                                         sampling={"cavities": []})
    assert row.key != designer.entry_key("pneumatic", PNEUMATIC, mesh_size=0.005, material="neo_hookean")


def test_nonlinear_segments_need_the_model_builder_and_valid_sampling(tmp_path):
    scene = solver.parse_scene(twisted_rods(rod_segment()), base_dir=tmp_path, source="s.toml")
    with pytest.raises(OptionError, match="build_model"):
        prepare(scene, executor="serial", progress=False, dry_run=True)
    bad = rod_segment()
    bad["sampling"]["degre"] = 4
    with pytest.raises(SceneError) as info:
        prepare(solver.parse_scene(twisted_rods(bad), base_dir=tmp_path, source="s.toml"), dry_run=True, **FAST)
    assert info.value.field == "segment[0].sampling" and "degre" in info.value.reason
    wrong = rod_segment()
    wrong["sampling"]["degree"] = "six"
    with pytest.raises(SceneError) as info:
        solver.parse_scene(twisted_rods(wrong), source="s.toml")
    assert info.value.field == "segment[0].sampling.degree"
    assert dataclasses.asdict(solver.parse_scene(twisted_rods(rod_segment())).segments[0].design)["sampling"] == \
        tuple(sorted(FIT.items()))


def test_prepare_refuses_an_entry_whose_fit_misses_where_the_scene_goes(prepared, capsys):
    """An entry whose held-out fit error where the scene goes exceeds ``max_fit_error`` is refused
    (reused or designed): status ``refused`` with the segment, the entry, the error and what to
    change; the segment stays unresolved, the exit code is 1; ``simulate`` without ``--prepare``
    stops with the same reason; ``inf`` accepts the fit (the coarse entry's held-out error is
    ~1e-3, so 1e-6 refuses it)."""
    directory, scene, _, first = prepared
    resolved, report = prepare(scene, max_fit_error=1e-6, **FAST)
    assert report.exit_code == 1 and report.refused == first.designed and report.designed == []
    row = report.segments[0]
    assert row.status == "refused" and row.key in row.refusal and "--max-fit-error" in row.refusal
    assert "held-out samples" in row.refusal and "more than the 1e-06 allowed" in row.refusal
    assert resolved.segments[0].type == "design"                              # not resolved to the refused entry
    summary = report.summary()
    assert "2 refused" not in summary and "1 refused" in summary and "segment[0] refused: entry" in summary
    assert report.to_json()["refused"] == first.designed and report.to_json()["segments"][0]["refusal"] == row.refusal
    with pytest.raises(SceneError, match=r"refused") as info:
        designer.preparation.resolve_prepared(scene, build_model=solver.build_model, max_fit_error=1e-6)
    assert info.value.field == "segment[0]"
    resolved, report = prepare(scene, max_fit_error=math.inf, **FAST)
    assert report.exit_code == 0 and report.refused == [] and resolved.segments[0].type == "entry"
    path = directory / "twisted.toml"
    path.write_text(scene_toml(twisted_rods(rod_segment(), rod_segment())))
    assert main(["prepare", str(path), "--executor", "serial", "--max-fit-error", "1e-6"]) == 1
    assert "refused" in capsys.readouterr().out
    assert main(["simulate", str(path), "--max-fit-error", "1e-6"]) == 2
    assert "refused" in capsys.readouterr().err
    assert main(["prepare", str(path), "--executor", "serial"]) == 0       # the default limit accepts it
