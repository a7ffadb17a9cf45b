"""Batched forward solves (``model.solve_batch``, ``vertebra workspace``) against the single solve.

Rows of the batching acceptance table (docs/batch.md), each measured against the serial path in the same run, interleaved
(batch, serial, batch, serial …; medians), CPU time of this process (the machine is shared:
wall time measures the scheduler):

1. ``workspace``   ``gallery:paper_5v_16t``, N samples (10,000), one process: ``sample_workspace``
                   (batches by generation) against the serial path it replaced — every sample
                   solved on its own along the spanning tree, from the Euler predictor off its
                   parent (``model.solve``, ``model.linearise``, ``model.step``).
2. ``same_samples`` B = 1,000 actuations of the same robot from rest: ``solve_batch`` against
                   ``model.solve`` one by one — throughput, and the largest difference of any
                   frame position (relative to the trunk's length), iterations and factor kinds.
3. ``robustness``  the robustness suite's random representable robots (``tests/robots.py``,
                   seeds 0…199): per robot a batch of 16 actuations (the drawn tensions × 1/16 … 1)
                   solved in a batch and one by one: converged alike, the same equilibria.
4. ``single``      the 20-link cantilever's forward solve, this tree against ``--baseline`` (a
                   directory holding the base commit's ``vertebra`` package), alternating processes.
5. ``batch_ab``    this tree's batch against ``--baseline``'s, alternating processes: the
                   1,000 cold samples of row 2 (``solve_batch``) and the 10,000-sample workspace
                   of row 1 (CPU time of each), and the single solve of the same 1,000 samples
                   (the serial path's own change).
6. ``memory``      peak resident memory of a process solving a 100,000-sample workspace of the
                   16-tendon robot (batches chunked automatically).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_batch [--quick] [--baseline DIR]``.
Results: ``benchmarks/results/batch.json``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS  # noqa: E402
from vertebra import solver  # noqa: E402
from vertebra.solver.workspace import sample_actuations, sample_workspace  # noqa: E402
from vertebra.solver.workspace_order import ORDERINGS, response_coordinates  # noqa: E402

SCENE = "gallery:paper_5v_16t"
import vertebra  # noqa: E402

ROOT = Path(vertebra.__file__).parent          # the package (the repository's root), as imported


def cpu_wall(fn):
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - cpu, time.perf_counter() - wall


def serial_workspace(model, actuations: np.ndarray) -> dict:
    """The former workspace path: one solve after the other along the spanning tree, each from
    the Euler predictor off its parent's equilibrium (factored once per parent)."""
    plan = ORDERINGS["tree"](response_coordinates(model, actuations))
    states, paths = {}, {}
    positions = np.full((len(actuations), len(model.effector_names), 3), np.nan)
    iterations = np.zeros(len(actuations), int)
    for i in plan.order.tolist():
        p = int(plan.parent[i])
        start = None
        if p in states:
            if p not in paths:
                lin = model.linearise(states[p], actuations[p])
                paths[p] = lin.solve(lin.actuator_forces)
            start = model.step(states[p], paths[p] @ (actuations[i] - actuations[p]))
        result = model.solve(actuations[i], initial=start, raise_on_failure=False)
        iterations[i] = result.iterations
        if result.converged:
            states[i] = result.state
            positions[i] = model.effector_positions(result.state)
    return {"positions": positions, "iterations": iterations}


