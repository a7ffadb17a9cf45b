"""Sensitivities of many equilibria: ``batch_sensitivities`` (batched factors, the explicit terms
over a sample axis) against ``model.sensitivities`` state by state, interleaved in one process:

    python -m benchmarks.bench_sensitivities [--samples 300] [--rounds 3]

Robots: the calibration example (nine stroke-driven tendons, the parameters its fit asks for:
stiffness scales, spring rates, pretensions, hole angles, strokes), the 16-tendon gallery robot
(tensions, holes, a tip load) and a two-section tendon robot. For each, B equilibria of random
commands; per round the single route then the batch (CPU time of the process), and the largest
difference of ``dq`` relative to each column's largest. Writes
benchmarks/results/sensitivities_batch.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import vertebra
from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json
from vertebra import solver
from vertebra.solver.scene import load_scene
from vertebra.solver.sensitivity import batch_sensitivities

CASES = {
    "ftdcr_v4": (str(ROOT / "examples" / "calibration" / "ftdcr_v4" / "scene.toml"), (-0.001, 0.003),
                 ("stiffness_scale:1", "stiffness_scale:2", "cable_stiffness", "pretension", "hole_angle",
                  "actuation")),
    "paper_5v_16t": ("gallery:paper_5v_16t", (0.0, 4.0), ("actuation", "hole_angle", "hole_radius", "dead:-1")),
    "tendon_two_section": ("gallery:tendon_two_section", (0.0, 3.0),
                           ("actuation", "hole_angle", "hole_radius", "stiffness_scale")),
}


def case(name: str, samples: int, rounds: int, seed: int = 0) -> dict:
    source, (low, high), wrt = CASES[name]
    model = solver.build_model(load_scene(source))
    rng = np.random.default_rng(seed)
    actuations = rng.uniform(low, high, (samples, model.n_cables))
    results = [model.solve(a) for a in actuations]
    keep = [i for i, r in enumerate(results) if r.converged and r.state.carried_strains() is not None]
    results = [results[i] for i in keep]
    actuations = actuations[keep]
    strains = np.stack([r.state.carried_strains().xi for r in results])
    serial_s, batch_s = [], []
    for _ in range(rounds):
        t = time.process_time()
        single = [model.sensitivities(r, wrt=wrt, outputs=(), method="direct").dq for r in results]
        serial_s.append(time.process_time() - t)
        t = time.process_time()
        batch = batch_sensitivities(model, strains, actuations, wrt=wrt, outputs=(), method="direct")
        batch_s.append(time.process_time() - t)
    single = np.stack(single)
    largest = np.abs(single).max(1, keepdims=True)
    difference = np.abs(batch.dq - single) / np.where(largest > 0, largest, 1.0)
    entry = {"samples": len(results), "parameters": len(batch.parameters), "n_dof": model.n_dof,
             "serial_s": serial_s, "batch_s": batch_s,
             "serial_ms_per_sample": 1e3 * float(np.median(serial_s)) / len(results),
             "batch_ms_per_sample": 1e3 * float(np.median(batch_s)) / len(results),
             "ratio": float(np.median(np.array(batch_s) / np.array(serial_s))),
             "single_samples": int(batch.single.sum()), "dq_difference_rel": float(difference.max())}
    log(f"{name}: {entry['samples']} samples, {entry['parameters']} parameters: serial "
        f"{entry['serial_ms_per_sample']:.3f} ms, batch {entry['batch_ms_per_sample']:.3f} ms per sample "
        f"({entry['ratio']:.3f}x), dq differs by {entry['dq_difference_rel']:.2e}")
    return entry


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    document = {"vertebra_version": vertebra.__version__, "date": now(), "loadavg_before": loadavg(),
                "samples": args.samples, "rounds": args.rounds, "cases": {}}
    for name in CASES:
        document["cases"][name] = case(name, args.samples, args.rounds)
    document["loadavg_after"] = loadavg()
    write_json(document, RESULTS / "sensitivities_batch.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
