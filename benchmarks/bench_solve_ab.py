"""Interleaved A/B of the two solves the tick's kernels share: the 20-link cantilever solve and
the serial solve of the 16-tendon robot from rest, against another revision of the package.

Each round runs one fresh process per side (A B, then B A, …): 300 timed cantilever solves after
50 of warm-up, then 150 solves of ``paper_5v_16t`` from rest at random tensions (seed 11) after 20;
each side's figure is the median process CPU time per solve, the ratio B/A (B: this tree) its
median over the rounds, with quartiles.

Run: ``.venv/bin/python -m benchmarks.bench_solve_ab --base-root DIR [--rounds 10]`` (``DIR`` holds
the A side's ``vertebra`` package, e.g. ``git archive <rev>`` unpacked into ``DIR/vertebra``);
writes ``benchmarks/results/solve_ab.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"

CODE = """
import time, numpy as np
from vertebra import solver
out = []
m = solver.build_model(solver.load_scene('gallery:cantilever'))
for _ in range(50): m.solve()
ts = []
for _ in range(300):
    t = time.process_time(); m.solve(); ts.append(time.process_time() - t)
out.append(float(np.median(ts)))
m = solver.build_model(solver.load_scene('gallery:paper_5v_16t'))
lower, upper = m.actuator_bounds
act = np.random.default_rng(11).uniform(lower, upper, (150, len(lower)))
for a in act[:20]: m.solve(a, raise_on_failure=False)
ts = []
for a in act:
    t = time.process_time(); m.solve(a, raise_on_failure=False); ts.append(time.process_time() - t)
out.append(float(np.median(ts)))
print(*out)
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base-root", required=True, help="folder holding the A side's vertebra package")
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--output", default=str(RESULTS / "solve_ab.json"))
    args = parser.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench_solve_ab_"))
    (tmp / "vertebra").symlink_to(REPO)                 # this tree, importable as vertebra
    roots = {"A": str(Path(args.base_root)), "B": str(tmp)}
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    times = {"A": [], "B": []}
    loads = []
    for r in range(args.rounds):
        for side in ("AB" if r % 2 == 0 else "BA"):
            out = subprocess.run([sys.executable, "-c", CODE], env=dict(env, PYTHONPATH=roots[side]), capture_output=True,
                                 text=True, check=True, cwd="/tmp").stdout.split()
            times[side].append([float(x) for x in out])
        loads.append(os.getloadavg()[0])
        a, b = times["A"][-1], times["B"][-1]
        print(f"round {r}: cantilever B/A {b[0] / a[0]:.3f} ({b[0] * 1e6:.0f}/{a[0] * 1e6:.0f} µs), paper_5v_16t "
              f"serial B/A {b[1] / a[1]:.3f} ({b[1] * 1e6:.0f}/{a[1] * 1e6:.0f} µs), load {loads[-1]:.1f}", flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    A, B = np.array(times["A"]), np.array(times["B"])
    ratios = B / A
    document = {"A": roots["A"], "B": roots["B"], "rounds": args.rounds,
                "load_average": [min(loads), float(np.median(loads)), max(loads)], "per_round": times}
    for k, name in enumerate(("cantilever", "paper_serial")):
        document[f"{name}_us"] = [float(np.median(A[:, k]) * 1e6), float(np.median(B[:, k]) * 1e6)]
        document[f"{name}_ratio_median"] = float(np.median(ratios[:, k]))
        document[f"{name}_ratio_quartiles"] = np.percentile(ratios[:, k], [25, 75]).tolist()
        print(f"{name}: B/A {document[f'{name}_ratio_median']:.3f} (quartiles "
              f"{document[f'{name}_ratio_quartiles'][0]:.3f}–{document[f'{name}_ratio_quartiles'][1]:.3f})")
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(json.dumps(document, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