def bench_workspace(model, n: int, rounds: int) -> dict:
    actuations = sample_actuations(model, n, seed=0)
    rows = {"batch": [], "serial": []}
    batch = serial = None
    for _ in range(rounds):
        batch, cpu, wall = cpu_wall(lambda: sample_workspace(model, actuations=actuations))
        rows["batch"].append({"cpu_s": cpu, "wall_s": wall})
        print(f"   batch  {n}: CPU {cpu:.2f} s, wall {wall:.2f} s", flush=True)
        serial, cpu, wall = cpu_wall(lambda: serial_workspace(model, actuations))
        rows["serial"].append({"cpu_s": cpu, "wall_s": wall})
        print(f"   serial {n}: CPU {cpu:.2f} s, wall {wall:.2f} s", flush=True)
    b = float(np.median([r["cpu_s"] for r in rows["batch"]]))
    s = float(np.median([r["cpu_s"] for r in rows["serial"]]))
    both = batch.converged & np.isfinite(serial["positions"][:, 0, 0])
    # the equilibria themselves: the samples where the two paths differ most and some drawn at
    # random, solved again to a tolerance far below the workspace's (1e-13)
    difference = np.abs(batch.positions - serial["positions"]).reshape(n, -1).max(1)
    check = np.union1d(np.argsort(np.where(both, difference, -1.0))[-50:],
                       np.random.default_rng(0).choice(n, min(n, 250), replace=False))
    check = check[both[check]]
    tight = model.solve_batch(actuations[check], tolerance=1e-13)
    effectors = model.trunk.effectors
    from vertebra.core.lie import qrotate
    f = effectors.frames
    truth = tight.positions[:, f] * effectors.point_mask + qrotate(tight.quaternions[:, f], effectors.offsets)
    good = tight.converged
    return {"samples": n, "rounds": rows, "batch_cpu_s": b, "serial_cpu_s": s, "speedup_cpu": s / b,
            "batch_wall_s": float(np.median([r["wall_s"] for r in rows["batch"]])),
            "serial_wall_s": float(np.median([r["wall_s"] for r in rows["serial"]])),
            "batch_iterations_mean": float(batch.iterations[batch.converged].mean()),
            "serial_iterations_mean": float(serial["iterations"].mean()),
            "batch_converged": int(batch.converged.sum()), "serial_converged": int(np.isfinite(serial["positions"][:, 0, 0]).sum()),
            "largest_effector_difference_m": float(np.abs(batch.positions[both] - serial["positions"][both]).max()),
            "checked_against_tolerance_1e-13": int(good.sum()),
            "batch_largest_distance_to_equilibrium_m": float(np.abs(batch.positions[check][good] - truth[good]).max()),
            "serial_largest_distance_to_equilibrium_m": float(np.abs(serial["positions"][check][good]
                                                                     - truth[good]).max()),
            "batch_iterations_histogram": np.bincount(batch.iterations[batch.converged]).tolist()}


def bench_same_samples(model, n: int, rounds: int) -> dict:
    rng = np.random.default_rng(11)
    lower, upper = model.actuator_bounds
    actuations = rng.uniform(lower, upper, (n, len(lower)))
    times = {"batch": [], "serial": []}
    for _ in range(rounds):
        batch, cpu, _ = cpu_wall(lambda: model.solve_batch(actuations))
        times["batch"].append(cpu)
        singles, cpu, _ = cpu_wall(lambda: [model.solve(a, raise_on_failure=False) for a in actuations])
        times["serial"].append(cpu)
        print(f"   B={n}: batch {times['batch'][-1]:.2f} s, serial {cpu:.2f} s CPU", flush=True)
    difference = max(float(np.abs(batch.positions[i] - r.state.positions).max()) for i, r in enumerate(singles)
                     if r.converged)
    b, s = float(np.median(times["batch"])), float(np.median(times["serial"]))
    return {"samples": n, "batch_cpu_s": times["batch"], "serial_cpu_s": times["serial"],
            "batch_per_sample_ms": 1e3 * b / n, "serial_per_sample_ms": 1e3 * s / n, "throughput_ratio": s / b,
            "converged_batch": int(batch.converged.sum()), "converged_serial": sum(r.converged for r in singles),
            "left_batch_path": int(batch.single.sum()),
            "same_iterations": int(sum(batch.iterations[i] == r.iterations for i, r in enumerate(singles))),
            "same_factor_kinds": int(sum(batch.factorization[i] == r.factorization for i, r in enumerate(singles))),
            "largest_position_difference_relative": difference / model.length_scale,
            "iterations_mean": float(batch.iterations.mean())}


