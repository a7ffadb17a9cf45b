"""Wall and CPU time of the documented FTDCR v4 calibration (docs/calibration.md), the exact
command, optionally interleaved with another tree of vertebra (a baseline) run by the same
interpreter:

    python -m benchmarks.bench_calibration [--rounds 2] [--baseline ROOT] [--workers N]

``ROOT`` is a directory holding a ``vertebra`` package (e.g. a worktree of an older commit linked
as ``ROOT/vertebra``). Each round runs the baseline (when given), then this tree: on a shared
machine their ratio, round by round, is what the load distorts least. CPU time is user + system
of the command and its worker processes. Writes benchmarks/results/calibration_v4.json.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import vertebra
from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json

EXAMPLE = ROOT / "examples" / "calibration" / "ftdcr_v4"
STEM = "tdcr_sysid_20260511-183002"


def command(extra=(), example=EXAMPLE) -> list[str]:
    return [sys.executable, "-m", "vertebra.cli.main", "calibrate", str(example / "scene.toml"),
            "--data", str(example / f"{STEM}_train.csv"), "--holdout", str(example / f"{STEM}_val.csv"),
            "--map", str(example / "map.toml"), "--json", *extra]


def run(root: str, extra=()) -> dict:
    """One run of the command with ``root`` first on the path (on that tree's own copy of the
    example, when it has one: a mapping file may name fields an older tree does not know): wall
    and CPU seconds, the held-out RMSE and the optimiser's counts."""
    env = dict(os.environ, PYTHONPATH=root, MPLBACKEND="Agg")
    own = Path(root) / "vertebra" / "examples" / "calibration" / "ftdcr_v4"
    example = own if (own / "map.toml").exists() else EXAMPLE
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = loadavg()
    start = time.perf_counter()
    done = subprocess.run(command(extra, example), env=env, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    document = json.loads(done.stdout)
    optimiser = document["optimiser"]
    return {"wall_s": wall, "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "loadavg_before": load, "holdout_rmse_m": document["holdout"]["rmse_m"],
            "holdout_rmse_pct_length": document["holdout"]["rmse_pct_length"],
            "train_rmse_m": document["train"]["rmse_m"], "evaluations": optimiser["evaluations"],
            "jacobians": optimiser["jacobians"], "workers": optimiser.get("workers", 1),
            "values": {p["name"]: p["value"] for p in document["parameters"]},
            "standard_errors": {p["name"]: p["standard_error"] for p in document["parameters"]},
            "unidentifiable": document.get("unidentifiable", []),
            "offset_removed_holdout_rmse_m": document["holdout"]["offset_removed"]["rmse_m"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--baseline", metavar="ROOT", help="a directory holding an older vertebra package")
    parser.add_argument("--workers", type=int, help="pass --workers N to this tree's runs")
    args = parser.parse_args(argv)
    this = os.path.dirname(os.path.dirname(os.path.abspath(vertebra.__file__)))   # the directory holding it
    extra = ("--workers", str(args.workers)) if args.workers else ()
    rounds = []
    for k in range(args.rounds):
        entry = {}
        if args.baseline:
            log(f"round {k + 1}: baseline …")
            entry["baseline"] = run(args.baseline)
            log(f"  {entry['baseline']['wall_s']:.1f} s wall, {entry['baseline']['cpu_s']:.1f} s CPU")
        log(f"round {k + 1}: this tree …")
        entry["this"] = run(this, extra)
        log(f"  {entry['this']['wall_s']:.1f} s wall, {entry['this']['cpu_s']:.1f} s CPU")
        if args.baseline:
            entry["wall_ratio"] = entry["this"]["wall_s"] / entry["baseline"]["wall_s"]
            entry["cpu_ratio"] = entry["this"]["cpu_s"] / entry["baseline"]["cpu_s"]
        rounds.append(entry)
        document = {"vertebra_version": vertebra.__version__, "date": now(), "loadavg": loadavg(),
                    "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
                    "command": " ".join(command(extra)[1:]), "baseline": args.baseline, "rounds": rounds}
        write_json(document, RESULTS / "calibration_v4.json")           # (after every round: runs are long)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
