"""A/B timing of the inverse tick: two revisions of the package, interleaved in one run.

Each revision's package root, ``solver/`` and ``store/`` are snapshot with ``git archive`` into
a temporary ``vertebra/`` folder; rounds alternate A B B A … in fresh subprocesses that put
their snapshot first on ``sys.path``. Every subprocess times ``InverseController.step`` in tick
mode on the gallery robots (median CPU time of the thread over ``--repeats`` ticks), so load
bursts on the shared machine hit both revisions alike, in two ways:

* ``<scene>``: every tick from the same state and actuation towards targets 1 mm off;
* ``<scene>/loop``: a control loop — each tick from the state and actuation the last one left,
  towards a target moving on a 1 mm circle (one turn per 100 ticks) around those points.

The ratio reported is the median over rounds of B/A.

Run: ``.venv/bin/python benchmarks/ab_tick.py [--base main] [--head HEAD|worktree] [--rounds 8]``;
writes ``benchmarks/results/ab_tick.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
SCENES = ("paper_3v_4t", "paper_5v_16t", "tendon_two_section")


def snapshot(rev: str, into: Path) -> str:
    """``rev``'s package (root, solver/, store/) as ``into/vertebra``; returns the commit.
    ``rev = "worktree"`` copies the files of the working tree instead."""
    if rev == "worktree":
        (into / "vertebra").mkdir(parents=True)
        shutil.copy(REPO / "__init__.py", into / "vertebra")
        for package in ("solver", "store"):
            shutil.copytree(REPO / package, into / "vertebra" / package,
                            ignore=shutil.ignore_patterns("__pycache__"))
        return "worktree"
    sha = subprocess.run(["git", "rev-parse", rev], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", sha, "__init__.py", "solver", "store"], cwd=REPO,
                             capture_output=True, check=True).stdout
    (into / "vertebra").mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(into / "vertebra")], input=archive, check=True)
    return sha


def measure(repeats: int) -> dict:
    """Median tick CPU time per scene with the package first on ``sys.path`` (subprocess side)."""
    import time

    import numpy as np

    from vertebra import solver
    from vertebra.solver.gallery import load
    from vertebra.solver.inverse.controller import InverseController, InverseSettings

    out = {}
    for name in SCENES:
        model = solver.build_model(load(name))
        lo, hi = model.actuator_bounds
        lam = np.clip(np.full(len(model.actuator_names), 0.3), lo, hi)
        state = model.solve(lam).state
        targets = model.effector_positions(state) + 1e-3
        controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)

        def tick():
            controller.state, controller.actuation = state, lam
            return controller.step(targets)

        for _ in range(20):
            tick()
        times = []
        for _ in range(repeats):
            t0 = time.thread_time()
            tick()
            times.append(time.thread_time() - t0)
        out[name] = float(np.median(times))

        controller.state, controller.actuation = state, lam
        centre = model.effector_positions(state)
        angles = 2 * np.pi * np.arange(20 + repeats) / 100
        loop = centre[None] + 1e-3 * np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1)[:, None]
        for k in range(20):
            controller.step(loop[k])
        times = []
        for k in range(20, 20 + repeats):
            t0 = time.thread_time()
            controller.step(loop[k])
            times.append(time.thread_time() - t0)
        out[f"{name}/loop"] = float(np.median(times))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="main")
    parser.add_argument("--head", default="HEAD")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=400)
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # subprocess side: the snapshot root
    args = parser.parse_args(argv)
    if args.measure:
        sys.path.insert(0, args.measure)
        print(json.dumps(measure(args.repeats)))
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="ab_tick_"))
    try:
        roots = {"A": tmp / "a", "B": tmp / "b"}
        commits = {"A": snapshot(args.base, roots["A"]), "B": snapshot(args.head, roots["B"])}
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        runs = {"A": [], "B": []}
        order = []
        for r in range(args.rounds):
            order += ["A", "B"] if r % 2 == 0 else ["B", "A"]
        for side in order:
            line = subprocess.run([sys.executable, __file__, "--measure", str(roots[side]),
                                   "--repeats", str(args.repeats)], env=env, capture_output=True, text=True,
                                  check=True, cwd=tmp).stdout
            runs[side].append(json.loads(line))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    import numpy as np

    summary = {}
    for name in [key for scene in SCENES for key in (scene, f"{scene}/loop")]:
        a = np.array([run[name] for run in runs["A"]])
        b = np.array([run[name] for run in runs["B"]])
        summary[name] = {"A_median_s": float(np.median(a)), "B_median_s": float(np.median(b)),
                         "ratio_B_over_A": float(np.median(b / a)), "ratio_min": float(np.min(b / a)),
                         "ratio_max": float(np.max(b / a))}
        print(f"{name}: A {np.median(a) * 1e3:.3f} ms, B {np.median(b) * 1e3:.3f} ms, "
              f"B/A {np.median(b / a):.3f} (rounds {np.min(b / a):.3f}–{np.max(b / a):.3f})")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "ab_tick.json").write_text(json.dumps(
        {"A": {"rev": args.base, "commit": commits["A"]}, "B": {"rev": args.head, "commit": commits["B"]},
         "rounds": args.rounds, "repeats": args.repeats, "host": platform.node(),
         "load_average": os.getloadavg()[0], "scenes": summary, "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