def bench_robustness(n_seeds: int) -> dict:
    sys.path.insert(0, str(ROOT / "tests"))
    import robots                                          # (the test suite's generators)

    rows = []
    for seed in range(n_seeds):
        scene, check, _ = robots.draw_representable(np.random.default_rng(seed))
        model = solver.build_model(solver.parse_scene(scene))
        base = model.actuation()
        actuations = base * (np.arange(1, 17) / 16.0)[:, None]
        batch, cpu_b, _ = cpu_wall(lambda: model.solve_batch(actuations))
        singles, cpu_s, _ = cpu_wall(lambda: [model.solve(a, raise_on_failure=False) for a in actuations])
        same = all(batch.converged[i] == r.converged for i, r in enumerate(singles))
        difference = max((float(np.abs(batch.positions[i] - r.state.positions).max()) / model.length_scale
                          for i, r in enumerate(singles) if r.converged), default=0.0)
        rows.append({"seed": seed, "converged_batch": int(batch.converged.sum()),
                     "converged_serial": sum(r.converged for r in singles), "same_convergence": same,
                     "left_batch_path": int(batch.single.sum()), "why": sorted(set(w for w in batch.why if w)),
                     "largest_difference_relative": difference, "batch_cpu_s": cpu_b, "serial_cpu_s": cpu_s})
        print(f"   robot {seed}: {rows[-1]['converged_batch']}/16 batch, {rows[-1]['converged_serial']}/16 serial, "
              f"diff {difference:.1e}", flush=True)
    return {"robots": n_seeds, "samples_per_robot": 16,
            "all_converged_batch": sum(r["converged_batch"] == 16 for r in rows),
            "all_converged_serial": sum(r["converged_serial"] == 16 for r in rows),
            "same_convergence": sum(r["same_convergence"] for r in rows),
            "largest_difference_relative": max(r["largest_difference_relative"] for r in rows),
            "samples_leaving_batch_path": sum(r["left_batch_path"] for r in rows), "rows": rows}


SINGLE = """
import time, numpy as np
from vertebra import solver
m = solver.build_model(solver.load_scene('gallery:cantilever'))
for _ in range(50): m.solve()
ts = []
for _ in range({repeats}):
    t = time.process_time(); m.solve(); ts.append(time.process_time() - t)
print(np.median(ts))
"""


def bench_single(baseline: str | None, rounds: int, repeats: int) -> dict | None:
    if baseline is None:
        return None
    here = str(ROOT.parent)
    times = {"this": [], "baseline": []}
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    for _ in range(rounds):
        for name, path in (("this", here), ("baseline", baseline)):
            out = subprocess.run([sys.executable, "-c", SINGLE.format(repeats=repeats)], capture_output=True,
                                 text=True, env=dict(env, PYTHONPATH=path), check=True)
            times[name].append(float(out.stdout.strip()))
        print(f"   20-link solve: this {times['this'][-1] * 1e6:.0f} µs, base {times['baseline'][-1] * 1e6:.0f} µs",
              flush=True)
    this, base = float(np.median(times["this"])), float(np.median(times["baseline"]))
    return {"rounds": times, "this_us": this * 1e6, "baseline_us": base * 1e6, "ratio": this / base,
            "ratios": [a / b for a, b in zip(times["this"], times["baseline"])]}


BATCH_AB = """
import time, numpy as np
from vertebra import solver
from vertebra.solver.workspace import sample_actuations, sample_workspace
m = solver.build_model(solver.load_scene('gallery:paper_5v_16t'))
lower, upper = m.actuator_bounds
act = np.random.default_rng(11).uniform(lower, upper, ({n}, len(lower)))
m.solve_batch(act[:100]); sample_workspace(m, 70)
t = time.process_time(); m.solve_batch(act); batch = time.process_time() - t
t = time.process_time(); [m.solve(a, raise_on_failure=False) for a in act[:{serial}]]; serial = (time.process_time() - t) / {serial}
ws = sample_actuations(m, {workspace}, seed=0)
t = time.process_time(); sample_workspace(m, actuations=ws); work = time.process_time() - t
print(batch, serial, work)
"""


