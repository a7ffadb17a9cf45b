"""Hostile and damaged catalogues: seeded corruption fuzz, crafted files, disk faults, lock waits.

Every command on a damaged or crafted file must end in a one-line CatalogueError (CLI exit 2)
or in a correct result: never a traceback, never a hang, never data other than what was stored.
The fuzz here is small (100 seeded cases, well under a minute); benchmarks/bench_catalogue_fuzz.py
runs a larger one. Nothing here is timed: deadlines only bound how long a case may run.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import corruption
from vertebra.store import catalogue, schema, shards
from vertebra.store.entry import SegmentEntry
from vertebra.core.errors import CatalogueError
from test_catalogue import make_entry

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """A catalogue of real designed entries (rod, tube, bellows, pneumatic) and a scene using it."""
    d = tmp_path_factory.mktemp("valid")
    path = corruption.build_catalogue(d)
    ref = corruption.reference(path, d)
    return path, ref


@pytest.fixture
def copy(valid, tmp_path):
    path, ref = valid
    target = tmp_path / "cat.h5"
    shutil.copy(path, target)
    scene = tmp_path / "scene.toml"
    scene.write_text(corruption.SCENE.format(catalogue=target.name))
    return target, scene, ref


def _key(path, name):
    with catalogue.open_catalogue(path) as cat:
        return cat.resolve(name)


def _commands(path, scene, name="fuzz-pneumatic"):
    """(outcome, stderr) of verify, ls, show, simulate through the CLI."""
    out = {}
    for label, argv in (("verify", ["catalogue", "verify", str(path)]), ("ls", ["catalogue", "ls", str(path)]),
                        ("show", ["catalogue", "show", str(path), name]), ("simulate", ["simulate", str(scene)])):
        outcome, code, stdout, err = corruption._cli(argv)
        out[label] = (outcome, stdout + err if label == "verify" else err)
    return out


def _assert_refused(results, *commands, match):
    for command in commands:
        outcome, err = results[command]
        assert outcome == "refused", (command, outcome, err)
        lines = [line for line in err.splitlines() if "error:" in line or command == "verify"]
        assert any(match in line for line in lines), (command, err)
        if command != "verify":
            assert len(lines) == 1, (command, err)


# ---------------------------------------------------------------- seeded corruption fuzz

def test_seeded_corruption_fuzz(tmp_path):
    """100 seeded corruptions (bit flips, zeroed blocks, truncations, random bytes) through verify,
    ls, show and simulate: no traceback, no hang, no command accepting data that differ from
    what was stored. The deadline (30 s per case, all four commands) only detects hangs."""
    results, counts = corruption.fuzz(tmp_path, range(100), deadline_s=30.0)
    bad = [r for r in results if r.get("hang") or r.get("detail") or "harness_error" in r]
    assert bad == [], bad[:3]
    for command in ("verify", "ls", "show", "simulate"):
        assert set(counts[command]) <= {"ok", "refused", "exit-1"}, counts
    # the corruptions are not harmless: most files are refused by verify
    assert counts["verify"].get("refused", 0) >= 40, counts


# ---------------------------------------------------------------- crafted files

def test_index_as_external_link_to_etc_passwd(copy):
    path, scene, _ = copy
    with h5py.File(path, "r+") as f:
        del f["index"]
        f["index"] = h5py.ExternalLink("/etc/passwd", "/")
    results = _commands(path, scene)
    _assert_refused(results, "verify", "ls", "show", "simulate", match="/index: external link refused")


def test_soft_link_loop(copy):
    path, scene, _ = copy
    with h5py.File(path, "r+") as f:
        f["entries"]["loop-a"] = h5py.SoftLink("/entries/loop-b")
        f["entries"]["loop-b"] = h5py.SoftLink("/entries/loop-a")
        f["loop"] = h5py.SoftLink("/loop")
    results = _commands(path, scene)
    outcome, _ = results["verify"]
    assert outcome == "refused"
    problems = catalogue.verify(path)
    assert any("/loop: soft link refused" in p for p in problems)
    assert any("/entries/loop-a: soft link refused" in p for p in problems)
    # entries stored as hard links are still readable through ls/show/simulate
    assert [results[c][0] for c in ("ls", "show", "simulate")] == ["ok", "ok", "ok"]


def test_entry_group_that_is_an_external_link(copy, tmp_path):
    path, scene, _ = copy
    key = _key(path, "fuzz-pneumatic")
    other = tmp_path / "other.h5"
    shutil.copy(path, other)
    with h5py.File(path, "r+") as f:
        del f["entries"][key]
        f["entries"][key] = h5py.ExternalLink(str(other), f"/entries/{key}")
    results = _commands(path, scene)
    _assert_refused(results, "verify", "show", "simulate", match=f"/entries/{key}: external link refused")
    assert results["ls"][0] == "ok"            # listing reads the index only


def test_hard_link_cycle_and_virtual_and_external_storage_datasets(copy, tmp_path):
    path, _, _ = copy
    key = _key(path, "fuzz-rod")
    raw = tmp_path / "raw.bin"
    raw.write_bytes(np.arange(36, dtype="<f8").tobytes())
    with h5py.File(path, "r+") as f:
        g = f["entries"][key]
        g["cycle"] = g                                          # a group containing itself
        layout = h5py.VirtualLayout(shape=(3,), dtype="f8")
        layout[:] = h5py.VirtualSource(str(tmp_path / "x.h5"), "d", shape=(3,))
        f.create_virtual_dataset("virtual", layout)
        f.create_dataset("external", shape=(36,), dtype="<f8", external=[(str(raw), 0, 36 * 8)])
    problems = catalogue.verify(path)
    assert any("/virtual: virtual dataset" in p for p in problems), problems
    assert any("/external: dataset with external raw storage" in p for p in problems), problems
    assert not any(key in p for p in problems), problems       # the walk ends; a cycle is no problem
    with catalogue.open_catalogue(path) as cat:
        cat.load(key)


def test_index_row_invalid_on_its_own(copy):
    """Two rows that only parse when joined ('[' + row0 + ',' + row1 + ']' is valid JSON with two
    elements): each row must be valid on its own."""
    path, scene, _ = copy
    with h5py.File(path, "r+") as f:
        rows = [r.decode() for r in f["index"][()]]
        a, b = json.loads(rows[0]), json.loads(rows[1])
        text_a = json.dumps(a)[:-1] + ', "pad": [1'
        text_b = '2]}, ' + json.dumps(b)
        f["index"][0] = text_a
        f["index"][1] = text_b
        json.loads("[" + ",".join([text_a, text_b]) + "]")     # the trap: joined, it parses
    results = _commands(path, scene)
    _assert_refused(results, "verify", "ls", "show", "simulate", match="index row 0: invalid JSON")


def _forge(path, key, *, compliance_factor=None, mass=None):
    """Rewrite an entry in place with a VALID checksum (a deliberate forger, or a buggy writer)."""
    with h5py.File(path, "r+") as f:
        g = f["entries"][key]
        arrays = {k: g[k][()] for k in schema.ARRAY_FIELDS}
        if compliance_factor is not None:
            arrays["compliance"] = arrays["compliance"] * compliance_factor
            g["compliance"][...] = arrays["compliance"]
        m = float(g.attrs["mass"]) if mass is None else mass
        g.attrs["mass"] = np.float64(m)
        dicts = {k: json.loads(g.attrs[k].decode()) for k in schema.DICT_FIELDS}
        name, family = g.attrs["name"].decode(), g.attrs["family"].decode()
        checksum, content = schema.digests(key, name, family, m, arrays, dicts)
        g.attrs["checksum"] = schema._fixed_string(checksum)
        g.attrs["content"] = schema._fixed_string(content)
        rows = [json.loads(r) for r in f["index"][()]]
        for i, row in enumerate(rows):
            if row["key"] == key:
                row.update(checksum=checksum, content=content, mass=m)
                f["index"][i] = json.dumps(row, sort_keys=True, separators=(",", ":"))


def test_compliance_times_1e290_with_a_valid_checksum(copy):
    path, scene, _ = copy
    key = _key(path, "fuzz-pneumatic")
    _forge(path, key, compliance_factor=1e290)
    results = _commands(path, scene)
    _assert_refused(results, "verify", "show", "simulate", match="not physically sound")
    from vertebra import solver
    with pytest.raises(CatalogueError, match="not physically sound"):
        solver.build_model(solver.load_scene(scene))            # build_model refuses what verify refuses


@pytest.mark.parametrize("factor, what", [(1e-6, "below"), (1e4, "above")])
def test_compliance_off_by_large_factors_is_refused(copy, factor, what):
    """Within the generic magnitude range but far outside the family's bounds."""
    path, _, _ = copy
    key = _key(path, "fuzz-rod")
    _forge(path, key, compliance_factor=factor)
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "not physically sound" in problems[0] and what in problems[0], problems


