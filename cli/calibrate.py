"""``vertebra calibrate SCENE --data TRAIN.csv --map MAP.toml [--holdout VAL.csv] [--fit PARAM ...]``:
fit a scene's parameters to measured static samples (docs/calibration.md)."""

from __future__ import annotations

import json
import sys

from vertebra.cli.outputs import output_file

MAX_STARTS = 1000              # random starts of one calibration
MAX_EVALUATIONS = 100_000      # model evaluations per start
MAX_WORKERS = 64               # worker processes solving the samples
from vertebra.core.errors import OptionError


def add_arguments(parser):
    parser.add_argument("scene", help="scene file (TOML; docs/scenes.md)")
    parser.add_argument("--data", required=True, metavar="TRAIN.csv", help="training samples (CSV with a header)")
    parser.add_argument("--holdout", metavar="VAL.csv", help="held-out samples, measured but not fitted")
    parser.add_argument("--map", required=True, metavar="MAP.toml",
                        help="how the CSV columns meet the scene: actuator columns, units and signs, markers, "
                             "measurement frame, parameters to fit (docs/calibration.md)")
    parser.add_argument("--fit", nargs="+", metavar="PARAM",
                        help="parameters to fit: KIND, KIND.*, KIND.MEMBER or KIND.A+B, optionally =LOW:HIGH "
                             "(kinds: stiffness, angle, radius, cable_stiffness, pretension, frame, marker); "
                             "default: the mapping's [fit] parameters")
    parser.add_argument("--method", default="trf", choices=("trf", "lm"),
                        help="least-squares method: trf (bounded, default) or lm (unbounded)")
    parser.add_argument("--loss", default="linear", choices=("linear", "soft_l1", "huber", "cauchy", "arctan"),
                        help="robust loss (trf only; default linear)")
    parser.add_argument("--loss-scale", type=float, metavar="M",
                        help="residual (m) at which a robust loss starts to discount (default 1%% of the length)")
    parser.add_argument("--starts", type=int, default=1, help="starts: the initial values, then random ones "
                                                              "inside the bounds (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    parser.add_argument("--max-evaluations", type=int, default=60, metavar="N",
                        help="model evaluations per start at most (default 60)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="processes solving the samples (default: one per core, at most one per 256 "
                             "training samples)")
    parser.add_argument("--output", metavar="SCENE.toml", help="write the calibrated scene")
    parser.add_argument("--report", metavar="REPORT.md", help="write a Markdown report (pictures beside it)")
    parser.add_argument("--plots", metavar="DIR", help="write the pictures into DIR (default: beside --report)")
    parser.add_argument("--save-json", metavar="FILE.json", help="write the JSON document to a file")
    parser.add_argument("--json", action="store_true", help="print one JSON document on stdout")


def run(args) -> int:
    from pathlib import Path

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver
    from vertebra.solver.calibration import calibrate, load_mapping, load_samples
    from vertebra.solver.calibration.report import (calibrated_scene_toml, calibration_document, markdown_report,
                                                    write_plots)

    output = output_file(args.output, "--output", (".toml",))
    report = output_file(args.report, "--report", (".md",))
    saved = output_file(args.save_json, "--save-json", (".json",))
    if args.max_evaluations < 1:
        raise OptionError(f"must be at least 1, got {args.max_evaluations}", field="--max-evaluations")
    if args.loss_scale is not None and not 0 < args.loss_scale < float("inf"):
        raise OptionError(f"must be a finite number > 0, got {args.loss_scale}", field="--loss-scale")
    if not 1 <= args.starts <= MAX_STARTS:
        raise OptionError(f"must be 1..{MAX_STARTS}, got {args.starts}", field="--starts")
    if not 0 <= args.seed < 2 ** 63:
        raise OptionError(f"must be 0..2**63-1, got {args.seed}", field="--seed")
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise OptionError(f"must be 1..{MAX_WORKERS}, got {args.workers}", field="--workers")
    if args.max_evaluations > MAX_EVALUATIONS:
        raise OptionError(f"must be at most {MAX_EVALUATIONS}, got {args.max_evaluations}", field="--max-evaluations")
    scene = solver.load_scene(args.scene)
    mapping = load_mapping(args.map)
    train = load_samples(args.data, mapping)
    holdout = load_samples(args.holdout, mapping) if args.holdout else None

    def progress(message):
        print(f"vertebra calibrate: {message}", file=sys.stderr)

    cal = calibrate(scene, mapping, train, holdout, args.fit, loss=args.loss, loss_scale=args.loss_scale,
                    method=args.method, starts=args.starts, seed=args.seed, max_evaluations=args.max_evaluations,
                    workers=args.workers, progress=progress)
    sources = {"scene": args.scene, "data": args.data, "holdout": args.holdout, "map": args.map}
    sources = {k: v for k, v in sources.items() if v}
    if output is not None:
        output.write_text(calibrated_scene_toml(cal, scene, mapping), encoding="utf-8")
        progress(f"wrote {output}")
    pictures = None
    plots = Path(args.plots) if args.plots else (report.parent / f"{report.stem}_plots" if report else None)
    if plots is not None:
        files = write_plots(cal, plots)
        base = report.parent if report else plots
        pictures = {title: str((plots / name).relative_to(base)) if plots.is_relative_to(base) else str(plots / name)
                    for title, name in files.items()}
        progress(f"wrote {len(files)} pictures into {plots}")
    if report is not None:
        report.write_text(markdown_report(cal, scene, mapping, sources, pictures), encoding="utf-8")
        progress(f"wrote {report}")
    document = calibration_document(cal, scene, mapping, sources)
    if saved is not None:
        saved.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
        progress(f"wrote {saved}")
    if args.json:
        json.dump(document, sys.stdout)
        sys.stdout.write("\n")
    else:
        for label, m in (("train", cal.train), ("held-out", cal.holdout)):
            if m is not None:
                print(f"{label}: tip RMSE {1e3 * m['rmse_m']:.3f} mm ({m['rmse_pct_length']:.2f} % of length), "
                      f"median {1e3 * m['median_m']:.3f} mm, p95 {1e3 * m['p95_m']:.3f} mm, max {1e3 * m['max_m']:.3f} mm; "
                      f"offset removed {1e3 * m['offset_removed']['rmse_m']:.3f} mm")
        for p in document["parameters"]:
            se = "unidentifiable" if not p["identifiable"] else f"± {p['standard_error']:.3g}"
            print(f"  {p['name']}: {p['value']:.6g} {p['unit']} {se}")
        print(f"{cal.timings['total_s']:.1f} s, {cal.optimiser['evaluations']} evaluations")
    return 0
