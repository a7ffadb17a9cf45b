"""Hostile catalogues: a large seeded corruption fuzz and the cost of refusing a huge attribute.

1. ``--cases`` seeded corruptions (default 1000: bit flips, zeroed blocks, truncations, random
   bytes, in turn) of a valid catalogue of real designed entries, each through
   ``catalogue verify``, ``ls``, ``show`` and ``simulate`` in a forked child with a 30 s deadline
   (tests/corruption.py; ``make test`` runs 100 of them). Counts outcomes per command and per
   corruption kind: ``ok``/``refused``/``exit-1`` are fine; ``traceback``, ``hang`` and
   ``unsound`` (a command accepting data other than what was stored) must be 0.
2. A 300 MB variable-length string attribute in an entry: seconds to refuse it (verify, load)
   against the seconds h5py needs to read it.

3. ``--tamper N``: N seeded tampering cases of nonlinear entries written with a recomputed
   checksum (tests/tampering.py: coefficients, convexity, scales, range, terms, the energy group
   deleted), each through ``verify`` and ``load``; ``accepted`` must be 0. Only these run then.

Results: benchmarks/results/catalogue_fuzz.json and .md (``--tamper``: catalogue_tamper.json).

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_catalogue_fuzz [--cases 1000]
"""

from __future__ import annotations

import argparse
import collections
import os
import platform
import shutil
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from benchmarks import render
from tests import corruption  # noqa: E402

COMMANDS = ("verify", "ls", "show", "simulate")
BAD = ("traceback", "hang", "unsound")


def huge_attribute(directory: Path, megabytes: int = 300) -> dict:
    import h5py

    from vertebra.store import catalogue
    from vertebra.core.errors import CatalogueError

    valid = corruption.build_catalogue(directory)
    path = directory / "huge.h5"
    shutil.copy(valid, path)
    with catalogue.open_catalogue(path) as cat:
        key = cat.resolve("fuzz-pneumatic")
    with h5py.File(path, "r+") as f:
        f["entries"][key].attrs["provenance"] = "x" * (megabytes << 20)
    out = {"megabytes": megabytes, "file_bytes": path.stat().st_size}
    t0 = time.perf_counter()
    with h5py.File(path, "r") as f:
        value = f["entries"][key].attrs["provenance"]
    out["h5py_read_s"] = time.perf_counter() - t0
    del value
    t0 = time.perf_counter()
    problems = catalogue.verify(path)
    out["verify_s"] = time.perf_counter() - t0
    out["verify_problem"] = problems[0] if problems else None
    t0 = time.perf_counter()
    try:
        with catalogue.open_catalogue(path) as cat:
            cat.load(key)
        out["load"] = "accepted"
    except CatalogueError as error:
        out["load"] = str(error)
    out["load_s"] = time.perf_counter() - t0
    return out


def tamper(cases: int, first_seed: int) -> int:
    """Seeded tampering cases (tests/tampering.py); writes results/catalogue_tamper.json."""
    import json

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import tampering

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        results = tampering.run(Path(d), range(first_seed, first_seed + cases))
    by_kind = collections.defaultdict(lambda: {"cases": 0, "accepted": 0})
    for r in results:
        by_kind[r["kind"]]["cases"] += 1
        by_kind[r["kind"]]["accepted"] += "accepted" in (r["verify"], r["load"])
    accepted = [r for r in results if "accepted" in (r["verify"], r["load"])]
    out = {"date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(), "host": platform.node(),
           "cases": cases, "seeds": [first_seed, first_seed + cases - 1], "run_s": time.perf_counter() - start,
           "accepted": len(accepted), "by_kind": dict(by_kind), "accepted_cases": accepted}
    path = Path(__file__).resolve().parent / "results" / "catalogue_tamper.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    for kind, row in sorted(by_kind.items()):
        print(f"{kind:24} {row['cases']:5d} cases  {row['accepted']} accepted")
    print(f"{cases} tampering cases in {out['run_s']:.1f} s: {len(accepted)} accepted")
    return 1 if accepted else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=1000)
    parser.add_argument("--first-seed", type=int, default=1000, help="(make test uses seeds 0-99)")
    parser.add_argument("--tamper", type=int, default=0, metavar="N",
                        help="run N tampering cases of nonlinear entries instead (tests/tampering.py)")
    args = parser.parse_args(argv)
    if args.tamper:
        return tamper(args.tamper, args.first_seed)
    result = {"date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(), "host": platform.node(),
              "python": platform.python_version(), "loadavg_start": os.getloadavg(), "deadline_s": 30.0,
              "cases": args.cases, "seeds": [args.first_seed, args.first_seed + args.cases - 1]}
    with tempfile.TemporaryDirectory() as d:
        start = time.perf_counter()
        results, counts = corruption.fuzz(Path(d), range(args.first_seed, args.first_seed + args.cases),
                                          deadline_s=result["deadline_s"])
        result["run_s"] = time.perf_counter() - start
        result["catalogue_bytes"] = (Path(d) / "valid.h5").stat().st_size
    result["counts"] = counts
    by_kind = collections.defaultdict(lambda: {"cases": 0, "refused": 0, "unchanged": 0})
    for r in results:
        row = by_kind[r["kind"]]
        row["cases"] += 1
        row["refused"] += r.get("verify") == "refused"
        row["unchanged"] += r.get("changed") is False
    result["by_kind"] = dict(by_kind)
    result["max_case_s"] = max(r.get("seconds", 0.0) for r in results)
    result["failures"] = [r for r in results if r.get("hang") or r.get("detail") or "harness_error" in r]
    with tempfile.TemporaryDirectory() as d:
        result["huge_attribute"] = huge_attribute(Path(d))
    result["loadavg_end"] = os.getloadavg()
    render.write("catalogue_fuzz", result)
    print(render.markdown("catalogue_fuzz", result))
    bad = sum(counts.get(c, {}).get(b, 0) for c in COMMANDS for b in BAD)
    return 1 if bad or result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
