"""What a user trusts of the catalogue: tampered entries with recomputed checksums are refused
by every reader, identical designs are recognised as identical (wall-clock times aside, nonlinear
fits within the stored numbers' tolerance), and pool workers die with a killed parent."""

from __future__ import annotations

import dataclasses
import functools
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import tampering
from vertebra.core.errors import CatalogueError
from vertebra.store import catalogue, schema
from vertebra.store.shards import problem_files


@functools.cache
def _bases():
    return tampering.bases()


def test_sound_nonlinear_entries_are_read(tmp_path):
    """The bases of the tampering cases are sound: written the same way, every reader takes them."""
    for entry in (_bases().rod, _bases().pneumatic):
        path = tmp_path / f"{entry.name}.h5"
        tampering.write_resigned(path, entry)
        assert tampering.readers(path, entry.key) == {"verify": "accepted", "load": "accepted"}


def test_tampered_energies_with_recomputed_checksums_are_refused_by_every_reader(tmp_path):
    """Every kind of tampering on both bases (rod, pneumatic): 0 accepted by verify or load."""
    results = tampering.run(tmp_path, range(2 * len(tampering.KINDS)), _bases())
    accepted = [r for r in results if "accepted" in (r["verify"], r["load"])]
    assert {r["kind"] for r in results} == set(tampering.KINDS)
    assert accepted == []


@pytest.mark.parametrize("kind", ["non-convex quartic", "range excludes rest", "energy deleted"])
def test_the_cli_refuses_a_tampered_entry(tmp_path, kind):
    """show and simulate (not only verify) refuse: exit 2 and a message, no traceback."""
    from vertebra.cli.main import main

    bad = tampering.tamper(_bases().rod, kind, np.random.default_rng(0))
    path = tmp_path / "cat.h5"
    tampering.write_resigned(path, bad)
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[catalogue]\npath = "cat.h5"\n[[segment]]\ntype = "entry"\nentry = "{bad.key}"\ncount = 2\n')
    assert main(["catalogue", "verify", str(path)]) != 0
    assert main(["catalogue", "show", str(path), bad.key]) == 2
    assert main(["simulate", str(scene)]) == 2


def test_a_wall_clock_time_is_not_content():
    """Two designs that differ only in how long their accuracy estimate took have one content digest."""
    entry = _bases().rod
    a = dataclasses.replace(entry, accuracy={"method": "richardson", "relative_error": 0.01, "estimate_s": 1.5})
    b = dataclasses.replace(a, accuracy={**a.accuracy, "estimate_s": 7.25})
    c = dataclasses.replace(a, accuracy={**a.accuracy, "relative_error": 0.02})
    assert schema.EncodedEntry(a).content == schema.EncodedEntry(b).content
    assert schema.EncodedEntry(a).checksum != schema.EncodedEntry(b).checksum
    assert schema.EncodedEntry(a).content != schema.EncodedEntry(c).content


def _refit(entry, relative):
    fit = entry.energy
    scale = np.abs(fit.coefficients).max()
    noise = relative * scale * np.random.default_rng(1).uniform(-1, 1, size=fit.coefficients.size)
    return dataclasses.replace(entry, energy=dataclasses.replace(fit, coefficients=fit.coefficients + noise),
                               accuracy={**entry.accuracy, "estimate_s": float(relative)})


def test_concurrent_writers_of_one_nonlinear_design_all_succeed(tmp_path):
    """Two runs of one nonlinear design differ in the last bits of their fit (~2e-10): both
    writers succeed, in turn and through pending shards merged together, and nothing is set aside."""
    entry = _bases().rod
    again = _refit(entry, 2e-10)
    assert schema.EncodedEntry(entry).content != schema.EncodedEntry(again).content
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, entry)
    assert catalogue.add_entry(path, again) == entry.key
    other = tmp_path / "pending.h5"
    catalogue.add_entries(other, [entry], consolidate=False)
    catalogue.add_entries(other, [again], consolidate=False)
    report = catalogue.consolidate(other)
    assert report.conflicts == [] and list(problem_files(other)) == []
    assert catalogue.verify(path) == [] and catalogue.verify(other) == []


def test_another_nonlinear_design_under_the_same_key_still_conflicts(tmp_path):
    """The tolerance is on the last bits: a fit that differs by 1e-5 is another design."""
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, _bases().rod)
    with pytest.raises(CatalogueError, match="different content.*energy"):
        catalogue.add_entry(path, _refit(_bases().rod, 1e-5))


CHILD = textwrap.dedent("""
    import sys, time
    from vertebra.designer.executors import LocalExecutor
    with LocalExecutor(workers=2) as ex:
        for _ in ex.map_unordered(time.sleep, [60, 60]):
            pass
""")