def test_nan_mass(copy):
    path, scene, _ = copy
    key = _key(path, "fuzz-pneumatic")
    with h5py.File(path, "r+") as f:
        f["entries"][key].attrs["mass"] = np.float64("nan")
    results = _commands(path, scene)
    _assert_refused(results, "verify", "show", "simulate", match="attribute 'mass' is nan, not a finite number")


def test_mass_of_another_density_with_a_valid_checksum(copy):
    path, _, _ = copy
    key = _key(path, "fuzz-rod")
    with catalogue.open_catalogue(path) as cat:
        mass = cat.load(key).mass
    _forge(path, key, mass=10 * mass)
    problems = catalogue.verify(path)
    assert len(problems) == 1 and "mass" in problems[0] and "density × solid volume" in problems[0], problems


def test_huge_variable_length_attribute_is_refused_unread(copy):
    """A 32 MB variable-length string attribute: refused from its datatype, before any byte of it
    is read (HDF5 only learns a variable-length size by reading it)."""
    path, scene, _ = copy
    key = _key(path, "fuzz-pneumatic")
    with h5py.File(path, "r+") as f:
        f["entries"][key].attrs["provenance"] = "x" * (32 << 20)      # h5py writes str as vlen
    results = _commands(path, scene)
    _assert_refused(results, "verify", "show", "simulate",
                    match=f"/entries/{key}: attribute 'provenance' is variable-length")


