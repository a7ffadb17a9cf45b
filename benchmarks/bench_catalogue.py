"""Catalogue store: overhead per entry, opening a 10,000-entry catalogue, merging.

Measured (wall clock, one process unless stated, entries with one cavity: 7×7 compliance):

1. ``add_entry`` into a fresh catalogue, sequentially (shard + fsync + merge under the
   lock + fsync + atomic replace), and the shard-only part (``consolidate=False``).
2. ``add_entry`` of one entry into catalogues of 1,000 and 10,000 entries (the merger
   copies the file: cost grows with the file size) and ``add_entries`` of 1,000.
3. Open a 10,000-entry catalogue and load one entry by key, by name and by key prefix
   (in this process, and in a fresh process after imports); ``list()``, ``query``,
   ``has_entry``, ``verify``.
4. ``merge`` of two 5,000-entry catalogues into a new one, and re-merging (all skipped).

The machine is shared (2 cores, other engineers' jobs): the load average is recorded.
Results: benchmarks/results/catalogue.json and catalogue.md.

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_catalogue [--entries 10000]

The asv benchmarks ``speed/catalogue.py`` time the same operations on 1,000 entries per commit.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from benchmarks import render
from benchmarks.common import timed as _timed
from benchmarks.speed.catalogue import make_entry
from vertebra.store import catalogue


def timed(fn, repeat=1):
    """(last result, wall times of ``repeat`` calls), the first call timed too."""
    out, t = _timed(fn, repeat, warmup=0, samples=True)
    return out, t["times_s"]


def ms(times):
    return {"median_ms": 1e3 * statistics.median(times), "min_ms": 1e3 * min(times),
            "max_ms": 1e3 * max(times), "n": len(times)}


def build(path: Path, entries, batch: int = 1000) -> float:
    t0 = time.perf_counter()
    for start in range(0, len(entries), batch):
        catalogue.add_entries(path, entries[start:start + batch])
    return time.perf_counter() - t0


COLD = """
import sys, time
from vertebra.store import catalogue
t0 = time.perf_counter()
with catalogue.open_catalogue({path!r}) as cat:
    t1 = time.perf_counter()
    entry = cat.load({ref!r})
