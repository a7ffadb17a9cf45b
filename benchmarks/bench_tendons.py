"""Stroke-driven tendons and run-time parameters on the paper's 16-tendon robot: do random servo
commands (slack and taut mixed) all converge, and what does a warm solve cost when the loads
(dead, gravity, follower) or parameters change instead of the actuation?

    python -m benchmarks.bench_tendons [--samples 200] [--rounds 7]

Writes benchmarks/results/tendons.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from benchmarks.common import RESULTS, loadavg, log, now, write_json
from vertebra import __version__, solver
from vertebra.solver.gallery import load

WIRE_EA = 200e9 * math.pi * 0.00015 ** 2       # a 0.3 mm steel wire
FREE_LENGTH = 0.2                               # m of tendon between the servo and the base


def tendon_robot():
    """paper_5v_16t with every cable a stroke-driven steel-wire tendon, 0.5 N pretension."""
    scene = load("paper_5v_16t")
    cables = tuple(dataclasses.replace(c, stroke=0.0, axial_stiffness=WIRE_EA, free_length=FREE_LENGTH,
                                       pretension=0.5, min_stroke=-0.002, max_stroke=0.002,
                                       min_tension=0.0, max_tension=math.inf, max_tension_change=None)
                   for c in scene.cables)
    return solver.build_model(dataclasses.replace(scene, cables=cables))


def random_commands(model, samples: int, seed: int = 0) -> dict:
    """Solves from rest of ``samples`` random servo strokes in ±0.5 mm (tensions 0 to ~25 N)."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(samples):
        strokes = rng.uniform(-0.0005, 0.0005, model.n_cables)
        start = time.perf_counter()
        result = model.solve(strokes, raise_on_failure=False)
        elapsed = time.perf_counter() - start
        tensions = model.cable_tensions(result.state, strokes)
        rows.append({"converged": bool(result.converged), "iterations": int(result.iterations),
                     "residual": float(result.residual), "time_s": elapsed,
                     "slack": int((tensions == 0.0).sum()), "max_tension": float(tensions.max())})
    return {"samples": samples, "failures": sum(not r["converged"] for r in rows),
            "iterations_median": float(np.median([r["iterations"] for r in rows])),
            "iterations_max": max(r["iterations"] for r in rows),
            "time_median_s": float(np.median([r["time_s"] for r in rows])),
            "slack_tendons_per_sample_mean": float(np.mean([r["slack"] for r in rows])),
            "max_tension_N": max(r["max_tension"] for r in rows)}


def warm_solves(model, rounds: int, per_round: int = 200) -> dict:
    """Warm solves from one equilibrium, interleaved per round: a changed actuation, then changed
    loads (a dead force at the tip and gravity), a changed follower load at the tip (force and
    moment in its axes), parameters (pretension, stiffness scale), and — to tell the follower's
    banded LU from its change — a changed actuation under a fixed follower load."""
    base = model.parameters
    start = model.solve(np.full(model.n_cables, 0.0002))
    rng = np.random.default_rng(1)
    tip = int(model.vertebra_frames[-1])

    def actuation_change():
        model.solve(np.full(model.n_cables, 0.0002) + rng.uniform(-1e-5, 1e-5, model.n_cables), initial=start.state)

    def load_change():
        dead = np.array(base.dead)
        dead[tip, :3] = rng.uniform(-0.05, 0.05, 3)
        model.set_parameters(base, dead=dead, gravity=[0.0, rng.uniform(-0.5, 0.5), -9.81])
        model.solve(np.full(model.n_cables, 0.0002), initial=start.state)

    def follower_wrench():
        return np.r_[rng.uniform(-0.05, 0.05, 3), rng.uniform(-0.002, 0.002, 3)]

    def follower_change():
        model.set_parameters(base, follower={-1: follower_wrench()})
        model.solve(np.full(model.n_cables, 0.0002), initial=start.state)

    fixed_follower = model.with_parameters(base, follower={-1: [0.02, -0.02, 0.03, 0.001, 0.0, 0.001]})

    def actuation_change_under_a_follower():
        model.set_parameters(fixed_follower)
        model.solve(np.full(model.n_cables, 0.0002) + rng.uniform(-1e-5, 1e-5, model.n_cables), initial=start.state)

    def parameter_change():
        model.set_parameters(base, pretension=np.where(model.trunk.actuators.stroke_driven,
                                                       0.5 + rng.uniform(-0.05, 0.05), 0.0),
                             stiffness_scale=[1.0 + rng.uniform(-0.05, 0.05)])
        model.solve(np.full(model.n_cables, 0.0002), initial=start.state)

    cases = {"actuation": actuation_change, "loads": load_change, "follower": follower_change,
             "parameters": parameter_change, "actuation_under_follower": actuation_change_under_a_follower}
    medians = {name: [] for name in cases}
    for _ in range(rounds):
        for name, case in cases.items():
            times = []
            for _ in range(per_round):
                t0 = time.thread_time()
                case()
                times.append(time.thread_time() - t0)
            medians[name].append(float(np.median(times)))
        model.set_parameters(base)
    ratios = {name: [m / a for m, a in zip(medians[name], medians["actuation"])]
              for name in ("loads", "follower", "parameters", "actuation_under_follower")}
    ratios["follower_vs_actuation_under_follower"] = [
        f / a for f, a in zip(medians["follower"], medians["actuation_under_follower"])]
    return {"rounds": rounds, "per_round": per_round,
            "median_s": {name: float(np.median(v)) for name, v in medians.items()},
            "ratio_to_actuation_median": {name: float(np.median(v)) for name, v in ratios.items()},
            "ratio_range": {name: [float(min(v)), float(max(v))] for name, v in ratios.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args(argv)
    model = tendon_robot()
    log(f"{args.samples} random servo commands …")
    commands = random_commands(model, args.samples)
    log(f"  failures {commands['failures']}, iterations median {commands['iterations_median']}")
    log("warm solves: actuation vs loads vs parameters, interleaved …")
    warm = warm_solves(model, args.rounds)
    log(f"  medians {warm['median_s']}; ratios {warm['ratio_to_actuation_median']}")
    document = {"vertebra_version": __version__, "date": now(), "loadavg": loadavg(),
                "robot": "paper_5v_16t, 16 stroke-driven 0.3 mm steel tendons (EA/(L + 0.2 m)), 0.5 N pretension",
                "random_commands": commands, "warm_solves": warm}
    write_json(document, RESULTS / "tendons.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