def test_oversized_fixed_length_attribute_is_refused(copy):
    path, _, _ = copy
    key = _key(path, "fuzz-rod")
    with h5py.File(path, "r+") as f:
        f["entries"][key].attrs["mesh"] = np.bytes_(b" " * (2 << 20))
    problems = catalogue.verify(path)
    assert any(f"/entries/{key}: attribute 'mesh' is {2 << 20} bytes > limit" in p for p in problems), problems


def test_index_row_longer_than_the_limit_is_refused_before_it_is_read(copy):
    path, scene, _ = copy
    with h5py.File(path, "r+") as f:
        f["index"][0] = "x" * (schema.MAX_JSON_BYTES + 1)
    results = _commands(path, scene)
    _assert_refused(results, "verify", "ls", match=f"/index row 0: {schema.MAX_JSON_BYTES + 1} bytes > limit")


def test_adding_an_unsound_entry_is_refused(tmp_path):
    good = make_entry(1)
    params = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
    with pytest.raises(CatalogueError, match=r"not physically sound: .*compliance zz"):
        SegmentEntry(key="k", name="r", family="rod", parameters=params, compliance=np.eye(6),
                     cavity_volumes=[], mass=0.0, center_of_mass=[0, 0, 0.02], rest_translation=[0, 0, 0.04])
    assert good.family == "rod"          # incomplete rod parameters: generic checks only (it was built)


# ---------------------------------------------------------------- disk faults

def _mount_tmpfs(directory: Path, size: str) -> None:
    directory.mkdir(exist_ok=True)
    run = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(directory)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({run.stderr.strip() or 'mount failed'}): needs root")


