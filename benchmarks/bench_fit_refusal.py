"""Where ``vertebra prepare`` refuses a nonlinear entry: the default St Venant–Kirchhoff rod of the
range-extension trunk (R 10 mm, L 20 mm, E 1 MPa, ν 0.3, P2 h 2.5 mm, four repetitions), under a
dead tip force normal to the trunk.

For each force: the range the scene needs (``designer.scene_range.estimate_ranges`` with the
linear entry, as ``prepare`` does), how far into the entry's sampled box that reaches
(``preparation.needed_level``), the entry's held-out load error over that part of the box
(``energy_fit.error_up_to``) and whether ``prepare`` refuses it at the default limit
(``energy_fit.FIT_LIMIT``). The tip errors of the same trunk against the full nonlinear FE are
those of ``benchmarks/bench_range_extension.py`` (``range_extension_*.json``).

Run: ``OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_fit_refusal [--entries DIR]``; writes
``benchmarks/results/fit_refusal.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from benchmarks.bench_range_extension import ROD, case_of  # noqa: E402
from benchmarks.bench_nonlinear_acceptance import designed  # noqa: E402
from benchmarks.common import RESULTS, loadavg, log, now, write_json  # noqa: E402
from vertebra import __version__, solver  # noqa: E402

FORCES = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 8.0)      # N, normal tip force


def main(argv=None) -> int:
    from vertebra.designer.energy_fit import FIT_LIMIT, error_up_to
    from vertebra.designer.preparation import fit_refusal, needed_level
    from vertebra.designer.scene_range import estimate_ranges

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--entries", type=Path, default=Path(tempfile.gettempdir()) / "vertebra-range-extension")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    args.entries.mkdir(parents=True, exist_ok=True)
    entry, seconds = designed(case_of("svk", "normal"), ROD, args.entries / "entries.h5")
    linear = dataclasses.replace(entry, energy=None)
    held = entry.energy.fit_error["held_out"]
    log(f"svk entry {entry.name} ({seconds:.0f} s to design): held-out load error {held['load_max']:.3g} "
        f"(rms {held['load_rms']:.3g}); by level {held.get('by_level')}")
    rows = []
    for force in FORCES:
        data = {"catalogue": {"path": "unused.h5"}, "segment": [{"type": "entry", "entry": entry.name, "count": 4}],
                "load": [{"vertebra": -1, "force": [force, 0.0, 0.0]}], "effector": [{"name": "tip"}]}
        model = solver.build_model(solver.parse_scene(data), {entry.name: linear})
        estimate = estimate_ranges(model)
        level = needed_level(estimate.segments[0], entry.energy.range)
        error, count = error_up_to(held["by_level"], *level)
        reason = fit_refusal(entry.energy, level, FIT_LIMIT)
        rows.append({"force_N": force, "needed_level": level[0], "error_where_needed": error,
                     "held_out_samples_counted": count, "refused": reason is not None, "reason": reason})
        log(f"  {force} N: needs {level[0]:.3g} of the box, held-out error there {error:.3g} ({count} samples): "
            f"{'refused' if reason else 'accepted'}")
    write_json({"meta": {"date": now(), "version": __version__, "load": loadavg(), "limit": FIT_LIMIT},
                "entry": {"name": entry.name, "held_out": held, "design_s": seconds}, "rows": rows},
               args.out / "fit_refusal.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
