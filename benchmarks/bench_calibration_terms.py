"""The FTDCR v4 calibration (docs/calibration.md) with the transmission's memory terms added to the
shipped fit, one command each, against the shipped fit in the same run:

    python -m benchmarks.bench_calibration_terms [--terms lag backlash_rate ...]

Each term is a ``--fit`` specification appended to the mapping's ``[fit]`` list (``lag``: one time
constant of the strokes behind the commands for the nine tendons; ``backlash_rate``: one growth of
the play with the tendon's tension). Records, per variant, the train and held-out tip RMSE (no
offset removal), the fitted values with their standard errors, the unidentifiable parameters, the
evaluations and the wall and CPU seconds of the command (the load beside it). Writes
benchmarks/results/calibration_v4_terms.json.
"""

from __future__ import annotations

import argparse
import os

import vertebra
from benchmarks.bench_calibration import EXAMPLE, run
from benchmarks.common import RESULTS, loadavg, log, now, write_json
from vertebra.solver.calibration import load_mapping


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--terms", nargs="+", default=["lag", "backlash_rate"],
                        help="--fit specifications to add, one variant each")
    args = parser.parse_args(argv)
    this = os.path.dirname(os.path.dirname(os.path.abspath(vertebra.__file__)))
    shipped = list(load_mapping(EXAMPLE / "map.toml").fit)
    variants = {"shipped": ()}
    variants.update({term: ("--fit", *shipped, term) for term in args.terms})
    rows = {}
    for name, extra in variants.items():
        log(f"{name} …")
        rows[name] = run(this, extra)
        r = rows[name]
        log(f"  train {1e3 * r['train_rmse_m']:.3f} mm, held out {1e3 * r['holdout_rmse_m']:.3f} mm, "
            f"{r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU, load {r['loadavg_before']}")
        write_json({"vertebra_version": vertebra.__version__, "date": now(), "loadavg": loadavg(),
                    "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
                    "shipped_fit": shipped, "variants": rows}, RESULTS / "calibration_v4_terms.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
