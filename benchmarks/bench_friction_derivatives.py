"""The μ columns of a calibration's Jacobian with tendon friction (docs/friction.md): forward mode
along the time-ordered samples against differences of the whole sequence, on the FTDCR v4 robot.

The example scene (``examples/calibration/ftdcr_v4/scene.toml``, nine stroke-driven tendons) with
``friction = --mu`` on every cable, the first ``--rows`` rows of the training file as one
sequence (each row from the state the row before left). For ``friction`` fitted as one μ shared by
the nine tendons (nine elements) and as ``friction.*`` (the same nine columns), the derivatives of
the markers by the nine μ are taken

* exactly (:meth:`SequencePredictor.predict`: ``friction.sequence_sensitivities``, one
  implicit-function solve per sample carrying the history's derivatives), and
* by forward differences of the whole sequence (the former path: one sequence per element),

interleaved ``--rounds`` times (the sequence itself solved once before, its equilibria kept).
Reported: the medians of the wall times, their ratio, the relative difference of the two
Jacobians, and the load.

Run: ``.venv/bin/python -m benchmarks.bench_friction_derivatives [--rows 60] [--rounds 3]``;
writes ``benchmarks/results/friction_derivatives.json``.

``--servo16``: the exact μ-derivatives of single equilibria
(``friction.equilibrium_sensitivities``) of the 16-tendon robot with stroke-driven tendons of
:mod:`benchmarks.bench_friction_tick` (``outside_6v_16t_servo``, μ = 0.15 on every tendon; the
short tendons ``t1``…``t4`` have one interior hole) against central differences of solves from
the same history (tolerance 1e-14) at steps h = 1e-2 … 1e-4, for a pull from rest, a pull on, a
release and a mixed change after a pull (random strokes, ``--seeds``). The differences are taken
twice: each ±h solve from where the command itself was solved from (``cold``: rest, or the pulled
state) and from the equilibrium at μ (``warm``), with the largest distance between the two
solves' tips. Per μ column: the difference relative to the column's largest derivative. Writes
``benchmarks/results/friction_derivatives_servo16.json``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json  # noqa: E402

DATA = ROOT / "examples" / "calibration" / "ftdcr_v4"
TRAIN = DATA / "tdcr_sysid_20260511-183002_train.csv"


def main(argv=None) -> None:
    from vertebra import __version__
    from vertebra.solver.calibration import parse_parameters
    from vertebra.solver.calibration.data import Samples, load_mapping, load_samples
    from vertebra.solver.calibration.sequence import SequencePredictor
    from vertebra.solver.scene import load_scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--mu", type=float, default=0.05)
    parser.add_argument("--out", default="friction_derivatives.json")
    parser.add_argument("--servo16", action="store_true", help="the step scan on the 16-tendon servo robot")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    args = parser.parse_args(argv)
    if args.servo16:
        servo16(args.seeds)
        return
    with tempfile.TemporaryDirectory() as tmp:
        scene_path = Path(tmp) / "scene.toml"
        text = (DATA / "scene.toml").read_text()
        scene_path.write_text(text.replace("\n[[cable]]\n", f"\n[[cable]]\nfriction = {args.mu!r}\n"))
        scene = load_scene(scene_path)
    mapping = load_mapping(DATA / "map.toml")
    full = load_samples(TRAIN, mapping)
    n = min(args.rows, len(full))
    samples = Samples(full.commands[:n], full.markers[:n], full.patterns[:n], full.source, full.rows[:n])
    predictor = SequencePredictor(scene, mapping)
    ps = parse_parameters(["friction"], scene, mapping, predictor.model)
    values = ps.values([args.mu])
    elements = list(ps.elements[0])
    t0 = time.perf_counter()
    predictor.predict(values, samples)
    sequence_s = time.perf_counter() - t0
    log(f"{n} rows, {len(elements)} μ elements: the sequence solved in {sequence_s:.1f} s")
    times = {"exact": [], "differences": []}
    results = {}
    exact_path = predictor._friction_derivatives
    for _ in range(args.rounds):
        for label in ("exact", "differences"):
            predictor._friction_derivatives = exact_path if label == "exact" else (lambda *a, **k: {})
            t1 = time.perf_counter()
            results[label] = predictor.predict(values, samples, elements).derivatives
            times[label].append(time.perf_counter() - t1)
            log(f"{label}: {times[label][-1]:.2f} s")
    predictor._friction_derivatives = exact_path
    exact, diff = results["exact"], results["differences"]
    relative = float(np.abs(exact - diff).max() / np.abs(diff).max())
    median = {k: float(np.median(v)) for k, v in times.items()}
    out = {"benchmark": "friction_derivatives", "vertebra_version": __version__, "date": now(),
           "loadavg": loadavg(), "rows": n, "mu": args.mu, "elements": len(elements), "rounds": args.rounds,
           "sequence_s": sequence_s, "seconds": times, "median_s": median,
           "speedup": median["differences"] / median["exact"],
           "relative_difference_exact_vs_forward_differences": relative}
    log(f"median exact {median['exact']:.2f} s, differences {median['differences']:.2f} s: "
        f"{out['speedup']:.1f}x; Jacobians differ by {relative:.2e} of the largest")
    write_json(out, RESULTS / args.out)



STEPS = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4)


def servo16(seeds, mu: float = 0.15) -> None:
    """The step scan of ``--servo16`` (module docstring)."""
    from benchmarks.bench_friction_tick import robot
    from vertebra import __version__
    from vertebra.solver import friction

    model = robot("outside_6v_16t_servo", mu)
    n = model.n_cables
    rest = friction.FrictionState.rest(model.trunk)

    def tip(result):
        return model.effector_positions(result.state).reshape(-1)

    def solve(command, history, initial, column=None, value=mu):
        model.set_parameters(friction=np.where(np.arange(n) == column, value, mu))
        return model.solve(command, history=history, initial=initial, tolerance=1e-14)

    cases = []
    load_before = loadavg()
    for seed in seeds:
        rng = np.random.default_rng(seed)
        first = rng.uniform(-0.001, 0.003, n)
        pulled = solve(first, rest, None)
        for kind, command, history, start in (
                ("pull from rest", first, rest, None),
                ("pull on", first + 0.0005, pulled.friction, pulled.state),
                ("release", 0.6 * first - 0.0003, pulled.friction, pulled.state),
                ("mixed", first + rng.uniform(-0.001, 0.001, n), pulled.friction, pulled.state)):
            result = solve(command, history, start)
            exact = friction.equilibrium_sensitivities(model, result, history)["effector_positions"]
            largest = np.abs(exact).max(0)
            entry = {"seed": seed, "case": kind, "converged": bool(result.converged),
                     "column_largest": largest.tolist()}
            for label, initial in (("cold", start), ("warm", result.state)):
                errors, offset = {}, {}
                for h in STEPS:
                    columns, moved = [], []
                    for c in range(n):
                        above = solve(command, history, initial, c, mu + h)
                        below = solve(command, history, initial, c, mu - h)
                        columns.append((tip(above) - tip(below)) / (2 * h))
                        if label == "warm":       # how far the warm solves land from the cold ones
                            cold = [solve(command, history, start, c, mu + s * h) for s in (1, -1)]
                            moved.append(max(float(np.abs(tip(above) - tip(cold[0])).max()),
                                             float(np.abs(tip(below) - tip(cold[1])).max())))
                    difference = np.abs(exact - np.stack(columns, 1)).max(0)
                    errors[str(h)] = [float(e / l) if l > 0 else 0.0 for e, l in zip(difference, largest)]
                    if moved:
                        offset[str(h)] = moved
                entry[label] = {"relative_error": errors,
                                "best": [min(errors[str(h)][c] for h in STEPS) for c in range(n)]}
                if offset:
                    entry[label]["tip_offset_from_cold_m"] = offset
                log(f"seed {seed}, {kind}, differences from the {label} start ({'the equilibrium itself' if label == 'warm' else 'where the command was solved from'}):")
                for h in STEPS:
                    log(f"   h={h:g}: " + " ".join(f"{e:.0e}" for e in errors[str(h)]))
                if offset:
                    log("   largest |tip(warm) - tip(cold)| per h: " + ", ".join(
                        f"{h:g}: {max(offset[str(h)]):.1e} m" for h in STEPS))
            model.set_parameters(friction=np.full(n, mu))
            cases.append(entry)
    out = {"benchmark": "friction_derivatives_servo16", "vertebra_version": __version__, "date": now(),
           "loadavg_before": load_before, "loadavg_after": loadavg(), "mu": mu, "steps": list(STEPS),
           "cases": cases}
    write_json(out, RESULTS / "friction_derivatives_servo16.json")


if __name__ == "__main__":
    main()
