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

from vertebra.store import catalogue, shards
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
        for p in procs:
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