def bench_batch_ab(baseline: str | None, rounds: int, n: int, serial: int, workspace: int) -> dict | None:
    if baseline is None:
        return None
    here = str(ROOT.parent)
    names = ("batch_s", "serial_per_sample_s", "workspace_s")
    times = {side: {k: [] for k in names} for side in ("this", "baseline")}
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    for r in range(rounds):
        order = (("this", here), ("baseline", baseline)) if r % 2 == 0 else (("baseline", baseline), ("this", here))
        for name, path in order:
            out = subprocess.run([sys.executable, "-c", BATCH_AB.format(n=n, serial=serial, workspace=workspace)],
                                 capture_output=True, text=True, env=dict(env, PYTHONPATH=path), check=True)
            for k, v in zip(names, out.stdout.split()):
                times[name][k].append(float(v))
        print("   " + ", ".join(f"{k} this/base {times['this'][k][-1]:.3g}/{times['baseline'][k][-1]:.3g}"
                                 for k in names), flush=True)
    result = {"rounds": times, "samples": n, "workspace_samples": workspace}
    for k in names:
        ratios = [a / b for a, b in zip(times["this"][k], times["baseline"][k])]
        result[k] = {"this": float(np.median(times["this"][k])), "baseline": float(np.median(times["baseline"][k])),
                     "ratio_median": float(np.median(ratios)), "ratios": ratios}
    return result


MEMORY = """
import resource, time, numpy as np
from vertebra import solver
from vertebra.solver.batch import chunk_size
from vertebra.solver.workspace import sample_workspace
m = solver.build_model(solver.load_scene('gallery:paper_5v_16t'))
t = time.process_time()
ws = sample_workspace(m, {n})
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, chunk_size(m.trunk), int(ws.converged.sum()),
      time.process_time() - t)
"""


def bench_memory(n: int) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT.parent))
    out = subprocess.run([sys.executable, "-c", MEMORY.format(n=n)], capture_output=True, text=True, env=env,
                         check=True).stdout.split()
    peak_kib, chunk, converged, cpu = int(out[0]), int(out[1]), int(out[2]), float(out[3])
    print(f"   {n} samples: peak RSS {peak_kib / 2**20:.2f} GiB, chunk {chunk}, {converged} converged, "
          f"CPU {cpu:.1f} s", flush=True)
    return {"samples": n, "peak_rss_gib": peak_kib / 2**20, "chunk": chunk, "converged": converged, "cpu_s": cpu}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run (small sizes; not the acceptance figures)")
    parser.add_argument("--baseline", default=None, help="directory holding the base commit's vertebra package")
    parser.add_argument("--only", default=None, help="comma-separated sections to run")
    parser.add_argument("--output", default=str(RESULTS / "batch.json"))
    args = parser.parse_args(argv)
    quick = args.quick
    only = set(args.only.split(",")) if args.only else None
    model = solver.build_model(solver.load_scene(SCENE))
    sample_workspace(model, 70)                 # imports and caches warmed
    document = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
                "numpy": np.__version__, "loadavg_start": os.getloadavg(),
                "note": "CPU time of this process; shared 2-core machine under load from other jobs"}
    path = Path(args.output)
    if path.exists() and only:
        document = {**json.loads(path.read_text()), **document}
    sections = [("workspace", lambda: bench_workspace(model, 1000 if quick else 10_000, 1 if quick else 2)),
                ("same_samples", lambda: bench_same_samples(model, 200 if quick else 1000, 1 if quick else 3)),
                ("robustness", lambda: bench_robustness(10 if quick else 200)),
                ("single", lambda: bench_single(args.baseline, 2 if quick else 8, 200 if quick else 400)),
                ("batch_ab", lambda: bench_batch_ab(args.baseline, 2 if quick else 6, 1000, 100 if quick else 300,
                                                    1000 if quick else 10_000)),
                ("memory", lambda: bench_memory(10_000 if quick else 100_000))]
    for name, run in sections:
        if only and name not in only:
            continue
        print(f"{name}", flush=True)
        document[name] = run()
        document["loadavg_end"] = os.getloadavg()
        path.write_text(json.dumps(document, indent=1, default=float))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
