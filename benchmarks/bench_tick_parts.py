"""Interleaved A/B of the inverse tick's parts, as the tick times them itself.

Each tick reports its own ``timings`` (``linearise_s``: the linearisation, ``W_s``: the projection,
``qp_s``: the two QP stages, ``step_s``: the step with its checks, ``total_s``: the whole tick).
This benchmark runs ``benchmarks.bench_tick``'s control loops (``paper_5v_16t``,
``outside_6v_16t``) in two worker processes, one per revision, alternating blocks of ``--block``
ticks (A B, then B A); every ``--rounds`` blocks both workers are replaced by new ones (their
order swapped), ``--pairs`` times. A process's speed depends on where its memory and code land
(a few % either way, the same for every part): new pairs average that out, and a part the
revisions share (e.g. the linearisation when only the QP changed) shows ≈ 1.00, the check of
the run. Reported per robot and part: each side's median over blocks of the block medians, and
the median of B/A over blocks with its quartiles.

Run: ``.venv/bin/python -m benchmarks.bench_tick_parts --roots main=/tmp/a now=/tmp/b [--rounds 20]
[--pairs 10] [--block 30] [--output benchmarks/results/tick_parts.json]`` (each root a folder
holding a ``vertebra`` package).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ROBOTS = ("paper_5v_16t", "outside_6v_16t")
PARTS = ("linearise_s", "W_s", "qp_s", "step_s", "total_s")

WORKER = r"""
import gc, json, sys
import numpy as np
sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[2])
import bench_tick
loops = {name: bench_tick.Loop(name) for name in bench_tick.ROBOTS}
parts = sys.argv[3].split(",")
print(json.dumps("ready"), flush=True)
for line in sys.stdin:
    name, count = json.loads(line)
    loop = loops[name]
    loop.run = []
    loop.ticks(count)
    print(json.dumps({k: float(np.median([s.timings.get(k, np.nan) for _, s in loop.run])) for k in parts}),
          flush=True)
"""


def _workers(roots: dict) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    workers = {}
    for label, root in roots.items():
        workers[label] = subprocess.Popen([sys.executable, "-c", WORKER, str(root), str(REPO / "benchmarks"),
                                           ",".join(PARTS)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          text=True, env=env, cwd="/tmp")
    for worker in workers.values():
        if json.loads(worker.stdout.readline()) != "ready":
            raise RuntimeError("a benchmark worker did not start")
    return workers


def _close(workers: dict) -> None:
    for worker in workers.values():
        worker.stdin.close()
        worker.wait()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--roots", nargs=2, required=True, help="A=DIR B=DIR, each holding a vertebra package")
    parser.add_argument("--rounds", type=int, default=20, help="blocks per robot and side per worker pair")
    parser.add_argument("--pairs", type=int, default=10, help="worker pairs, one after the other")
    parser.add_argument("--block", type=int, default=30, help="ticks per block")
    parser.add_argument("--output", default=str(REPO / "benchmarks" / "results" / "tick_parts.json"))
    args = parser.parse_args(argv)
    roots = dict(item.split("=", 1) for item in args.roots)
    labels = list(roots)
    blocks = {name: {label: [] for label in labels} for name in ROBOTS}
    load = []
    for pair in range(args.pairs):
        order = labels if pair % 2 == 0 else labels[::-1]
        workers = _workers({label: roots[label] for label in order})
        try:
            for r in range(args.rounds):
                for name in ROBOTS:
                    for label in (labels if r % 2 == 0 else labels[::-1]):
                        workers[label].stdin.write(json.dumps([name, args.block]) + "\n")
                        workers[label].stdin.flush()
                        blocks[name][label].append(json.loads(workers[label].stdout.readline()))
        finally:
            _close(workers)
        load.append(os.getloadavg()[0])
    a, b = labels
    report = {"roots": roots, "rounds": args.rounds, "pairs": args.pairs, "block": args.block,
              "load_average": [min(load), float(np.median(load)), max(load)], "robots": {}}
    print(f"tick parts, {b} against {a} (load {min(load):.1f}–{max(load):.1f})")
    for name in ROBOTS:
        print(name)
        report["robots"][name] = {}
        for part in PARTS:
            A = np.array([x[part] for x in blocks[name][a]])
            B = np.array([x[part] for x in blocks[name][b]])
            ratio = B / A
            entry = {a: float(np.median(A)), b: float(np.median(B)), "ratio": float(np.median(ratio)),
                     "quartiles": [float(np.quantile(ratio, 0.25)), float(np.quantile(ratio, 0.75))]}
            report["robots"][name][part] = entry
            print(f"  {part:12s} {a} {entry[a] * 1e6:7.1f} µs  {b} {entry[b] * 1e6:7.1f} µs  "
                  f"{entry['ratio']:.3f} ({entry['quartiles'][0]:.3f}–{entry['quartiles'][1]:.3f})")
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
