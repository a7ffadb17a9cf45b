"""Benchmark of the inverse tick (real-time mode) on 16-tendon robots, with its checks, and an
interleaved A/B against another revision of the package.

Robots:

* ``paper_5v_16t`` — the gallery's 16-tendon robot (paper §V-a: 5 vertebrae, 10 beam links, four
  tendons ending at each of vertebrae 2–5, gravity, effectors ``mid`` and ``tip``);
* ``outside_6v_16t`` — a 16-tendon robot that is not in the gallery (:data:`OUTSIDE`): 6 vertebrae
  22 mm apart, 3 links each (18 links, 19 frames), a thinner and softer backbone, the tendons in four
  groups ending at vertebrae 2, 3, 5 and 6 on holes at 7–13 mm, each group turned by 22.5°, gravity
  across the base axis, effectors at vertebra 3 and the tip.

Protocol (the control loop of ``benchmarks/speed/inverse.py``): from the equilibrium under 0.3 N
on every tendon, each tick from the state and actuation the last one left, the targets moving on
a 1 mm circle around the effectors there (one turn per 100 ticks); 20 ticks of warm-up, then
``--rounds`` blocks of ``--block`` timed ticks per robot (CPU time of the thread, garbage
collector off). After the timing every tick is checked: actuation inside the bounds, change
within the per-tick limit, and the equilibrium under its actuation found
(``InverseController.settled``), with the largest error of those equilibria from the targets.

A/B: ``--base REV`` (a git revision, snapshot with ``git archive``) or ``--base-root DIR`` (a
folder holding a ``vertebra`` package) is timed against this tree. Each side runs in its own
worker process that keeps its controllers; the blocks alternate between the sides (A B, then
B A, …) so that load bursts on a shared machine hit both alike, and the ratio reported is the
median over blocks of B/A (B: this tree), with its quartiles.

``--tangent-reuse N`` runs this tree's loops with ``InverseSettings(tangent_reuse=N)`` (chord ticks;
the A side keeps its default), so the ratio and the settled errors show that knob's trade.

Run: ``.venv/bin/python -m benchmarks.bench_tick [--base REV | --base-root DIR] [--rounds 40]
[--block 50] [--tangent-reuse N]``; writes ``benchmarks/results/tick.json``.
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

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
ROBOTS = ("paper_5v_16t", "outside_6v_16t")
PACKAGE = ("__init__.py", "core", "solver", "store")    # what the runtime imports

# a 16-tendon robot outside the gallery (module docstring)
OUTSIDE = {
    "name": "outside_6v_16t",
    "gravity": {"vector": [0.0, -9.81, 0.0]},
    "segment": [{"type": "beam", "count": 6, "length": 0.022, "elements": 3, "youngs_modulus": 40e9,
                 "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 0.0008}, "density": 6450.0,
                 "vertebra": {"mass": 0.003}}],
    "cable": [{"name": f"t{4 * g + j + 1}", "radius": 0.007 + 0.002 * g, "angle_deg": 90.0 * j + 22.5 * g,
               "from": 1, "to": end, "tension": 0.0, "min_tension": 0.0, "max_tension": 12.0}
              for g, end in enumerate((2, 3, 5, 6)) for j in range(4)],
    "effector": [{"name": "mid", "vertebra": 3}, {"name": "tip", "vertebra": -1}],
}


def robot(name: str):
    """The compiled model of one of :data:`ROBOTS`."""
    from vertebra import solver
    from vertebra.solver.gallery import load

    return solver.build_model(solver.parse_scene(OUTSIDE) if name == "outside_6v_16t" else load(name))


class Loop:
    """One robot's control loop in tick mode (module docstring): ticks on demand, timed, and the
    checks of every tick run so far."""

    def __init__(self, name: str, tangent_reuse: int = 0):
        import numpy as np

        from vertebra.solver.inverse import InverseController, InverseSettings

        self.model = model = robot(name)
        lower, upper = model.actuator_bounds
        lam = np.clip(np.full(len(model.actuator_names), 0.3), lower, upper)
        state = model.solve(lam).state
        settings = (InverseSettings(mode="tick", tangent_reuse=tangent_reuse) if tangent_reuse else
                    InverseSettings(mode="tick"))
        self.controller = InverseController(model, settings, actuation=lam, state=state)
        self.centre = model.effector_positions(state)
        self.k = 0
        self.run = []
        self.ticks(20)          # warm-up (not kept)
        self.run = []

    def target(self, k: int):
        import numpy as np

        angle = 2 * np.pi * k / 100
        return self.centre + 1e-3 * np.array([np.cos(angle), np.sin(angle), 0.0])

    def ticks(self, count: int) -> list:
        """CPU times (s, this thread) of the next ``count`` ticks, the garbage collector off."""
        import gc
        import time

        targets = [self.target(self.k + i) for i in range(count)]
        self.k += count
        times = []
        gc.disable()
        try:
            for target in targets:
                previous = self.controller.actuation
                t0 = time.thread_time()
                step = self.controller.step(target)
                times.append(time.thread_time() - t0)
                self.run.append((previous, step))
        finally:
            gc.enable()
        return times

    def checks(self) -> dict:
        """Bounds, per-tick changes and the equilibrium of every tick run (after the timing)."""
        import numpy as np

        model = self.model
        lower, upper = model.actuator_bounds
        change = model.actuator_max_change
        bounds = changes = equilibria = 0
        statuses: dict = {}
        errors = []
        for previous, step in self.run:
            statuses[step.status] = statuses.get(step.status, 0) + 1
            bounds += int(np.any(step.actuation < lower) or np.any(step.actuation > upper))
            changes += int(np.any(np.abs(step.actuation - previous) > change * (1 + 1e-12)))
            settled = self.controller.settled(step)
            equilibria += int(settled.equilibrium)
            errors.append(float(settled.errors.max()))
        return {"ticks": len(self.run), "bound_violations": bounds, "change_violations": changes,
                "equilibria": equilibria, "statuses": statuses, "max_error_m": max(errors, default=0.0),
                "frames": int(model.n_frames), "tendons": int(model.n_cables)}


def worker() -> None:
    """The subprocess side: builds every robot's loop, then answers one JSON line per request
    ``["ticks", robot, count]`` (the CPU times) or ``["checks"]`` (the checks per robot)."""
    reuse = int(os.environ.get("BENCH_TICK_REUSE", "0"))
    loops = {name: Loop(name, reuse) for name in ROBOTS}
    print(json.dumps("ready"), flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        if request[0] == "ticks":
            answer = loops[request[1]].ticks(int(request[2]))
        else:
            answer = {name: loop.checks() for name, loop in loops.items()}
        print(json.dumps(answer), flush=True)


class Side:
    """A worker subprocess with one revision's package first on its path."""

    def __init__(self, root: Path, tangent_reuse: int = 0):
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   PYTHONPATH=str(root), BENCH_TICK_REUSE=str(tangent_reuse))
        code = "import sys; sys.path.insert(0, sys.argv[1]); from bench_tick import worker; worker()"
        self.process = subprocess.Popen([sys.executable, "-c", code, str(Path(__file__).parent)], env=env,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                        cwd=tempfile.gettempdir())
        self.ask(None)

    def ask(self, request):
        if request is not None:
            self.process.stdin.write(json.dumps(request) + "\n")
            self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError("the benchmark worker ended early")
        return json.loads(line)

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def snapshot(rev: str, into: Path) -> str:
    """``rev``'s runtime package (:data:`PACKAGE`) as ``into/vertebra``; returns the commit."""
    sha = subprocess.run(["git", "rev-parse", rev], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", sha, *PACKAGE], cwd=REPO, capture_output=True, check=True).stdout
    (into / "vertebra").mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(into / "vertebra")], input=archive, check=True)
    return sha