def _umount(directory: Path) -> None:
    subprocess.run(["umount", "-l", str(directory)], capture_output=True)


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB tmpfs (ENOSPC after a few entries); skipped where mounting is not allowed."""
    d = tmp_path / "small"
    _mount_tmpfs(d, "2m")
    yield d
    _umount(d)


def _fill(directory: Path, leave: int) -> Path:
    """Fill a filesystem until ``leave`` bytes remain."""
    st = os.statvfs(directory)
    free = st.f_bavail * st.f_frsize
    filler = directory / "filler"
    with open(filler, "wb") as fh:
        fh.write(b"\0" * max(0, free - leave))
    return filler


def test_full_disk_keeps_every_committed_entry(small_disk):
    """Adding entries until the 2 MB disk is full: every add either raises CatalogueError (nothing
    stored) or returns a key (stored; merge maybe deferred); every returned key is readable;
    no temporary file is left behind."""
    path = small_disk / "cat.h5"
    (small_disk / "pad").write_bytes(b"\0" * (768 << 10))      # freed at the end
    stored, refused, deferred = [], 0, 0
    for i in range(400):
        try:
            key = catalogue.add_entry(path, make_entry(i, n_cavities=1))
        except CatalogueError as error:
            assert "No space left on device" in str(error) and "\n" not in str(error), error
            refused += 1
            if refused > 5:
                break
            continue
        stored.append(key)
        deferred += key.merge_deferred is not None
    assert refused > 0 and len(stored) > 10
    with catalogue.open_catalogue(path) as cat:
        assert set(stored) <= set(cat.keys())
        for key in stored[-5:]:
            cat.load(key)
    assert [p.name for p in small_disk.rglob("*.tmp")] == []
    assert deferred > 0
    (small_disk / "pad").unlink()             # free space again: the next merge picks every shard up
    catalogue.consolidate(path)
    with catalogue.open_catalogue(path) as cat:
        assert set(stored) <= set(cat.keys()) and cat.pending == []
    assert catalogue.verify(path) == []


def test_merge_deferred_when_the_shard_fits_but_the_merge_does_not(small_disk):
    path = small_disk / "cat.h5"
    catalogue.add_entries(path, [make_entry(i) for i in range(40)])
    size = path.stat().st_size
    _fill(small_disk, leave=size // 2)        # room for a shard, not for a new catalogue file
    key = catalogue.add_entry(path, make_entry(100))
    assert key.status == "stored, merge deferred" and "No space left on device" in key.merge_deferred
    with catalogue.open_catalogue(path) as cat:
        assert key in cat.pending and len(cat) == 41
        cat.load(key)
    assert [p.name for p in small_disk.rglob("*.tmp")] == []
    (small_disk / "filler").unlink()
    report = catalogue.consolidate(path)
    assert report.added == [key]
    with catalogue.open_catalogue(path) as cat:
        assert cat.pending == [] and len(cat) == 41


def test_full_disk_through_the_cli_is_one_line_exit_2(small_disk, capsys):
    from vertebra.cli.main import main

    path = small_disk / "cat.h5"
    catalogue.add_entries(path, [make_entry(i) for i in range(20)])
    _fill(small_disk, leave=4096)
    for argv in (["catalogue", "export", str(path), make_entry(3).key, "--format", "npz", "--out", str(small_disk)],
                 ["catalogue", "rm", str(path), make_entry(3).key]):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "No space left on device" in err, (argv, err)
    assert [p.name for p in small_disk.rglob("*.tmp")] == []
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 20


@pytest.fixture
def read_only(tmp_path):
    """A tmpfs holding a catalogue with a pending shard, remounted read-only."""
    d = tmp_path / "ro"
    _mount_tmpfs(d, "8m")
    path = d / "cat.h5"
    catalogue.add_entries(path, [make_entry(i) for i in range(5)])
    catalogue.add_entry(path, make_entry(9), consolidate=False)
    run = subprocess.run(["mount", "-o", "remount,ro", str(d)], capture_output=True, text=True)
    if run.returncode != 0:
        _umount(d)
        pytest.skip(f"cannot remount read-only here ({run.stderr.strip()})")
    yield path
    _umount(d)


def test_read_only_filesystem(read_only, tmp_path, capsys):
    from vertebra.cli.main import main

    path = read_only
    key = make_entry(2).key
    with catalogue.open_catalogue(path) as cat:                   # reading works
        assert len(cat) == 6
    assert catalogue.verify(path) == []
    for argv in (["catalogue", "consolidate", str(path)], ["catalogue", "rm", str(path), key],
                 ["catalogue", "merge", str(path), str(path)],
                 ["catalogue", "export", str(path), key, "--out", str(path.parent / "x.json")]):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "Read-only file system" in err, (argv, err)
    with pytest.raises(CatalogueError, match="Read-only file system"):
        catalogue.add_entry(path, make_entry(50))
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 6


def test_design_into_a_read_only_catalogue_is_exit_2(read_only, capsys):
    from vertebra.cli.main import main

    code = main(["design", "rod", "--set", "radius=0.01", "--set", "length=0.04", "--set", "youngs_modulus=1e6",
                 "--set", "poisson_ratio=0.3", "--mesh-size", "0.01", "--order", "1", "--no-accuracy",
                 "--catalogue", str(read_only)])
    err = capsys.readouterr().err       # refused before meshing (the CLI checks its output files first)
    assert code == 2 and err.count("\n") == 1 and "not writable" in err and "Traceback" not in err


def _as_nobody(fn):
    """Run ``fn`` in a forked child with the uid of 'nobody' (permissions apply; root ignores
    them). Returns the child's exit status (fn returns an int)."""
    pid = os.fork()
    if pid == 0:
        code = 99
        try:
            os.setgid(65534)
            os.setuid(65534)
            code = fn()
        except BaseException:                 # noqa: BLE001 — reported through the exit status
            import traceback
            traceback.print_exc()
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


