"""Concurrent writers, SIGKILLed writers and simultaneous adds (issue 5, DESIGN.md §6).

Writers are separate processes (forked: no re-import cost, and a SIGKILL hits a real
process holding real file locks). Nothing here is timed; the durations only bound
how long the tests run.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import time

import pytest

from vertebra.store import catalogue, locking, shards
from vertebra.core.errors import CatalogueError
from test_catalogue import assert_same_entry, make_entry

CTX = multiprocessing.get_context("fork")


def _writer(path, seed, indices, log_path=None, barrier=None, pause=0.0):
    """Add entries; after each add_entry returns, record the key durably in ``log_path``."""
    if barrier is not None:
        barrier.wait(timeout=60)
    log = open(log_path, "a") if log_path else None
    for i in indices:
        key = catalogue.add_entry(path, make_entry(i, n_cavities=i % 3, seed=seed))
        if log:
            log.write(key + "\n")
            log.flush()
            os.fsync(log.fileno())
        if pause:
            time.sleep(pause)
    os._exit(0)


def _beside(path):
    """What the store left in the catalogue's directory (everything it makes is named after it)."""
    return sorted(p.name for p in path.parent.iterdir() if path.name in p.name)


def _run_all(procs, timeout=120):
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout)
    codes = [p.exitcode for p in procs]
    for p in procs:
        if p.is_alive():
            p.kill()
    return codes


def test_eight_processes_times_25_entries(tmp_path):
    path = tmp_path / "cat.h5"
    procs = [CTX.Process(target=_writer, args=(path, seed, range(25))) for seed in range(8)]
    assert _run_all(procs) == [0] * 8
    assert shards.list_shards(path) == []           # every writer left after its shard was merged
    assert _beside(path) == ["cat.h5"]               # no lock file, no empty shards directory
    with catalogue.open_catalogue(path) as cat:
        assert len(cat) == 200 and cat.pending == []
        for seed in (0, 7):                          # spot-check content, verify checks all
            for i in (0, 24):
                assert_same_entry(make_entry(i, n_cavities=i % 3, seed=seed), cat.load(make_entry(i, seed=seed).key))
    assert catalogue.verify(path) == []


def test_sigkilled_writers_lose_only_their_unfinished_entry(tmp_path):
    """10 trials: 3 writers killed with SIGKILL at random moments. Afterwards the catalogue
    opens without repair, every entry whose add_entry returned is there and verifies, and
    the next writer works normally."""
    rng = random.Random(1234)
    path = tmp_path / "cat.h5"
    committed: set[str] = set()
    for trial in range(10):
        logs = [tmp_path / f"log-{trial}-{w}" for w in range(3)]
        procs = [CTX.Process(target=_writer, args=(path, 100 * trial + w, range(1000), logs[w]))
                 for w in range(3)]
        for p in procs:
            p.start()
        for p, log in zip(procs, logs):
            if trial % 2:                            # odd trials: after the writer's first commit
                deadline = time.monotonic() + 30     # (a loaded machine may take long to get there)
                while not (log.exists() and log.stat().st_size) and time.monotonic() < deadline:
                    time.sleep(0.005)
            time.sleep(rng.uniform(0.02, 0.25))
            p.kill()
        for p in procs:
            p.join(30)                               # reap: a zombie would look alive
            assert p.exitcode == -9
        for log in logs:
            if log.exists():
                committed |= {line for line in log.read_text().split("\n") if len(line) == 20}
        with catalogue.open_catalogue(path) as cat:  # no repair tool, no h5clear
            missing = committed - set(cat.keys())
            assert not missing, f"trial {trial}: committed entries lost: {sorted(missing)[:5]}"
        assert catalogue.verify(path) == [], f"trial {trial}"
    assert len(committed) >= 10, "the writers were killed before committing anything; test too weak"
    extra = make_entry(0, seed=9999)
    catalogue.add_entry(path, extra)                 # merges leftovers, cleans stale temp files
    with catalogue.open_catalogue(path) as cat:
        assert cat.pending == [] and committed | {extra.key} <= set(cat.keys())
        assert_same_entry(extra, cat.load(extra.key))
    leftovers = [p.name for d in (tmp_path, shards.shards_dir(path)) if d.is_dir() for p in d.iterdir() if p.suffix == ".tmp"]
    assert leftovers == []
    assert catalogue.verify(path) == []
    assert _beside(path) == ["cat.h5"]               # a killed merger's lock file went with the next merge


