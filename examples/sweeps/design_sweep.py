"""Design sweep to robot: fill a catalogue from a sweep spec, compare the entries, build a trunk.

1. runs a sweep spec (default: ``rod_grid.toml`` next to this script, six silicone rods)
   into an HDF5 catalogue — entries already there are reused, so a second run is instant;
2. prints each entry's axial and bending compliance against the beam formulas (the FE
   segments are a little stiffer: their rigid end faces restrain the Poisson contraction
   and the shear warping, more so the squatter the segment);
3. writes a scene stacking four of the softest entry, loads its tip sideways and solves it.

    python design_sweep.py [SPEC.toml] [--catalogue parts.h5] [--workers 2] [--first N]

The command-line equivalent of step 1: ``vertebra sweep rod_grid.toml --catalogue parts.h5``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def first_sets(spec, count: int):
    """The spec cut to its first ``count`` parameter sets (as an explicit list)."""
    from vertebra.designer.sweep import SAMPLERS

    sets = SAMPLERS[spec.sampler].expand(spec.design)[:count]
    return dataclasses.replace(spec, sampler="list", design=sets)


def run(spec_path=HERE / "rod_grid.toml", catalogue="parts.h5", workers: int = 1, first: int | None = None,
        executor: str = "local", quiet: bool = False) -> dict:
    from vertebra import solver
    from vertebra.designer.sweep import load_spec, run_sweep
    from vertebra.solver.scene import scene_toml
    from vertebra.store.catalogue import open_catalogue

    spec = load_spec(spec_path)
    if first is not None:
        spec = first_sets(spec, first)
    report = run_sweep(spec, catalogue, executor=executor, workers=workers, progress=not quiet)
    keys = [outcome.key for outcome in report.completed] + [task.key for task in report.skipped]
    rows = []
    with open_catalogue(catalogue) as cat:
        for key in keys:
            entry = cat.load(key)
            p = entry.parameters
            radius, length, E, nu = p["radius"], p["length"], p["youngs_modulus"], p["poisson_ratio"]
            area, inertia = math.pi * radius ** 2, math.pi * radius ** 4 / 4
            shear_area = 6 * (1 + nu) / (7 + 6 * nu) * area
            bending = length ** 3 / (3 * E * inertia) + length / (E / (2 * (1 + nu)) * shear_area)
            rows.append({"name": entry.name, "key": key, "radius": radius, "length": length,
                         "axial_over_formula": float(entry.compliance[2, 2] / (length / (E * area))),
                         "bending_over_timoshenko": float(entry.compliance[0, 0] / bending),
                         "lateral_compliance": float(entry.compliance[0, 0])})
    if not quiet:
        print(f"{len(rows)} entries in {catalogue} ({len(report.completed)} designed now, "
              f"{len(report.skipped)} reused, {len(report.failures)} failed)")
        print(f"  {'name':24s} {'r mm':>6s} {'L mm':>6s} {'axial/(L/EA)':>13s} {'lateral/Timoshenko':>19s}")
        for row in rows:
            print(f"  {row['name']:24s} {1e3 * row['radius']:6.1f} {1e3 * row['length']:6.1f} "
                  f"{row['axial_over_formula']:13.3f} {row['bending_over_timoshenko']:19.3f}")
    softest = max(rows, key=lambda row: row["lateral_compliance"])
    scene = {"name": f"four {softest['name']}",
             "catalogue": {"path": Path(catalogue).name},
             "segment": [{"type": "entry", "entry": softest["key"], "count": 4}],
             "load": [{"vertebra": -1, "force": [0.01, 0.0, 0.0]}],
             "effector": [{"name": "tip", "vertebra": -1}]}
    scene_path = Path(catalogue).with_name("stacked.toml")
    scene_path.write_text(scene_toml(scene))
    model = solver.build_model(solver.load_scene(scene_path))
    result = model.solve()
    tip = model.effector_positions(result.state)[0]
    if not quiet:
        print(f"{scene_path}: four '{softest['name']}' under 0.01 N sideways: tip at "
              f"{[round(v, 5) for v in tip.tolist()]} m (converged {result.converged})")
    return {"entries": rows, "failures": len(report.failures), "scene": str(scene_path),
            "tip": tip.tolist(), "converged": bool(result.converged)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec", nargs="?", default=str(HERE / "rod_grid.toml"), help="sweep spec (TOML, rod family)")
    parser.add_argument("--catalogue", default="parts.h5", help="HDF5 catalogue to fill (created if missing)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--first", type=int, default=None, help="design only the spec's first N parameter sets")
    args = parser.parse_args(argv)
    summary = run(args.spec, args.catalogue, args.workers, args.first)
    return 0 if summary["converged"] and not summary["failures"] else 1


if __name__ == "__main__":
    sys.exit(main())