@pytest.fixture
def world_readable_dir():
    """A directory every user can search and read but only root can write (pytest's own
    temporary tree is private to root)."""
    import tempfile
    d = Path(tempfile.mkdtemp(prefix="vertebra-perm-", dir="/tmp"))
    os.chmod(d, 0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


def test_permission_denied(world_readable_dir):
    if os.geteuid() != 0:
        pytest.skip("needs root to switch to an unprivileged user (permissions do not bind root)")
    path = world_readable_dir / "cat.h5"
    catalogue.add_entries(path, [make_entry(i) for i in range(3)])

    def attempt():
        from vertebra.cli.main import main
        import contextlib
        import io
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            codes = [main(["catalogue", "consolidate", str(path)]),
                     main(["catalogue", "rm", str(path), make_entry(1).key])]
            try:
                catalogue.add_entry(path, make_entry(7))
                codes.append(0)
            except CatalogueError as error:
                codes.append(2 if "Permission denied" in str(error) else 3)
        text = err.getvalue()
        ok = codes == [2, 2, 2] and text.count("Permission denied") == 2 and "Traceback" not in text
        return 0 if ok else 1

    assert _as_nobody(attempt) == 0
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 3


def test_directories_where_files_are_expected(tmp_path, capsys):
    from vertebra.cli.main import main

    path = tmp_path / "cat.h5"
    catalogue.add_entries(path, [make_entry(i) for i in range(2)])
    key = make_entry(1).key
    out_dir = tmp_path / "exports"
    out_dir.mkdir()
    assert main(["catalogue", "export", str(path), key, "--format", "json", "--out", str(out_dir)]) == 0
    assert json.loads((out_dir / f"{key}.json").read_text())["key"] == key
    capsys.readouterr()
    as_dir = tmp_path / "dir.h5"
    as_dir.mkdir()
    for argv in (["catalogue", "ls", str(as_dir)], ["catalogue", "verify", str(as_dir)]):
        assert main(argv) == 2 and "not a regular file" in capsys.readouterr().err
    with pytest.raises(CatalogueError, match="not a regular file"):
        catalogue.add_entry(as_dir, make_entry(0))
    blocked = tmp_path / "blocked.h5"
    shards.shards_dir(blocked).write_text("a file where the shards directory goes")
    with pytest.raises(CatalogueError, match="exists but is not a directory"):
        catalogue.add_entry(blocked, make_entry(0))
    locked = tmp_path / "locked.h5"
    shards.lock_path(locked).mkdir(parents=True)
    key = catalogue.add_entry(locked, make_entry(0))            # stored; the merge cannot lock
    assert key.status == "stored, merge deferred" and "lock file" in key.merge_deferred


# ---------------------------------------------------------------- lock waits

def test_lock_wait_is_reported_and_gives_up_with_a_clear_error(tmp_path, caplog, monkeypatch):
    """A stale soft lock file: the wait is reported (logging) and ends in LockTimeout naming the
    lock and what to do; add_entry stores its entry and reports the deferred merge."""
    monkeypatch.setenv("VERTEBRA_CATALOGUE_LOCK", "soft")
    monkeypatch.setattr(shards, "LOCK_FIRST_REPORT_S", 0.1)
    monkeypatch.setattr(shards, "LOCK_REPORT_EVERY_S", 0.2)
    path = tmp_path / "cat.h5"
    catalogue.add_entry(path, make_entry(0))
    shards.lock_path(path).parent.mkdir()
    shards.lock_path(path).write_text("4242\nsomehost\n")        # left by a crashed merger
    with pytest.raises(shards.LockTimeout, match=r"cat\.h5\.shards/\.lock: catalogue lock not obtained within 1 s "
                                                 r"\(soft lock file created \d+ s ago by pid 4242.*stale: delete it"):
        catalogue.consolidate(path, timeout=1.0)
    assert "waiting" in caplog.text and "cat.h5.shards/.lock" in caplog.text
    key = catalogue.add_entry(path, make_entry(1), timeout=0.5)
    assert key.status == "stored, merge deferred" and "not obtained" in key.merge_deferred
    shards.lock_path(path).unlink()
    catalogue.consolidate(path)
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 2 and cat.pending == []


def test_a_catalogue_in_a_missing_directory_is_refused_at_once(tmp_path):
    """Its lock's directory cannot be made where the catalogue's own is missing: consolidating (or
    any writer) says so instead of retrying the directory for ever (the command-line fuzz found a
    busy loop). A subprocess, so that a regression fails by its timeout instead of hanging the run."""
    missing = tmp_path / "no" / "x.h5"
    done = subprocess.run([sys.executable, "-m", "vertebra.cli.main", "catalogue", "consolidate", str(missing)],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path,
                          env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert done.returncode == 2, done.stderr
    assert f"its directory {missing.parent} does not exist" in done.stderr
    assert "Traceback" not in done.stderr
    with pytest.raises(CatalogueError, match="does not exist"):
        with shards.catalogue_lock(missing):
            pass