def test_four_processes_adding_at_the_same_moment_all_succeed(tmp_path):
    path = tmp_path / "cat.h5"                       # does not exist yet: they also race to create it
    barrier = CTX.Barrier(4)
    procs = [CTX.Process(target=_writer, args=(path, seed, [seed], None, barrier)) for seed in range(4)]
    assert _run_all(procs) == [0] * 4
    with catalogue.open_catalogue(path) as cat:
        assert sorted(cat.keys()) == sorted(make_entry(s, seed=s).key for s in range(4))
        assert cat.pending == []
    assert catalogue.verify(path) == []


def _same_key_writer(path, barrier, mass, result_path):
    barrier.wait(timeout=60)
    try:
        catalogue.add_entry(path, make_entry(0, mass=mass))
        result_path.write_text("ok")
    except CatalogueError as error:
        result_path.write_text(f"conflict: {error}")
    os._exit(0)


@pytest.mark.parametrize("masses, n_ok", [((1.0, 1.0, 1.0, 1.0), 4), ((1.0, 2.0, 3.0, 4.0), 1)])
def test_simultaneous_adds_of_one_key(tmp_path, masses, n_ok):
    """Same key at the same moment: identical content → all succeed, one entry; different
    content → exactly one wins, the others get CatalogueError, nothing is overwritten."""
    path = tmp_path / "cat.h5"
    barrier = CTX.Barrier(4)
    results = [tmp_path / f"r{i}" for i in range(4)]
    procs = [CTX.Process(target=_same_key_writer, args=(path, barrier, m, r)) for m, r in zip(masses, results)]
    assert _run_all(procs) == [0] * 4
    outcomes = [r.read_text() for r in results]
    assert sum(o == "ok" for o in outcomes) == n_ok, outcomes
    with catalogue.open_catalogue(path) as cat:
        assert cat.keys() == [make_entry(0).key]
        winner = cat.load(make_entry(0).key).mass
    assert outcomes[masses.index(winner)] == "ok"
    assert catalogue.verify(path) == []              # no stale conflict shards left behind
    assert _beside(path) == ["cat.h5"]


# ---------------------------------------------------------------- the merger lock itself

def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a killed, not yet reaped child is a zombie: dead)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (FileNotFoundError, IndexError):
        return False


def _hammer(path, probe, rounds, seed, report):
    """Take the merger lock ``rounds`` times; inside it, claim ``probe/holder`` (a hard link:
    atomic, with this pid inside). Finding the claim of a live process is two holders at once."""
    rng = random.Random(seed)
    mine = probe / f"pid-{os.getpid()}"
    mine.write_text(str(os.getpid()))
    holder = probe / "holder"
    overlaps = 0
    for _ in range(rounds):
        with shards.catalogue_lock(path, timeout=60):
            try:
                os.link(mine, holder)
            except FileExistsError:
                other = int(holder.read_text() or 0)
                overlaps += _alive(other)           # a dead one was killed inside: fine
                os.unlink(holder)
                os.link(mine, holder)
            time.sleep(rng.uniform(0.0, 0.002))
            os.unlink(holder)
    report.write_text(str(overlaps))
    os._exit(0)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads process states from /proc")
def test_merger_lock_excludes_under_churn_and_kills_and_leaves_nothing(tmp_path):
    """12 processes take and release the lock (the lock file unlinked at every release) 150 times
    each while 4 of them are SIGKILLed at random moments, inside the lock or waiting on it: never
    two holders, the survivors finish, and afterwards nothing is left beside the catalogue."""
    path = tmp_path / "cat.h5"
    probe = tmp_path / "probe"
    probe.mkdir()
    rng = random.Random(7)
    reports = [tmp_path / f"probe-report-{i}" for i in range(12)]
    procs = [CTX.Process(target=_hammer, args=(path, probe, 150, i, reports[i])) for i in range(12)]
    for p in procs:
        p.start()
    for victim in rng.sample(procs, 4):
        time.sleep(rng.uniform(0.05, 0.4))
        victim.kill()
    for p in procs:
        p.join(120)
    codes = [p.exitcode for p in procs]
    assert all(c in (0, -9) for c in codes) and codes.count(0) >= 8, codes
    finished = [int(r.read_text()) for r in reports if r.exists()]
    assert len(finished) >= 8 and sum(finished) == 0, f"two holders at once {sum(finished)} times"
    if not any(c == -9 for c in codes):
        pytest.fail("no process was killed: the victims finished first; test too weak")
    assert not shards.shards_dir(path).exists() or list(shards.shards_dir(path).iterdir()) == [shards.LOCK_NAME]
    with shards.catalogue_lock(path, timeout=5):      # a killed holder's file is reused, then removed
        assert shards.lock_path(path).exists()
    assert not shards.shards_dir(path).exists() and not shards.lock_path(path).exists()