def head() -> str:
    out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "--", *PACKAGE], cwd=REPO, capture_output=True,
                           text=True).stdout.strip()
    return out.stdout.strip() + (" (with uncommitted changes)" if dirty else "")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", help="git revision to compare against (A)")
    parser.add_argument("--base-root", help="folder holding the A side's vertebra package")
    parser.add_argument("--rounds", type=int, default=40, help="blocks of ticks per robot and side")
    parser.add_argument("--block", type=int, default=50, help="ticks per block")
    parser.add_argument("--tangent-reuse", type=int, default=0, metavar="N",
                        help="this tree's (B) controllers reuse a tick's tangent factor for up to N ticks "
                             "(InverseSettings.tangent_reuse; A keeps its default)")
    args = parser.parse_args(argv)
    import numpy as np

    tmp = Path(tempfile.mkdtemp(prefix="bench_tick_"))
    workers = {}
    try:
        roots = {"B": tmp / "b"}
        roots["B"].mkdir()
        (roots["B"] / "vertebra").symlink_to(REPO)
        commits = {"B": head()}
        if args.base_root:
            roots["A"] = Path(args.base_root)
            commits["A"] = subprocess.run(["git", "rev-parse", "HEAD"], cwd=roots["A"] / "vertebra",
                                          capture_output=True, text=True).stdout.strip()
        elif args.base:
            roots["A"] = tmp / "a"
            commits["A"] = snapshot(args.base, roots["A"])
        sides = sorted(roots)
        workers = {side: Side(roots[side], args.tangent_reuse if side == "B" else 0) for side in sides}
        blocks = {side: {name: [] for name in ROBOTS} for side in sides}
        loads = []
        for r in range(args.rounds):
            for name in ROBOTS:
                for side in (sides if r % 2 == 0 else sides[::-1]):     # A B, then B A, …
                    blocks[side][name].append(workers[side].ask(["ticks", name, args.block]))
            loads.append(os.getloadavg()[0])
        checks = {side: workers[side].ask(["checks"]) for side in sides}
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)

    summary = {}
    for name in ROBOTS:
        row = {}
        for side in sides:
            times = np.concatenate(blocks[side][name])
            row[side] = {"median_s": float(np.median(times)), "p90_s": float(np.percentile(times, 90)),
                         "block_medians_s": [float(np.median(b)) for b in blocks[side][name]],
                         **checks[side][name]}
        if "A" in row:
            ratios = np.array(row["B"]["block_medians_s"]) / np.array(row["A"]["block_medians_s"])
            row["ratio_B_over_A"] = float(np.median(ratios))
            row["ratio_quartiles"] = [float(np.percentile(ratios, 25)), float(np.percentile(ratios, 75))]
        summary[name] = row
        b = row["B"]
        text = (f"{name}: B {b['median_s'] * 1e3:.3f} ms (equilibria {b['equilibria']}/{b['ticks']}, "
                f"bound violations {b['bound_violations']}, per-tick change violations {b['change_violations']})")
        if "A" in row:
            text += (f"; A {row['A']['median_s'] * 1e3:.3f} ms (equilibria {row['A']['equilibria']}/"
                     f"{row['A']['ticks']}); B/A {row['ratio_B_over_A']:.3f} (blocks' quartiles "
                     f"{row['ratio_quartiles'][0]:.3f}–{row['ratio_quartiles'][1]:.3f})")
        print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    document = {"A": {"rev": args.base or args.base_root, "commit": commits.get("A")},
                "B": {"commit": commits["B"]}, "rounds": args.rounds, "block": args.block, "tangent_reuse_B": args.tangent_reuse,
                "host": f"{platform.node()} · {platform.processor() or platform.machine()} · python "
                        f"{platform.python_version()} · {os.cpu_count()} cores",
                "load_average": {"min": min(loads), "median": float(np.median(loads)), "max": max(loads)},
                "robots": summary}
    (RESULTS / "tick.json").write_text(json.dumps(document, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