t2 = time.perf_counter()
print(t1 - t0, t2 - t0)
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--entries", type=int, default=10_000)
    parser.add_argument("--sequential", type=int, default=100, help="sequential add_entry calls")
    args = parser.parse_args(argv)
    n = args.entries
    rows = []
    result = {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "host": platform.node(), "python": platform.python_version(),
              "loadavg_start": os.getloadavg(), "entries": n}

    def row(name, value, note=""):
        rows.append((name, value, note))
        print(f"{name:58} {value:>14}  {note}", flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # 1. sequential add_entry into a fresh catalogue
        fresh = tmp / "fresh.h5"
        seq = [make_entry(i, seed=1) for i in range(args.sequential)]
        t_add = []
        for e in seq:
            t0 = time.perf_counter()
            catalogue.add_entry(fresh, e)
            t_add.append(time.perf_counter() - t0)
        result["add_entry_fresh"] = ms(t_add)
        row(f"add_entry, fresh catalogue (first {args.sequential})",
            f"{result['add_entry_fresh']['median_ms']:.1f} ms", "median; shard+merge+2 fsync")
        shard_only = tmp / "shards.h5"
        t_shard = []
        for e in seq[:50]:
            t0 = time.perf_counter()
            catalogue.add_entry(shard_only, e, consolidate=False)
            t_shard.append(time.perf_counter() - t0)
        result["add_entry_shard_only"] = ms(t_shard)
        row("add_entry(consolidate=False), shard only", f"{result['add_entry_shard_only']['median_ms']:.1f} ms",
            "median of 50")
        _, t_cons = timed(lambda: catalogue.consolidate(shard_only))
        result["consolidate_50_shards_s"] = t_cons[0]
        row("consolidate 50 pending shards", f"{t_cons[0] * 1e3:.0f} ms")

        # 2. build big catalogues; one add into them
        big = tmp / "big.h5"
        entries = [make_entry(i) for i in range(n)]
        t_build = build(big, entries)
        result["build_s"] = t_build
        result["file_bytes"] = big.stat().st_size
        row(f"build {n} entries (add_entries, batches of 1000)", f"{t_build:.1f} s",
            f"{big.stat().st_size / n:.0f} bytes/entry")
        for size in sorted({min(1000, n), n}):
            target = tmp / f"size{size}.h5"
            if size == n:
                target = big
            else:
                build(target, entries[:size])
            extra = [make_entry(i, seed=7000 + size) for i in range(3)]
            _, t = timed(lambda it=iter(extra): catalogue.add_entry(target, next(it)), repeat=3)
            result[f"add_entry_into_{size}"] = ms(t)
            row(f"add_entry into a {size}-entry catalogue", f"{statistics.median(t) * 1e3:.0f} ms",
                "median of 3 (file copy dominates)")
        batch = [make_entry(i, seed=8000) for i in range(1000)]
        _, t = timed(lambda: catalogue.add_entries(big, batch))
        result["add_entries_1000_into_big_s"] = t[0]
        row(f"add_entries(1000) into the {n}-entry catalogue", f"{t[0]:.2f} s",
            f"{t[0] / 1000 * 1e3:.2f} ms/entry")
        total = n + 1000 + 3

        # 3. open + load
        key, name, prefix = entries[n // 2].key, entries[n // 3].name, entries[n // 4].key[:8]

        def open_load(ref):
            with catalogue.open_catalogue(big) as cat:
                return cat.load(ref)

        for label, ref in (("key", key), ("name", name), ("key prefix", prefix)):
            _, t = timed(lambda: open_load(ref), repeat=7)
            result[f"open_and_load_by_{label.replace(' ', '_')}"] = ms(t)
            row(f"open {total}-entry catalogue + load one by {label}", f"{statistics.median(t) * 1e3:.1f} ms",
                f"median of 7, max {max(t) * 1e3:.1f} ms")
        cold = []
        for _ in range(3):
            out = subprocess.run([sys.executable, "-c", COLD.format(path=str(big), ref=name)],
                                 capture_output=True, text=True, check=True).stdout.split()
            cold.append((float(out[0]), float(out[1])))
        result["fresh_process_open_s"] = [c[0] for c in cold]
        result["fresh_process_open_and_load_s"] = [c[1] for c in cold]
        row("same in a fresh process (after imports), by name",
            f"{statistics.median(c[1] for c in cold) * 1e3:.1f} ms", "median of 3")
        with catalogue.open_catalogue(big) as cat:
            _, t = timed(cat.list, repeat=3)
        result["list"] = ms(t)
        row(f"list() of {total} entries (handle open)", f"{statistics.median(t) * 1e3:.1f} ms")
        _, t = timed(lambda: catalogue.query(big, ["outer_radius>=0.0105", "family=bellows"]), repeat=3)
        result["query"] = ms(t)
        row("query 2 conditions (open + filter)", f"{statistics.median(t) * 1e3:.1f} ms")
        _, t = timed(lambda: catalogue.has_entry(big, key), repeat=7)
        result["has_entry"] = ms(t)
        row("has_entry", f"{statistics.median(t) * 1e3:.2f} ms")
        problems, t = timed(lambda: catalogue.verify(big))
        assert problems == [], problems[:3]
        result["verify_s"] = t[0]
        row(f"verify {total} entries", f"{t[0]:.2f} s", f"{t[0] / total * 1e3:.2f} ms/entry")

        # 4. merge
        half_a, half_b = tmp / "a.h5", tmp / "b.h5"
        build(half_a, entries[: n // 2])
        build(half_b, entries[n // 2:])
        out = tmp / "merged.h5"
        report, t = timed(lambda: catalogue.merge(out, [half_a, half_b]))
        assert len(report.added) == n and not report.conflicts
        result["merge_two_halves_s"] = t[0]
        row(f"merge 2 × {n // 2} entries into a new catalogue", f"{t[0]:.2f} s",
            f"{t[0] / n * 1e3:.2f} ms/entry (checksum-checked copy)")
        report, t = timed(lambda: catalogue.merge(out, [half_a, half_b]))
        assert report.added == [] and len(report.skipped) == n
        result["remerge_all_skipped_s"] = t[0]
        row("merge the same inputs again (all skipped)", f"{t[0]:.2f} s")

    result["loadavg_end"] = os.getloadavg()
    result["rows"] = rows
    render.write("catalogue", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
