"""The CBHA-like gallery trunk: entries into a catalogue, reuse by key, a scene the runtime
solver accepts, and the physics of a pressurised chamber."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from vertebra.designer.gallery import CBHA_MAX_PRESSURE, cbha_catalogue, cbha_slices
from vertebra.solver.scene import load_scene, scene_toml


def test_cbha_slices_taper_and_are_valid():
    slices = cbha_slices(coarse=True)
    assert len(slices) == 16 and len({s["name"] for s in slices}) == 16
    from vertebra import designer
    for s in slices:
        designer.canonical_parameters("tapered_pneumatic", s["parameters"])     # no GeometryError
    # continuous taper: each slice starts where the previous one ended (within a section)
    for a, b in zip(slices, slices[1:]):
        if a["section"] == b["section"]:
            assert a["parameters"]["top_outer_radius"] == pytest.approx(b["parameters"]["bottom_outer_radius"])


@pytest.fixture(scope="module")
def cbha(tmp_path_factory):
    path = tmp_path_factory.mktemp("cbha") / "catalogue.h5"
    # coarse and without accuracy estimates to fit the test budget (the example keeps them)
    return path, cbha_catalogue(path, coarse=True, estimate_accuracy=False)


@pytest.mark.slow
def test_cbha_catalogue_entries_and_reuse(cbha):
    path, result = cbha
    keys = [row["key"] for row in result["entries"]]
    assert len(set(keys)) == 16 and not any(row["reused"] for row in result["entries"])
    again = cbha_catalogue(path, coarse=True, estimate_accuracy=False)
    assert [row["key"] for row in again["entries"]] == keys and all(row["reused"] for row in again["entries"])
    from vertebra.store import catalogue
    with catalogue.open_catalogue(path) as cat:
        entries = [cat.load(k) for k in keys]
    # thinner slices higher up: the bending compliance grows along each section
    bending = [e.C[3, 3] for e in entries]
    assert all(b1 > b0 for b0, b1 in zip(bending[:8], bending[1:8]))
    assert all(b1 > b0 for b0, b1 in zip(bending[8:], bending[9:]))


@pytest.mark.slow
def test_cbha_scene_solves_and_bends_away_from_the_pressurised_chamber(cbha, tmp_path):
    from vertebra import solver
    path, result = cbha
    scene = dict(result["scene"])
    text = scene_toml(scene)
    assert tomllib.loads(text)["chamber"][0]["max_pressure"] == CBHA_MAX_PRESSURE       # TOML round trip
    (tmp_path / "cbha.toml").write_text(text)
    model = solver.build_model(solver.load_scene(tmp_path / "cbha.toml"))
    assert model.n_chambers == 6
    rest = model.effector_positions(model.rest_state)[0]
    pressures = np.zeros(6)
    pressures[0] = CBHA_MAX_PRESSURE                          # section 1, chamber 0 (at +y)
    loaded = model.solve(pressures)
    assert loaded.converged
    tip = model.effector_positions(loaded.state)[0]
    # the pressurised side lengthens: the trunk bends towards −y, by more than 1 % of its length
    assert tip[1] < rest[1] - 0.01 * 0.44
    # the pressurised chamber grows, its volume growth is positive
    growth = model.actuator_displacements(loaded.state, pressures)
    assert growth[0] > 0


@pytest.mark.slow
def test_cbha_example_script_runs(cbha):
    """The example end to end (STYLE.md §9: examples run as tests). Its catalogue already holds
    the 16 coarse entries (same content keys), so the script reuses them instead of meshing."""
    import subprocess
    import sys
    from pathlib import Path
    path, _ = cbha
    script = Path(__file__).resolve().parents[1] / "examples" / "cbha" / "design_cbha.py"
    run = subprocess.run([sys.executable, str(script), "--out", str(path.parent), "--no-accuracy", "--simulate"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.count("reused") == 16 and "converged True" in run.stdout
    assert (path.parent / "cbha.toml").exists()


def test_the_gallery_design_scene_is_the_generated_one():
    """``gallery:cbha_design`` is ``cbha_design_scene()`` written out (regenerate the file with
    ``scene_toml(cbha_design_scene(), header)`` when the slices change)."""
    import dataclasses

    from vertebra import solver
    from vertebra.designer.gallery import cbha_design_scene
    from vertebra.solver import gallery
    stored = gallery.load("cbha_design")
    generated = solver.parse_scene(cbha_design_scene(coarse=True))
    assert dataclasses.replace(stored, source="") == dataclasses.replace(generated, source="")
    assert stored.design_segments == tuple(range(16)) and stored.catalogue is None


@pytest.mark.slow
def test_the_gallery_design_scene_prepares_from_the_catalogue_without_designing(cbha):
    """The gallery scene names the same designs as ``cbha_catalogue``: the same 16 keys, all reused."""
    from vertebra import solver
    from vertebra.designer import prepare
    path, result = cbha
    resolved, report = prepare(load_scene("gallery:cbha_design"), path, executor="serial", estimate_accuracy=False,
                               progress=False)
    assert report.designed == [] and report.reused == [row["key"] for row in result["entries"]]
    model = solver.build_model(resolved)
    assert model.n_chambers == 6 and model.solve().converged


@pytest.mark.slow
def test_cbha_ranges_cover_its_pressures_and_the_equilibria_between_corners(cbha, tmp_path):
    """Pressure bounds per cavity come from the chambers over each section; the strain and load
    ranges (64 pressure corners of the six chambers, linear entries) cover seeded random
    pressures inside the box."""
    from vertebra import solver
    from vertebra.designer.scene_range import estimate_ranges, group_coordinates
    path, result = cbha
    (tmp_path / "cbha.toml").write_text(scene_toml(result["scene"]))
    model = solver.build_model(solver.load_scene(tmp_path / "cbha.toml"))
    estimate = estimate_ranges(model)
    assert len(estimate.actuations) == 65 and estimate.failed == ()
    for segment in estimate.segments:
        assert segment.pressures == {c: (0.0, CBHA_MAX_PRESSURE) for c in range(3)}
    bending = [s.strain_upper[2] for s in estimate.segments]
    assert min(bending) > 0.0
    rng = np.random.default_rng(11)
    for pressures in CBHA_MAX_PRESSURE * rng.random((4, 6)):
        evaluation = model.evaluate(model.solve(pressures).state, pressures)
        strain = group_coordinates(evaluation.links.xi - model.link_rest)
        load = group_coordinates(evaluation.w)
        for link, s in enumerate(estimate.segments):            # one link per slice
            assert np.all(strain[link] >= s.strain_lower) and np.all(strain[link] <= s.strain_upper)
            assert np.all(load[link] >= s.load_lower) and np.all(load[link] <= s.load_upper)
