"""Tracking of the inverse tick (real-time mode) with tendon friction (docs/friction.md).

Robots: the two 16-tendon robots of :mod:`benchmarks.bench_tick` (``paper_5v_16t`` from the gallery,
``outside_6v_16t`` outside it), every cable given the same friction coefficient ``μ``; with
``--robots outside_6v_16t_servo`` the outside robot with stroke-driven tendons (:data:`SERVO`:
k = 2000 N/m, pretension 1 N, strokes −1 … 3 mm, starting at 0.3 mm).

Protocol (bench_tick's loop): from the equilibrium under 0.3 N on every tendon (with friction: a
monotone pull from rest), each tick from the state and actuation the last one left, the targets
on a 1 mm circle around the effectors there (one turn per 100 ticks), ``--ticks`` ticks. The
*plant* is the frictional robot driven by the controller's commands: after every tick it solves
the tick's actuation from its own last equilibrium and friction state (``model.solve(λ,
history=…)``, the sequence of commands one after the other). Reported per robot and μ: the
largest and median distance of the plant's effectors from the tick's targets over the ticks
after the first turn (``tracking``), the largest over all ticks, the violations of the actuator
bounds and of the per-tick change limits, the ticks not applied or cut back, the holes found
stuck on the plant, and the median CPU time of a tick (thread time; the machine is shared, see
``load_average``).

Run: ``.venv/bin/python -m benchmarks.bench_friction_tick [--ticks 200] [--mu 0 0.1 0.2]``;
writes ``benchmarks/results/friction_tick.json`` (``--out`` to name another file).
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


SERVO = {"stroke": 0.0, "stiffness": 2000.0, "pretension": 1.0, "min_stroke": -0.001, "max_stroke": 0.003}
START = {"outside_6v_16t_servo": 0.0003}     # the start command on every tendon (default 0.3 N)


def robot(name: str, mu: float):
    from benchmarks.bench_tick import OUTSIDE
    from benchmarks.bench_tick import robot as tick_robot
    from vertebra import solver

    if name == "outside_6v_16t_servo":        # the outside robot with stroke-driven tendons (SERVO)
        drive = ("tension", "min_tension", "max_tension")
        scene = dict(OUTSIDE, cable=[{**{k: v for k, v in c.items() if k not in drive}, **SERVO}
                                     for c in OUTSIDE["cable"]])
        model = solver.build_model(solver.parse_scene(scene))
    else:
        model = tick_robot(name)
    if mu:
        model.set_parameters(friction=np.full(model.n_cables, mu))
    return model


def run(name: str, mu: float, ticks: int) -> dict:
    from vertebra.solver.friction import routes
    from vertebra.solver.inverse import InverseController, InverseSettings

    model = robot(name, mu)
    lower, upper = model.actuator_bounds
    change = model.actuator_max_change
    lam = np.clip(np.full(len(model.actuator_names), START.get(name, 0.3)), lower, upper)
    start = model.solve(lam)
    # (a controller that does not carry a friction state — as before the frictional tick — gets none)
    carries = "history" in inspect.signature(InverseController).parameters
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=start.state,
                                   **({"history": start.friction} if carries else {}))
    interior = routes(model.trunk.cables).previous >= 0
    centre = model.effector_positions(start.state)
    plant_state, plant_history = start.state, start.friction
    errors, times, statuses, stuck = [], [], {}, 0
    bounds = changes = 0
    for k in range(ticks):
        angle = 2 * np.pi * k / 100
        target = centre + 1e-3 * np.array([np.cos(angle), np.sin(angle), 0.0])
        previous = controller.actuation
        t0 = time.thread_time()
        step = controller.step(target)
        times.append(time.thread_time() - t0)
        statuses[step.status] = statuses.get(step.status, 0) + 1
        bounds += int(np.any(step.actuation < lower) or np.any(step.actuation > upper))
        changes += int(np.any(np.abs(step.actuation - previous) > change * (1 + 1e-12)))
        solved = model.solve(step.actuation, initial=plant_state, history=plant_history) if mu else \
            model.solve(step.actuation, initial=plant_state)
        plant_state, plant_history = solved.state, solved.friction
        if plant_history is not None:
            stuck += int(np.count_nonzero(plant_history.slip[interior] == 0))
        errors.append(float(np.max(np.linalg.norm(model.effector_positions(plant_state) - target, axis=1))))
    errors = np.array(errors)
    after = errors[100:] if ticks > 100 else errors
    return {"robot": name, "mu": mu, "ticks": ticks, "tracking_max_m": float(after.max()),
            "tracking_median_m": float(np.median(after)), "max_error_m": float(errors.max()),
            "bound_violations": bounds, "change_violations": changes, "statuses": statuses,
            "stuck_hole_ticks": stuck, "tick_median_s": float(np.median(times)), "tick_p90_s": float(np.percentile(times, 90))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=200)
    parser.add_argument("--mu", type=float, nargs="+", default=[0.0, 0.1, 0.2])
    parser.add_argument("--robots", nargs="+", default=["paper_5v_16t", "outside_6v_16t"])
    parser.add_argument("--out", default="friction_tick.json")
    args = parser.parse_args(argv)
    rows, loads = [], []
    for name in args.robots:
        for mu in args.mu:
            row = run(name, mu, args.ticks)
            loads.append(os.getloadavg()[0])
            rows.append(row)
            print(f"{name} μ={mu}: tracking max {row['tracking_max_m']:.3g} m, median {row['tracking_median_m']:.3g} m "
                  f"(all ticks max {row['max_error_m']:.3g} m); violations bounds {row['bound_violations']}, "
                  f"per-tick {row['change_violations']}; statuses {row['statuses']}; stuck hole-ticks "
                  f"{row['stuck_hole_ticks']}; tick {row['tick_median_s'] * 1e3:.2f} ms", flush=True)
    import vertebra

    document = {"package": str(Path(vertebra.__file__).parent), "ticks": args.ticks,
                "host": f"{platform.node()} · {platform.machine()} · python {platform.python_version()} · "
                        f"{os.cpu_count()} cores",
                "load_average": {"min": min(loads), "median": float(np.median(loads)), "max": max(loads)},
                "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / args.out).write_text(json.dumps(document, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