def test_a_waiter_on_the_unlinked_lock_file_starts_again():
    """The race that unlink-on-release opens, step by step: B opened the lock file while A held
    it; A releases (unlinks); newcomer C creates and locks a new file; B's flock on the old inode
    now succeeds — and B must see that the path names C's inode, not claim the lock."""
    import tempfile

    fcntl = pytest.importorskip("fcntl")
    with tempfile.TemporaryDirectory() as directory:
        lock_file = shards.Path(directory) / "x.lock"
        a = locking.acquire(lock_file, time.monotonic() + 1, how="flock")
        b = os.open(lock_file, os.O_RDWR)                   # a waiter, blocked in flock on A's inode
        locking.release(a)
        assert not lock_file.exists()                       # the releasing holder leaves nothing
        c = locking.acquire(lock_file, time.monotonic() + 1, how="flock")
        fcntl.flock(b, fcntl.LOCK_EX | fcntl.LOCK_NB)       # the old inode is free …
        assert not locking._same_inode(b, lock_file)        # … but no longer the lock
        os.close(b)
        assert locking.acquire(lock_file, time.monotonic() + 0.2, how="flock") is None    # C holds it
        assert "pid" in locking.holder(lock_file, "flock")
        locking.release(c)
        assert os.listdir(directory) == []


def _soft_churn(path, rounds, report):
    overlaps = 0
    marker = path.parent / "probe-soft-holder"
    for _ in range(rounds):
        with shards.catalogue_lock(path, timeout=60):
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
                os.close(fd)
            except FileExistsError:
                overlaps += 1
                continue
            time.sleep(0.0005)
            os.unlink(marker)
    report.write_text(str(overlaps))
    os._exit(0)


def test_soft_lock_excludes_and_leaves_nothing(tmp_path, monkeypatch):
    """The soft lock (the file's existence) under the same churn, without kills (a killed soft
    holder leaves its file by design: see test_catalogue_hostile)."""
    monkeypatch.setenv("VERTEBRA_CATALOGUE_LOCK", "soft")
    path = tmp_path / "cat.h5"
    reports = [tmp_path / f"probe-report-{i}" for i in range(6)]
    procs = [CTX.Process(target=_soft_churn, args=(path, 60, r)) for r in reports]
    assert _run_all(procs) == [0] * 6
    assert sum(int(r.read_text()) for r in reports) == 0
    assert not shards.shards_dir(path).exists()


def test_many_writers_with_kills_lose_nothing_and_leave_nothing(tmp_path):
    """10 writers, 5 SIGKILLed at random moments, the others adding 12 entries each; then one more
    add: every entry whose add returned is in the catalogue, which verifies, and the catalogue
    stands alone in its directory (no lock file, no shards directory, no temporary file)."""
    rng = random.Random(99)
    path = tmp_path / "cat.h5"
    logs = [tmp_path / f"log-{w}" for w in range(10)]
    procs = [CTX.Process(target=_writer, args=(path, 500 + w, range(1000 if w < 5 else 12), logs[w]))
             for w in range(10)]
    for p in procs:
        p.start()
    for p in procs[:5]:
        time.sleep(rng.uniform(0.05, 0.3))
        p.kill()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [-9] * 5 + [0] * 5
    committed = set()
    for log in logs:
        if log.exists():
            committed |= {line for line in log.read_text().split("\n") if len(line) == 20}
    assert len(committed) >= 60
    catalogue.add_entry(path, make_entry(0, seed=4242))
    with catalogue.open_catalogue(path) as cat:
        assert committed <= set(cat.keys()) and cat.pending == []
    assert catalogue.verify(path) == []
    assert _beside(path) == ["cat.h5"]


def test_the_filelock_fallback_excludes(tmp_path):
    """The mechanism for platforms without fcntl (Windows), exercised here through filelock's
    own lock for this platform: it excludes a second holder and is released. (Removing the file
    on release is filelock's business there; see docs/catalogue.md.)"""
    lock_file = tmp_path / "x.h5.shards" / ".lock"
    held = locking.acquire(lock_file, time.monotonic() + 1, tidy_dir=True, how="filelock")
    assert held is not None
    assert locking.acquire(lock_file, time.monotonic() + 0.2, tidy_dir=True, how="filelock") is None
    locking.release(held, tidy_dir=True)
    again = locking.acquire(lock_file, time.monotonic() + 1, tidy_dir=True, how="filelock")
    assert again is not None
    locking.release(again, tidy_dir=True)
