"""Tendon friction on the FTDCR v4 data (docs/friction.md, docs/calibration.md): does a fitted
friction coefficient lower the held-out error of the calibrated robot, and how much of the
measured pull/release gaps does it explain?

    python -m benchmarks.bench_friction_v4 --calibrated v4.toml --document v4.json [--max-samples N]

``v4.toml`` and ``v4.json`` are the frictionless calibration's scene and JSON document
(``vertebra calibrate … --output v4.toml --save-json v4.json``, docs/calibration.md). With every
other parameter kept at its frictionless fit, one friction coefficient shared by the nine tendons
is fitted by ``vertebra calibrate``'s driver (``--fit friction``: the samples predicted as one
time-ordered sequence, each row from the state the row before left) on the training file
(``--max-samples`` evenly spaced rows of it: a coarser sequence), then both files are predicted
as sequences with μ = 0 and the fitted μ.

Pull/release gaps: within a run of rows of one pattern, two rows at least three apart whose
servo commands all agree within 0.08 mm — the same command reached on the way out and on the
way back. The measured gap is the difference of the two markers; a model without memory
predicts none. Explained share: ``1 − Σ|gap_measured − gap_predicted|² / Σ|gap_measured|²``.

Writes benchmarks/results/friction_v4.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json
from vertebra import __version__
from vertebra.solver.calibration import calibrate
from vertebra.solver.calibration.data import load_mapping, load_samples
from vertebra.solver.calibration.fit import error_metrics
from vertebra.solver.calibration.sequence import SequencePredictor
from vertebra.solver.scene import load_scene

DATA = ROOT / "examples" / "calibration" / "ftdcr_v4"
TRAIN = DATA / "tdcr_sysid_20260511-183002_train.csv"
HOLDOUT = DATA / "tdcr_sysid_20260511-183002_val.csv"
SAME_COMMAND = 0.08e-3      # m: every servo within this on both rows of a pair


def derived_mapping(document: dict, max_samples: int | None, fit=("friction",)) -> str:
    """map.toml with the measurement frame composed into the calibrated scene's base (identity
    here), the fitted marker offset, and friction as the parameter to fit."""
    text = (DATA / "map.toml").read_text()
    head = text[:text.index("[frame]")]
    offset = document["values"]["markers"]["tip"]["offset"]
    head = head.replace("offset = [0.0, 0.0, 8.0]", "offset = [%r, %r, %r]" % tuple(1e3 * v for v in offset))
    lines = [head, "[frame]", 'unit = "mm"', "position = [0.0, 0.0, 0.0]", "rotation_deg = [0.0, 0.0, 0.0]", "",
             "[fit]", "parameters = [%s]" % ", ".join(f'"{f}"' for f in fit)]
    if max_samples:
        lines.append(f"max_samples = {max_samples}")
    return "\n".join(lines) + "\n"


def pairs(samples) -> np.ndarray:
    """(p, 2) row pairs: the same command on two branches of one run of a pattern (module docstring)."""
    found = []
    patterns = samples.patterns
    start = 0
    for end in range(1, len(samples) + 1):
        if end < len(samples) and patterns[end] == patterns[start]:
            continue
        commands = samples.commands[start:end]
        for i in range(end - start):
            for j in range(i + 3, end - start):
                if np.max(np.abs(commands[i] - commands[j])) < SAME_COMMAND:
                    found.append((start + i, start + j))
        start = end
    return np.array(found, int).reshape(-1, 2)


def gaps(samples, predicted: np.ndarray, index: np.ndarray) -> dict:
    measured = samples.markers[index[:, 1], 0] - samples.markers[index[:, 0], 0]
    model = predicted[index[:, 1], 0] - predicted[index[:, 0], 0]
    m, p = np.linalg.norm(measured, axis=1), np.linalg.norm(model, axis=1)
    return {"pairs": int(len(index)), "measured_median_m": float(np.median(m)) if m.size else None,
            "measured_rms_m": float(np.sqrt(np.mean(m ** 2))) if m.size else None,
            "predicted_median_m": float(np.median(p)) if p.size else None,
            "explained_share": float(1.0 - np.sum((measured - model) ** 2) / np.sum(measured ** 2)) if m.size else None,
            "along_measured_share": float(np.sum(measured * model) / np.sum(measured ** 2)) if m.size else None}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibrated", required=True, help="the frictionless calibration's scene (--output)")
    parser.add_argument("--document", required=True, help="its JSON document (--save-json)")
    parser.add_argument("--max-samples", type=int, default=None, help="training rows used by the fit")
    parser.add_argument("--start", type=float, default=0.05, help="initial μ")
    parser.add_argument("--max-evaluations", type=int, default=12)
    parser.add_argument("--fit", nargs="+", default=["friction"],
                        help="parameters fitted from the frictionless calibration's values (friction among them)")
    parser.add_argument("--name", default="friction_v4", help="results file name (benchmarks/results/NAME.json)")
    parser.add_argument("--holdout-only", action="store_true", help="predict only the held-out file after the fit")
    parser.add_argument("--scan", nargs="+", type=float, metavar="MU",
                        help="no fit: predict the held-out file with the frictionless fit's values at each μ")
    args = parser.parse_args(argv)
    if args.scan:
        return scan(args)
    document = json.loads(Path(args.document).read_text())
    with tempfile.TemporaryDirectory() as tmp:
        mapping_path = Path(tmp) / "map.toml"
        mapping_path.write_text(derived_mapping(document, args.max_samples, args.fit))
        mapping = load_mapping(mapping_path)
        text = Path(args.calibrated).read_text()
        scene_path = Path(tmp) / "scene.toml"
        scene_path.write_text(text.replace("\n[[cable]]\n", f"\n[[cable]]\nfriction = {args.start!r}\n"))
        scene = load_scene(scene_path)
        train, holdout = load_samples(TRAIN, mapping), load_samples(HOLDOUT, mapping)
        length = None
        out = {"benchmark": "friction_v4", "vertebra_version": __version__, "date": now(), "loadavg": loadavg(),
               "max_samples": args.max_samples, "start_mu": args.start}
        t0 = time.perf_counter()
        cal = calibrate(scene, mapping, train, holdout, max_evaluations=args.max_evaluations,
                        progress=lambda message: log(f"fit: {message}"))
        mu = float(cal.x[list(cal.parameters.names).index("friction")])
        out["fit"] = {"parameters": dict(zip(cal.parameters.names, cal.x.tolist())),
                      "standard_errors": dict(zip(cal.parameters.names, cal.standard_errors.tolist())),
                      "mu": mu, "seconds": time.perf_counter() - t0, "train_subsampled": cal.train,
                      "holdout": cal.holdout, "optimiser": cal.optimiser}
        log(f"fitted {dict(zip(cal.parameters.names, np.round(cal.x, 5)))} in {time.perf_counter() - t0:.0f} s")
        predictor = SequencePredictor(scene, mapping)
        values = cal.values
        length = float(predictor.model.length_scale)
        for name, samples in (("holdout", holdout),) + ((("train", train),) if not args.holdout_only else ()):
            index = pairs(samples)
            row = {}
            for label, friction in (("frictionless", np.zeros_like(values.friction)), ("fitted", values.friction)):
                t1 = time.perf_counter()
                predicted = predictor.predict(dataclasses.replace(values, friction=friction), samples).markers
                metrics = error_metrics(predicted, samples.markers, samples.patterns, length)
                row[label] = {"rmse_m": metrics["rmse_m"], "rmse_pct_length": metrics["rmse_pct_length"],
                              "median_m": metrics["median_m"], "p95_m": metrics["p95_m"],
                              "pull_release": gaps(samples, predicted, index),
                              "seconds": time.perf_counter() - t1}
                log(f"{name} {label} (μ = {float(friction.max()):.4f}): RMSE {1e3 * metrics['rmse_m']:.3f} mm "
                    f"({metrics['rmse_pct_length']:.2f} %), pull/release pairs {len(index)}: measured median "
                    f"{1e3 * (row[label]['pull_release']['measured_median_m'] or 0):.2f} mm, predicted median "
                    f"{1e3 * (row[label]['pull_release']['predicted_median_m'] or 0):.3f} mm, explained share "
                    f"{row[label]['pull_release']['explained_share']}")
            out[name] = row
    write_json(out, RESULTS / f"{args.name}.json")
    log(f"wrote benchmarks/results/{args.name}.json")


def scan(args) -> None:
    """The held-out file predicted as a sequence at each μ of ``--scan``, every other value the
    frictionless calibration's."""
    document = json.loads(Path(args.document).read_text())
    with tempfile.TemporaryDirectory() as tmp:
        mapping_path = Path(tmp) / "map.toml"
        mapping_path.write_text(derived_mapping(document, None))
        mapping = load_mapping(mapping_path)
        scene_path = Path(tmp) / "scene.toml"
        scene_path.write_text(Path(args.calibrated).read_text())
        scene = load_scene(scene_path)
        holdout = load_samples(HOLDOUT, mapping)
        predictor = SequencePredictor(scene, mapping)
        from vertebra.solver.calibration.fit_parameters import initial_values      # (benchmark script)
        values = initial_values(scene, mapping, predictor.model)
        index = pairs(holdout)
        rows = []
        for mu in args.scan:
            t1 = time.perf_counter()
            predicted = predictor.predict(dataclasses.replace(values, friction=np.full(values.friction.size, mu)),
                                          holdout).markers
            metrics = error_metrics(predicted, holdout.markers, holdout.patterns, float(predictor.model.length_scale))
            row = {"mu": mu, "rmse_m": metrics["rmse_m"], "rmse_pct_length": metrics["rmse_pct_length"],
                   "median_m": metrics["median_m"], "pull_release": gaps(holdout, predicted, index),
                   "seconds": time.perf_counter() - t1}
            rows.append(row)
            log(f"held out, μ = {mu}: RMSE {1e3 * row['rmse_m']:.3f} mm, pull/release: measured median "
                f"{1e3 * row['pull_release']['measured_median_m']:.2f} mm, predicted median "
                f"{1e3 * row['pull_release']['predicted_median_m']:.3f} mm, explained share "
                f"{row['pull_release']['explained_share']:.3f}")
    write_json({"benchmark": "friction_v4_scan", "vertebra_version": __version__, "date": now(),
                "loadavg": loadavg(), "holdout": rows}, RESULTS / f"{args.name}.json")
    log(f"wrote benchmarks/results/{args.name}.json")


if __name__ == "__main__":
    main()
