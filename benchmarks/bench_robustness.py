"""Robustness of the runtime at the extremes, on robots the gallery does not contain.

Sections (each a table in ``results/robustness.md`` and a key in ``results/robustness.json``):

1. ``forward``      200 seeded random tendon robots (``tests/robots.py``: 1–8 vertebrae, 2–4 links
                    per segment, E 1 MPa–100 GPa, cables at 3–20 mm within their bounds, optional
                    gravity and tip loads up to PL²/EI = 10) whose equilibrium the independent
                    check calls representable, each solved from rest in one load step: convergence
                    rate, iterations, CPU time per solve, agreement with the refined reference;
                    and every draw (representable or not): how the solves that fail fail, how fast.
2. ``polymer_tick`` the gallery robot ``polymer_5v_16t`` in tick mode, with and without gravity, on
                    a 3 cm circle at z = 0.14 m (60 and 200 points) and a jump to (0.04, 0.02,
                    0.13) m: every tick settled to an equilibrium; the largest error after 10
                    ticks, bounds, per-tick changes, tick CPU time (median, 90th percentile).
3. ``polymer_converged`` the same targets in converged mode: error and CPU time per target.
4. ``control``      random robots of a control experiment's size (``robots.control_robot``) in tick
                    mode on a reachable circle and a 3–5 cm jump, and in converged mode on the jump.
5. ``extremes``     E 1 kPa–200 GPa × length 1 mm–1 m, 1–10,000 frames, coils to 2.5 turns,
                    tensions at their bounds, tiny and huge loads, and deformations a link cannot
                    represent: converged or the reason, iterations, time.

Times are CPU time of the thread (the machine is shared). Run:
``OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_robustness [--quick]`` (``--quick``: a
smoke run into a temporary directory).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS  # noqa: E402
from tests import robots  # noqa: E402

from vertebra import solver  # noqa: E402
from vertebra.solver.gallery import load  # noqa: E402
from vertebra.solver.gallery.targets import circle  # noqa: E402
from vertebra.solver.inverse import InverseController, InverseSettings  # noqa: E402
from vertebra.solver.newton import is_stable  # noqa: E402
from vertebra.core.errors import ConvergenceError  # noqa: E402

JUMP = np.array([[0.04, 0.02, 0.13]])


def cpu(fn):
    """(result or the exception raised, CPU seconds of this thread)."""
    start = time.thread_time()
    try:
        out = fn()
    except ConvergenceError as error:
        out = error
    return out, time.thread_time() - start


def stats(values) -> dict:
    values = np.asarray(values, float)
    if not values.size:
        return {}
    return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90)), "max": float(values.max())}


def build(scene):
    return solver.build_model(scene if isinstance(scene, solver.Scene) else solver.parse_scene(scene))


# --------------------------------------------------------------------------- 1. forward
def bench_forward(n_seeds: int) -> dict:
    rows, draws_all = [], []
    for seed in range(n_seeds):
        rng = np.random.default_rng(seed)
        scene, check, draws = robots.draw_representable(rng)
        model = build(scene)
        result, seconds = cpu(lambda: model.solve(raise_on_failure=False))
        row = {"seed": seed, "draws": draws, "converged": bool(result.converged), "iterations": int(result.iterations),
               "cpu_s": seconds, "largest_turn_deg": math.degrees(check.largest_turn),
               "total_turns": check.total_turn / (2 * math.pi), "shortest_piece": check.shortest_piece,
               "message": result.message}
        if result.converged:
            row["stable"] = bool(is_stable(model.trunk, model.evaluate(result.state)))
            row["tip_vs_reference"] = float(np.linalg.norm(result.state.positions[-1] - check.tip) / model.length_scale)
        rows.append(row)
        print(f"  forward seed {seed}: {'ok' if row['converged'] else 'FAILED'} {row['iterations']} it "
              f"{seconds * 1e3:.1f} ms", flush=True)
    for seed in range(n_seeds):                 # every draw, representable or not
        scene = robots.tendon_robot(np.random.default_rng(10_000 + seed))
        check = robots.representable(scene)
        model = build(scene)
        result, seconds = cpu(lambda: model.solve(raise_on_failure=False))
        draws_all.append({"seed": 10_000 + seed, "representable": check.ok, "reference_converged": check.converged,
                          "converged": bool(result.converged), "iterations": int(result.iterations), "cpu_s": seconds,
                          "reason": _reason(result.message)})
    ok = [r for r in rows if r["converged"]]
    agree = [r for r in ok if r["tip_vs_reference"] <= 1e-2]
    failures = [d for d in draws_all if not d["converged"]]
    return {"seeds": n_seeds, "converged": len(ok), "stable": sum(r.get("stable", False) for r in ok),
            "iterations": stats([r["iterations"] for r in rows]), "cpu_s": stats([r["cpu_s"] for r in ok]),
            "draws_per_robot": float(np.mean([r["draws"] for r in rows])),
            "tip_within_1pct_of_reference": len(agree),
            "tip_vs_reference": stats([r["tip_vs_reference"] for r in ok]), "rows": rows,
            "all_draws": {"count": len(draws_all), "converged": len(draws_all) - len(failures),
                          "representable": sum(d["representable"] for d in draws_all),
                          "failed_representable": sum(d["representable"] for d in failures),
                          "failure_reasons": {reason: sum(d["reason"] == reason for d in failures)
                                              for reason in sorted({d["reason"] for d in failures})},
                          "failure_cpu_s": stats([d["cpu_s"] for d in failures]),
                          "converged_cpu_s": stats([d["cpu_s"] for d in draws_all if d["converged"]]),
                          "rows": draws_all}}


def _reason(message: str) -> str:
    if not message:
        return ""
    for key, reason in (("holes of the two vertebrae meet", "cable holes meet"), ("turns", "link towards π"),
                        ("folds through itself", "link folds"), ("non-finite", "non-finite")):
        if key in message:
            return reason
    return "did not converge"


# --------------------------------------------------------------------------- 2–3. the polymer robot
def polymer(gravity: bool):
    scene = load("polymer_5v_16t")
    return build(scene if gravity else dataclasses.replace(scene, gravity=None))


def trajectories(n_points):
    return {f"circle_{n}": circle([0.0, 0.0, 0.14], 0.03, n)[:, None] for n in n_points} | \
        {"jump": np.repeat(JUMP[None], 30, axis=0)}


def run_ticks(model, trajectory) -> dict:
    controller = InverseController(model, InverseSettings(mode="tick"))
    lower, upper = model.actuator_bounds
    change = model.actuator_max_change
    errors, times, equilibria, bounds, changes, statuses = [], [], 0, 0, 0, {}
    # the control loop runs alone (as on a robot: nothing solves between its ticks); every tick
    # is settled to the equilibrium its actuation reaches afterwards, to check it
    run = []
    for target in trajectory:
        previous = controller.actuation
        step, seconds = cpu(lambda: controller.step(target))
        times.append(seconds)
        run.append((previous, step))
    for previous, step in run:
        statuses[step.status] = statuses.get(step.status, 0) + 1
        bounds += int(np.any(step.actuation < lower) or np.any(step.actuation > upper))
        changes += int(np.any(np.abs(step.actuation - previous) > change * (1 + 1e-12)))
        settled = controller.settled(step)
        equilibria += int(settled.equilibrium)
        errors.append(float(settled.errors.max()))
    errors = np.array(errors)
    return {"ticks": len(trajectory), "equilibria": equilibria, "bound_violations": bounds,
            "change_violations": changes, "error_first_10_m": errors[:10].tolist(),
            "max_error_after_10_m": float(errors[10:].max()), "tick_cpu_s": stats(times), "statuses": statuses}


def bench_polymer_tick(n_points) -> list:
    rows = []
    for gravity in (True, False):
        model = polymer(gravity)
        for name, trajectory in trajectories(n_points).items():
            row = dict(gravity=gravity, trajectory=name, **run_ticks(model, trajectory))
            rows.append(row)
            print(f"  polymer tick gravity={gravity} {name}: max error after 10 ticks "
                  f"{row['max_error_after_10_m'] * 1e3:.3f} mm, tick median {row['tick_cpu_s']['median'] * 1e3:.3f} ms",
                  flush=True)
    return rows


def bench_polymer_converged(n_points) -> list:
    rows = []
    for gravity in (True, False):
        model = polymer(gravity)
        for name, trajectory in trajectories(n_points).items():
            trajectory = trajectory[:1] if name == "jump" else trajectory
            controller = InverseController(model, InverseSettings(mode="converged"))
            errors, times, reached, iterations = [], [], 0, []
            for target in trajectory:
                step, seconds = cpu(lambda: controller.step(target))
                times.append(seconds)
                errors.append(float(step.errors.max()))
                reached += int(step.reached)
                iterations.append(step.iterations)
            rows.append({"gravity": gravity, "trajectory": name, "targets": len(trajectory), "reached": reached,
                         "max_error_m": max(errors), "cpu_s": stats(times), "iterations": stats(iterations)})
            print(f"  polymer converged gravity={gravity} {name}: {reached}/{len(trajectory)} reached, "
                  f"max {max(times) * 1e3:.1f} ms", flush=True)
    return rows


# --------------------------------------------------------------------------- 4. control robots
def bench_control(n_seeds: int) -> list:
    rows = []
    for seed in range(n_seeds):
        rng = np.random.default_rng(seed)
        gravity = seed % 2 == 0
        scene = robots.control_robot(rng, gravity=gravity)
        model = build(scene)
        reach = min(0.03, 0.3 * model.length_scale)
        distance = min(float(rng.uniform(0.03, 0.05)), 0.4 * model.length_scale)
        loop = robots.reachable_circle(model, scene, reach, 60)
        target, _ = robots.reachable_target(model, scene, rng, distance)
        row = {"seed": seed, "gravity": gravity, "vertebrae": model.scene.segments[0].count,
               "length_m": model.length_scale, "tendons": model.n_cables, "jump_m": distance,
               "circle": run_ticks(model, loop), "jump_tick": run_ticks(model, np.repeat(target[None], 30, axis=0))}
        step, seconds = cpu(lambda: InverseController(model, InverseSettings(mode="converged")).step(target))
        row["jump_converged"] = {"reached": bool(step.reached), "error_m": float(step.errors.max()),
                                 "cpu_s": seconds, "iterations": int(step.iterations), "status": step.status}
        rows.append(row)
        print(f"  control seed {seed}: circle {row['circle']['max_error_after_10_m'] * 1e3:.3f} mm, jump tick "
              f"{row['jump_tick']['max_error_after_10_m'] * 1e3:.3f} mm, converged {step.status} "
              f"{seconds * 1e3:.0f} ms", flush=True)
    return rows


# --------------------------------------------------------------------------- 5. extremes
def rod(links, length, youngs, radius, force=(0, 0, 0), moment=(0, 0, 0)):
    return build({"segment": [{"type": "beam", "elements": links, "length": length, "youngs_modulus": youngs,
                               "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": radius}}],
                  "load": [{"vertebra": -1, "force": list(force), "moment": list(moment)}]})


def outcome(case: str, model, **solve) -> dict:
    result, seconds = cpu(lambda: model.solve(**solve))
    if isinstance(result, ConvergenceError):
        return {"case": case, "converged": False, "iterations": int(result.result.iterations), "cpu_s": seconds,
                "reason": str(result)}
    return {"case": case, "converged": True, "iterations": int(result.iterations), "cpu_s": seconds,
            "largest_turn_deg": math.degrees(result.largest_turn), "rounding_limited": bool(result.rounding_limited)}


def bench_extremes(quick: bool) -> list:
    rows = []
    for youngs in (1e3, 1e6, 1e9, 2e11):
        for length in (1e-3, 1.0):
            radius = length / 100
            EI = youngs * math.pi * radius ** 4 / 4
            rows.append(outcome(f"E {youngs:.0e} Pa, L {length:g} m, PL²/EI = 10", rod(
                20, length, youngs, radius, force=(10 * EI / length ** 2, 0, 0))))
    EI = 200e9 * math.pi * 1e-12 / 4
    for links in ((1, 100, 1000) if quick else (1, 10, 100, 1000, 10_000)):
        rows.append(outcome(f"{links + 1} frames, PL²/EI = 1", rod(links, 0.5, 200e9, 1e-3, force=(EI / 0.25, 0, 0))))
    for turns in (1.0, 1.5, 2.2, 2.5):
        rows.append(outcome(f"coil of {turns} turns, 80 links", rod(80, 0.5, 200e9, 1e-3,
                                                                    moment=(0, 2 * math.pi * turns * EI / 0.5, 0))))
    for load, name in ((1e-15, "tiny tip force 1e-15 N"), (1e6, "huge tip force 1 MN (crushes)")):
        rows.append(outcome(name, rod(10, 0.5, 200e9, 1e-3, force=(0, 0, -load))))
    rows.append(outcome("20 links asked to coil 15 turns", rod(20, 0.5, 200e9, 1e-3,
                                                                moment=(0, 30 * math.pi * EI / 0.5, 0))))
    for seed in range(3 if quick else 10):
        rng = np.random.default_rng(500 + seed)
        scene, _, _ = robots.draw_representable(rng)
        for cable in scene["cable"]:
            cable["tension"] = cable["max_tension"]
        rows.append(outcome(f"random robot {500 + seed}, every tension raised to its bound (unchecked)", build(scene)))
    polymer_model = polymer(True)
    rows.append(outcome("polymer_5v_16t, one tendon at 30 N", polymer_model,
                        actuation=np.r_[30.0, np.zeros(15)], raise_on_failure=True))
    for row in rows:
        print(f"  {row['case']}: {'converged' if row['converged'] else 'raised'} {row['iterations']} it "
              f"{row['cpu_s'] * 1e3:.1f} ms {row.get('reason', '')[:100]}", flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run into a temporary directory")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.out or (Path(tempfile.mkdtemp(prefix="bench_robustness_")) if args.quick else RESULTS)
    points = (60,) if args.quick else (60, 200)
    res = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "host": platform.node(),
           "loadavg": [round(v, 2) for v in os.getloadavg()]}
    res["forward"] = bench_forward(10 if args.quick else 200)
    res["polymer_tick"] = bench_polymer_tick(points)
    res["polymer_converged"] = bench_polymer_converged(points)
    res["control"] = bench_control(3 if args.quick else 20)
    res["extremes"] = bench_extremes(args.quick)
    res["loadavg_end"] = [round(v, 2) for v in os.getloadavg()]
    name = "robustness-quick" if args.quick else "robustness"
    render.write("robustness", res, out, stem=name)
    print(f"wrote {out / name}.md/.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
