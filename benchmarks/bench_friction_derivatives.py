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
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    main()