def _children(pid: int) -> set[int]:
    out = set()
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as fh:
            out |= {int(x) for x in fh.read().split()}
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pool_workers_die_with_their_killed_parent():
    """SIGKILL of the process that owns a local pool: its workers end within seconds."""
    parent = subprocess.Popen([sys.executable, "-c", CHILD])
    try:
        deadline = time.monotonic() + 20
        workers: set[int] = set()
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.2)
            workers = {c for c in _children(parent.pid)
                       if b"resource_tracker" not in open(f"/proc/{c}/cmdline", "rb").read()}
        assert len(workers) >= 2, "the pool did not start"
        time.sleep(1.0)                              # initializers ran
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.1)
        alive = [w for w in workers if _alive(w)]
        for w in alive:                              # leave nothing behind if the test fails
            os.kill(w, signal.SIGKILL)
        assert alive == []
    finally:
        if parent.poll() is None:
            parent.kill()


def test_no_empty_shards_directory_is_left_beside_a_catalogue(tmp_path):
    """A merge that empties ``<catalogue>.shards/`` removes it; pending shards keep it."""
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, _bases().rod)
    assert not (tmp_path / "cat.h5.shards").exists()
    catalogue.add_entries(path, [_bases().pneumatic], consolidate=False)
    assert (tmp_path / "cat.h5.shards").is_dir()
    catalogue.consolidate(path)
    assert not (tmp_path / "cat.h5.shards").exists()
    assert len(catalogue.open_catalogue(path)) == 2 and catalogue.verify(path) == []


def test_catalogue_ls_and_show_name_the_material_and_the_fitted_range(tmp_path, capsys):
    from vertebra.cli.main import main

    path = tmp_path / "cat.h5"
    catalogue.add_entries(path, [_bases().pneumatic, tampering.bases().pneumatic.__class__(
        **{**{f.name: getattr(_bases().pneumatic, f.name) for f in dataclasses.fields(_bases().pneumatic)},
           "key": "plain", "name": "plain", "energy": None, "provenance": {}})])
    assert main(["catalogue", "ls", str(path)]) == 0
    out = capsys.readouterr().out
    assert "material" in out and "synthetic" in out and "linear" in out
    assert "fitted on: lateral ≤ 0.2 L" in out and "pressure ≤ 1.5e+05 Pa" in out
    assert main(["catalogue", "show", str(path), "tamper-pneumatic-nl"]) == 0
    out = capsys.readouterr().out
    assert "material   synthetic" in out and "fitted on  lateral" in out and "held-out load error" in out


def test_a_nonlinear_design_in_a_worker_reports_its_stages_while_prepare_shows_progress(monkeypatch, capsys):
    """``prepare`` (progress on) lets the worker designing a nonlinear entry print its stages
    (paths sampled, the fit's held-out errors) on stderr; linear entries and --no-progress stay quiet."""
    from vertebra.designer import preparation
    from vertebra.designer.sweep import tasks

    seen = []
    monkeypatch.setattr(tasks, "design_segment", lambda family, parameters, progress=None, **kw: seen.append(progress))
    task = dataclasses.make_dataclass("T", ["family", "parameters", "name", "options"])

    def design(material, on):
        seen.clear()
        with preparation._entry_progress(on):
            tasks.FiniteElementDesigner().design(task("rod", {}, "nl-rod", {"material": material}))
        return seen[0]

    assert design("neo_hookean", False) is None and design("linear", True) is None
    say = design("neo_hookean", True)
    say("  3/13 paths, 12 FE solves, 40.0 s")
    assert capsys.readouterr().err == "nl-rod:   3/13 paths, 12 FE solves, 40.0 s\n"
    assert os.environ.get("VERTEBRA_ENTRY_PROGRESS") is None


def test_a_file_whose_content_digests_include_the_estimate_time_still_verifies_and_takes_the_same_design(tmp_path):
    """Files written while ``estimate_s`` counted as content keep that digest in their index:
    verify accepts it, and the same design with another estimate time is no conflict."""
    import h5py

    entry = dataclasses.replace(_bases().rod, accuracy={"method": "richardson", "relative_error": 0.01,
                                                        "estimate_s": 3.0})
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, entry)
    enc = schema.EncodedEntry(entry)
    assert enc.legacy_content() != enc.content
    with h5py.File(path, "r+") as f:                 # as the earlier writer stored it
        f["entries"][entry.key].attrs["content"] = schema._fixed_string(enc.legacy_content())
        f["index"][0] = schema.canonical_json({**enc.index_row(), "content": enc.legacy_content()})
    assert catalogue.verify(path) == []
    again = dataclasses.replace(entry, accuracy={**entry.accuracy, "estimate_s": 9.0})
    assert catalogue.add_entry(path, again) == entry.key and catalogue.verify(path) == []
