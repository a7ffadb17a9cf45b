"""Interleaved A/B of several revisions at once: which commits of a history cost the solve or the
tick time (a bisection by measurement).

Each revision is a folder holding its ``vertebra`` package (``git archive <rev>`` unpacked into
``DIR/vertebra``). One worker process per revision keeps its models and control loops; blocks of
``--n`` calls go to every worker in turn, the order reversed and rotated from round to round, so
that load bursts on a shared machine hit every revision alike. Each block's figure is the median
thread CPU time of its calls; a revision's ratio is the median over rounds of its block against
the first revision's block of the same round, with quartiles.

What is timed (``--what``, comma-separated):

* ``cantilever`` — the gallery's 20-link cantilever solved from rest;
* ``serial`` — ``paper_5v_16t`` solved from rest at random tensions (seed 11; the same 60);
* ``tick`` / ``tick_outside`` — ``benchmarks.bench_tick``'s control loop on ``paper_5v_16t`` /
  ``outside_6v_16t`` (this tree's loop, each revision's package);
* ``tick_penalty`` — the ``paper_5v_16t`` loop with the one-stage QP (``effort="penalty"``) where
  the revision has the setting (the least-effort QP's second stage left out), else its default;
* ``tick_reuse`` / ``tick_outside_reuse`` — the two loops with ``tangent_reuse=2`` (chord ticks)
  where the revision has the setting, else its default.

Run: ``.venv/bin/python -m benchmarks.bench_revisions --roots start=/tmp/a now=/tmp/b … [--rounds
60] [--n 20] [--what cantilever,tick]``; writes ``benchmarks/results/revisions.json``
(``--output``).
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
RESULTS = REPO / "benchmarks" / "results"
KINDS = ("cantilever", "serial", "tick", "tick_outside", "tick_penalty", "tick_reuse", "tick_outside_reuse")

WORKER = r"""
import dataclasses, gc, json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[2])
from vertebra import solver
import vertebra.solver.inverse as inverse
from bench_tick import Loop
what = sys.argv[1].split(",")
runs = {}
if "cantilever" in what:
    model = solver.build_model(solver.load_scene("gallery:cantilever"))
    for _ in range(30):
        model.solve()
    runs["cantilever"] = lambda k, model=model: model.solve()
if "serial" in what:
    model = solver.build_model(solver.load_scene("gallery:paper_5v_16t"))
    lower, upper = model.actuator_bounds
    commands = np.random.default_rng(11).uniform(lower, upper, (60, len(lower)))
    for a in commands[:10]:
        model.solve(a, raise_on_failure=False)
    runs["serial"] = lambda k, model=model: model.solve(commands[k % len(commands)], raise_on_failure=False)
loops = {}
if "tick" in what:
    loops["tick"] = Loop("paper_5v_16t")
if "tick_outside" in what:
    loops["tick_outside"] = Loop("outside_6v_16t")
if "tick_penalty" in what:
    settings = inverse.InverseSettings
    if "effort" in {f.name for f in dataclasses.fields(settings)}:
        inverse.InverseSettings = lambda **k: settings(effort="penalty", **k)
    loops["tick_penalty"] = Loop("paper_5v_16t")
    inverse.InverseSettings = settings
for kind, robot in (("tick_reuse", "paper_5v_16t"), ("tick_outside_reuse", "outside_6v_16t")):
    if kind in what:
        settings = inverse.InverseSettings
        if "tangent_reuse" in {f.name for f in dataclasses.fields(settings)}:
            inverse.InverseSettings = lambda **k: settings(tangent_reuse=2, **k)
        loops[kind] = Loop(robot)
        inverse.InverseSettings = settings
calls = dict.fromkeys(runs, 0)
print(json.dumps("ready"), flush=True)
for line in sys.stdin:
    kind, n = json.loads(line)
    gc.disable()
    if kind in loops:
        times = loops[kind].ticks(n)
    else:
        times = []
        for _ in range(n):
            t = time.thread_time()
            runs[kind](calls[kind])
            times.append(time.thread_time() - t)
            calls[kind] += 1
    gc.enable()
    print(json.dumps(float(np.median(times))), flush=True)
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--roots", nargs="+", required=True, help="label=DIR, DIR holding that revision's vertebra")
    parser.add_argument("--rounds", type=int, default=60)
    parser.add_argument("--n", type=int, default=20, help="calls per block")
    parser.add_argument("--what", default="cantilever,tick")
    parser.add_argument("--output", default=str(RESULTS / "revisions.json"))
    args = parser.parse_args(argv)
    what = args.what.split(",")
    unknown = sorted(set(what) - set(KINDS))
    if unknown:
        parser.error(f"unknown --what {', '.join(unknown)} (choose from {', '.join(KINDS)})")
    labels, roots = zip(*(spec.split("=", 1) for spec in args.roots))
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    workers = [subprocess.Popen([sys.executable, "-c", WORKER, args.what, str(Path(__file__).parent)],
                                env=dict(env, PYTHONPATH=root), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                text=True, cwd="/tmp") for root in roots]
    for worker in workers:
        if json.loads(worker.stdout.readline() or "null") != "ready":
            raise RuntimeError("a benchmark worker ended early")
    blocks = {kind: {label: [] for label in labels} for kind in what}
    loads = []
    order = list(range(len(workers)))
    for r in range(args.rounds):
        turn = order if r % 2 == 0 else order[::-1]
        turn = turn[r % len(turn):] + turn[:r % len(turn)]
        for kind in what:
            for i in turn:
                workers[i].stdin.write(json.dumps([kind, args.n]) + "\n")
                workers[i].stdin.flush()
                blocks[kind][labels[i]].append(json.loads(workers[i].stdout.readline()))
        loads.append(os.getloadavg()[0])
    for worker in workers:
        worker.stdin.close()
        worker.wait()
    document = {"roots": dict(zip(labels, roots)), "rounds": args.rounds, "calls_per_block": args.n,
                "load_average": [min(loads), float(np.median(loads)), max(loads)], "blocks_s": blocks, "ratios": {}}
    for kind in what:
        base = np.array(blocks[kind][labels[0]])
        print(f"{kind} (against {labels[0]}; load {min(loads):.1f}–{max(loads):.1f})")
        document["ratios"][kind] = {}
        for label in labels:
            ratios = np.array(blocks[kind][label]) / base
            q1, median, q3 = np.percentile(ratios, [25, 50, 75])
            document["ratios"][kind][label] = {"median": float(median), "quartiles": [float(q1), float(q3)],
                                               "block_median_us": float(np.median(blocks[kind][label]) * 1e6)}
            print(f"  {label:14s} {np.median(blocks[kind][label]) * 1e6:9.1f} µs  {median:.3f} ({q1:.3f}–{q3:.3f})")
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(json.dumps(document, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
