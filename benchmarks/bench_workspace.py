"""Benchmark of workspace sampling (``vertebra workspace``) on the paper's 16-tendon robot.

Sections:
1. acceptance: 10,000 Sobol samples of ``paper_5v_16t`` (16 tendons, 0–20 N) with the default
   settings (spanning-tree order, Euler predictor, the scene's Newton tolerance) in one
   process and in two worker processes: wall and CPU time (``time.process_time``, worker
   processes included), samples per second, Newton iterations per solve, failures;
2. solve orders on the same 2,000 samples — ``tree``, ``chain``, ``sampled`` — each with the
   Euler predictor and, as the baseline, starting from the parent's equilibrium itself;
3. the Newton tolerance as a speed/accuracy knob: cost against the effector error relative
   to solves at 1e-13 (1,000 samples).

The machine is shared (2 cores, several jobs): CPU time is the figure to compare; wall time
is what a user waits and is recorded with the load average at start and end. Contention
inflates CPU time too, so the run also times a reference solve that ``bench_solver.py``
timed at low load (``paper_5v_16t`` with 3 N on every fourth tendon, from rest, its row in
``results/solver.json``): the ratio of the two is the slowdown at the time of this run, and
the CPU time divided by it estimates the same run on the quiet machine.

Run: ``.venv/bin/python -m benchmarks.bench_workspace [--quick] [--picture FILE.png]``; writes
``benchmarks/results/workspace.json``, ``workspace.md`` and ``workspace_tolerance.png`` (the
tolerance trade); ``--picture`` also draws the clouds of section 1.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import render
from benchmarks.common import RESULTS, timed
from vertebra import __version__, solver
from vertebra.designer.threads import pin_blas_threads
from vertebra.solver.workspace import ORDERINGS, response_coordinates, sample_actuations, sample_workspace

SCENE = "gallery:paper_5v_16t"
TARGET_S = 10.0


def run_row(model, n, **options) -> dict:
    workspace = sample_workspace(model, n, **options)
    its = workspace.iterations[workspace.converged]
    t = workspace.timings
    return {"samples": n, **{k: v for k, v in options.items() if k != "actuations"},
            "wall_s": t["wall_s"], "cpu_s": t["cpu_s"], "order_s": t["order_s"],
            "samples_per_s_wall": n / t["wall_s"], "samples_per_s_cpu": n / t["cpu_s"],
            "cpu_ms_per_sample": 1e3 * t["cpu_s"] / n,
            "iterations_mean": float(its.mean()), "iterations_max": int(its.max()),
            "iterations_histogram": np.bincount(its).tolist(),
            "failures": len(workspace.failures), "warm": int(workspace.warm.sum()),
            "predicted": int(workspace.predicted.sum())}, workspace


def parent_equilibrium_baseline(model, actuations, ordering) -> dict:
    """The same order, each sample starting from its parent's equilibrium itself (no
    predictor): what the Euler predictor is measured against."""
    wall, cpu = time.perf_counter(), time.process_time()
    plan = ORDERINGS[ordering](response_coordinates(model, actuations))
    states, its, failures = {}, [], 0
    for i in plan.order:
        try:
            result = model.solve(actuations[i], initial=states.get(plan.parent[i]))
        except Exception:                                   # counted like sample_workspace does
            failures += 1
            continue
        states[i] = result.state
        its.append(result.iterations)
    n, cpu_s = len(actuations), time.process_time() - cpu
    return {"samples": n, "ordering": ordering, "predictor": False, "wall_s": time.perf_counter() - wall,
            "cpu_s": cpu_s, "cpu_ms_per_sample": 1e3 * cpu_s / n, "iterations_mean": float(np.mean(its)),
            "iterations_max": int(np.max(its)), "iterations_histogram": np.bincount(its).tolist(),
            "failures": failures}


def tolerance_rows(model, n) -> list:
    actuations = sample_actuations(model, n, seed=11)
    reference = sample_workspace(model, actuations=actuations, tolerance=1e-13).positions
    rows = []
    for tolerance in (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11):
        row, workspace = run_row(model, n, actuations=actuations, tolerance=tolerance)
        error = np.linalg.norm(workspace.positions - reference, axis=2)
        row.update(max_error_m=float(np.nanmax(error)), median_error_m=float(np.nanmedian(error)))
        rows.append(row)
    return rows


def reference_solve_cpu_s(model, repeats: int = 41) -> float:
    """Median CPU time of bench_solver's gallery row for this robot: 3 N on every fourth
    tendon, solved from rest."""
    actuation = np.zeros(len(model.actuator_names))
    actuation[:model.n_cables:4] = 3.0
    return timed(lambda: model.solve(actuation), repeats)[1]["cpu_median_s"]


def quiet_reference_s() -> tuple[float | None, list | None]:
    """The same solve's CPU median in results/solver.json and the load it was measured at."""
    try:
        document = json.loads((RESULTS / "solver.json").read_text())
        row = next(r for r in document["gallery"]["rows"] if r["scene"].startswith("paper_5v_16t ("))
        return float(row["wall"]["cpu_median_s"]), row.get("loadavg")
    except (OSError, KeyError, StopIteration, ValueError):
        return None, None


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip()
    except OSError:
        return "?"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples (not the acceptance figure)")
    parser.add_argument("--picture", default=None, help="also draw the clouds of section 1 into this file")
    args = parser.parse_args(argv)
    pin_blas_threads()
    n_accept, n_order, n_tol = (2000, 500, 200) if args.quick else (10_000, 2000, 1000)
    load_start = os.getloadavg()
    model = solver.build_model(solver.load_scene(SCENE))
    sample_workspace(model, 16)                          # imports and caches warmed
    reference_now = [reference_solve_cpu_s(model)]

    print(f"1. acceptance: {n_accept} samples of {SCENE}", flush=True)
    serial, workspace = run_row(model, n_accept)
    parallel, _ = run_row(model, n_accept, workers=2)
    for row in (serial, parallel):
        print(f"   workers {row.get('workers', 1)}: wall {row['wall_s']:.2f} s, CPU {row['cpu_s']:.2f} s, "
              f"{row['samples_per_s_cpu']:.0f} samples/s (CPU), {row['iterations_mean']:.2f} iterations/solve, "
              f"{row['failures']} failures", flush=True)

    print(f"2. solve orders ({n_order} samples)", flush=True)
    actuations = sample_actuations(model, n_order, seed=7)
    orders = []
    for ordering in ("tree", "chain", "sampled"):
        row, _ = run_row(model, n_order, actuations=actuations, ordering=ordering)
        row.update(predictor=True)
        orders.append(row)
        orders.append(parent_equilibrium_baseline(model, actuations, ordering))
        for r in orders[-2:]:
            print(f"   {ordering:8s} predictor {str(r['predictor']):5s}: {r['iterations_mean']:.2f} iterations, "
                  f"{r['cpu_ms_per_sample']:.3f} ms CPU per sample", flush=True)

    print(f"3. Newton tolerance ({n_tol} samples)", flush=True)
    tolerances = tolerance_rows(model, n_tol)
    for r in tolerances:
        print(f"   tol {r['tolerance']:g}: {r['iterations_mean']:.2f} iterations, {r['cpu_ms_per_sample']:.3f} ms CPU, "
              f"max error {r['max_error_m']:.2e} m", flush=True)
    reference_now.append(reference_solve_cpu_s(model))
    load_end = os.getloadavg()
    quiet_s, quiet_load = quiet_reference_s()
    slowdown = float(np.mean(reference_now)) / quiet_s if quiet_s else None
    calibration = {"reference_solve_cpu_s": reference_now, "quiet_reference_cpu_s": quiet_s,
                   "quiet_reference_loadavg": quiet_load, "slowdown": slowdown,
                   "serial_cpu_s_on_quiet_machine": serial["cpu_s"] / slowdown if slowdown else None,
                   "two_workers_wall_s_on_quiet_machine": (parallel["cpu_s"] / slowdown / 2) if slowdown else None}
    print(f"   reference solve {1e3 * np.mean(reference_now):.3f} ms CPU now"
          + (f", {1e3 * quiet_s:.3f} ms at load {quiet_load[0]}: slowdown ×{slowdown:.2f}; serial run ≈ "
             f"{calibration['serial_cpu_s_on_quiet_machine']:.1f} s CPU on the quiet machine" if slowdown else ""))

    if args.picture:
        from vertebra.solver.workspace_plot import plot_workspace

        plot_workspace(workspace, args.picture, rest=model.effector_positions(model.rest_state),
                       title=f"paper_5v_16t: reachable workspace, {n_accept} Sobol samples of 16 tensions in 0–20 N")
    met = (serial["wall_s"] <= TARGET_S or parallel["wall_s"] <= TARGET_S) and not args.quick
    document = {"vertebra_version": __version__, "commit": commit(), "quick": args.quick,
                "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
                "host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
                "numpy": np.__version__, "load_average_start": load_start, "load_average_end": load_end,
                "target_s": TARGET_S, "acceptance": {"serial": serial, "two_workers": parallel, "met_wall": met},
                "calibration": calibration,
                "orders": orders, "tolerance": tolerances}
    render.write("workspace", document)
    verdict = "not measured (--quick)" if args.quick else ("met" if met else "NOT met")
    print(f"wrote {RESULTS / 'workspace.md'}; acceptance (10,000 samples, wall ≤ {TARGET_S:g} s): {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
