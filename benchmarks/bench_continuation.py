"""Continuation under loads without a potential (dead moments): what it finishes, what it names,
and what it costs the solves that never need it.

1. ``compressed``  random eight-beam trunks (one element each, R 10 mm, L 8 × 20 mm, E 1 MPa)
                   compressed at 0.5–6 × their Euler load with a sideways part, under dead tip
                   moments of 0.5–12 EI/L (seeds 1–3, 150 each): how each solve ends — converged by
                   the load stepping, converged by continuation after the stepping gave up, a
                   limit point, a bifurcation, a stop with a regular tangent, or a state a link
                   cannot represent — with iterations and CPU time.
2. ``ab``          the cost of the forward solve where continuation never runs, this tree against
                   ``--baseline`` (a directory holding the base commit's ``vertebra`` package),
                   alternating processes (CPU time of each): the 20-link cantilever under a dead
                   tip force (conservative), and 16 trunks of section 1's kind under dead tip
                   moments that turn their links 25–95° (converged by the stepping).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_continuation [--baseline DIR]
[--rounds 8]``; writes ``benchmarks/results/continuation.json``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, loadavg, log, now, write_json  # noqa: E402
from tests.test_dead_moments import COUNT, EI, LENGTH, RADIUS, E, _compressed  # noqa: E402

TRUNK = """
import math, time, numpy as np
from vertebra import solver
E, RADIUS, LENGTH, COUNT = {E!r}, {RADIUS!r}, {LENGTH!r}, {COUNT!r}
EI = E * math.pi * RADIUS ** 4 / 4
def trunk(force, moment):
    data = {{"segment": [{{"type": "beam", "count": COUNT, "length": LENGTH, "elements": 1, "youngs_modulus": E,
                         "poisson_ratio": 0.3, "section": {{"shape": "circle", "radius": RADIUS}}}}],
            "load": [{{"vertebra": -1, "force": list(map(float, force)), "moment": list(map(float, moment))}}],
            "effector": [{{"name": "tip", "vertebra": -1}}]}}
    return solver.build_model(solver.parse_scene(data))
"""

AB = TRUNK + """
from vertebra.solver import gallery
rng = np.random.default_rng(0)
moments = []
for _ in range(16):
    d, m = rng.normal(size=3), rng.normal(size=3)
    f = rng.uniform(3.0, 12.0)
    moments.append(trunk(0.3 * f * EI / (COUNT * LENGTH) ** 2 * d / np.linalg.norm(d),
                         f * EI / (COUNT * LENGTH) * m / np.linalg.norm(m)))
cantilever = solver.build_model(solver.load_scene("gallery:cantilever"))
cantilever.solve(); [m.solve() for m in moments]
t = time.process_time()
for _ in range({repeats}):
    cantilever.solve()
single = (time.process_time() - t) / {repeats}
t = time.process_time()
its = sum(m.solve().iterations for m in moments)
print(single, time.process_time() - t, its)
"""


def outcome(result, budget: int) -> str:
    if result.converged:
        return "continued" if result.iterations > budget else "stepped"
    message = result.message
    if "limit point" in message:
        return "limit_point"
    if "bifurcation" in message:
        return "bifurcation"
    if "continuation" in message:
        return "regular_stop"
    if "turns" in message or "compressed to" in message:
        return "unrepresentable"
    return "other"


def bench_compressed(seeds, count: int) -> dict:
    namespace: dict = {}
    exec(TRUNK.format(E=E, RADIUS=RADIUS, LENGTH=LENGTH, COUNT=COUNT), namespace)
    rows = []
    for seed in seeds:
        for k, (force, moment) in enumerate(_compressed(seed, count, euler=6.0, sideways=0.3, moments=12.0)):
            model = namespace["trunk"](force, moment)
            start = time.process_time()
            result = model.solve(raise_on_failure=False)
            budget = 10 * model.scene.solver.max_iterations
            row = {"seed": seed, "k": k, "force_N": force.tolist(), "moment_Nm": moment.tolist(),
                   "outcome": outcome(result, budget), "iterations": int(result.iterations),
                   "cpu_s": time.process_time() - start}
            if not result.converged:
                row["message"] = result.message
                found = re.search(r"past load factor ([0-9.]+)", result.message)
                if found:
                    row["load_factor"] = float(found.group(1))
            rows.append(row)
    counts = {}
    for row in rows:
        counts[row["outcome"]] = counts.get(row["outcome"], 0) + 1
    summary = {"trunks": len(rows), "outcomes": counts,
               "largest_iterations": max(r["iterations"] for r in rows),
               "largest_cpu_s": max(r["cpu_s"] for r in rows)}
    log(f"compressed: {summary}")
    return {"summary": summary, "rows": rows}


def bench_ab(baseline: str, rounds: int, repeats: int) -> dict:
    import vertebra

    package = Path(vertebra.__file__).parent
    if package.name != "vertebra":
        raise SystemExit(f"the A/B needs this tree imported as a folder named vertebra (PYTHONPATH=<folder holding it>); "
                         f"it was imported from {package}")
    here = str(package.parent)
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    code = AB.format(E=E, RADIUS=RADIUS, LENGTH=LENGTH, COUNT=COUNT, repeats=repeats)
    times = {side: {"cantilever_s": [], "dead_moments_s": [], "iterations": []} for side in ("this", "baseline")}
    for r in range(rounds):
        order = (("this", here), ("baseline", baseline)) if r % 2 == 0 else (("baseline", baseline), ("this", here))
        for name, path in order:
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 env=dict(env, PYTHONPATH=path), check=True)
            single, moments, iterations = out.stdout.split()
            times[name]["cantilever_s"].append(float(single))
            times[name]["dead_moments_s"].append(float(moments))
            times[name]["iterations"].append(int(iterations))
        log(f"  round {r}: cantilever this {times['this']['cantilever_s'][-1] * 1e6:.0f} µs, base "
            f"{times['baseline']['cantilever_s'][-1] * 1e6:.0f} µs; 16 dead-moment trunks this "
            f"{times['this']['dead_moments_s'][-1]:.3f} s, base {times['baseline']['dead_moments_s'][-1]:.3f} s")
    ratios = {key: float(np.median([a / b for a, b in zip(times["this"][key], times["baseline"][key])]))
              for key in ("cantilever_s", "dead_moments_s")}
    return {"rounds": times, "median_ratio_this_over_baseline": ratios,
            "same_iterations": times["this"]["iterations"] == times["baseline"]["iterations"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=None, help="directory holding the base commit's vertebra package")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=200, help="cantilever solves per process")
    parser.add_argument("--count", type=int, default=150, help="compressed trunks per seed")
    parser.add_argument("--out", default=str(RESULTS / "continuation.json"))
    args = parser.parse_args(argv)
    document = {"meta": {"date": now(), "load_start": loadavg()}}
    document["compressed"] = bench_compressed((1, 2, 3), args.count)
    document["meta"]["load_after_compressed"] = loadavg()
    if args.baseline:
        document["ab"] = bench_ab(args.baseline, args.rounds, args.repeats)
    document["meta"]["load_end"] = loadavg()
    write_json(document, Path(args.out))
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
