"""Accuracy estimate of a designed entry against the true error, and what it costs.

For every family (rod, tube, bellows, pneumatic, tapered pneumatic), element order 1 and 2 and
ν = 0.3, 0.45, 0.49, at the family's default mesh size: the compliance C_h, the estimate that
``design_segment`` stores (``designer.linear.estimate_accuracy_of``: second order on the same
mesh for order 1, Richardson extrapolation from a coarser mesh for order 2) and the true error
against a much finer second-order mesh (h/3; h/2.5 for the thin-walled bellows). Errors are
relative compliance errors over all loads (``designer.accuracy.relative_error``). Also where each
entry sits between the bounds the store checks (``store.soundness``).

Then the acceptance case: ``design_segment`` of a ~50,000-DoF second-order rod with its
estimate, timed (≤ 10 s; wall and CPU time, with the load average), and its estimate against a
reference at h/1.9 (~260,000 DoFs).

Results: benchmarks/results/accuracy.json and .md (only when every case ran).

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_accuracy [--quick]
        [--families bellows,pneumatic] [--nus 0.45,0.49] [--orders 1] [--no-large]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import warnings
from datetime import datetime, timezone

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import log  # noqa: E402
from vertebra.designer.accuracy import relative_error  # noqa: E402
from vertebra.designer.families import canonical_parameters, family_of  # noqa: E402
from vertebra.designer.linear import estimate_accuracy_of, solve_segment  # noqa: E402
from vertebra.designer.segment import design_segment  # noqa: E402
from vertebra.store.soundness import bound_ratios  # noqa: E402

E = 1.0e6
FAMILIES = {
    "rod": dict(radius=0.01, length=0.04),
    "tube": dict(outer_radius=0.01, inner_radius=0.006, length=0.03),
    "bellows": dict(inner_radius=0.008, outer_radius=0.014, wall_thickness=0.0015, length=0.04),
    "pneumatic": dict(outer_radius=0.02, chamber_radius=0.005, chamber_offset=0.011, length=0.02),
    "tapered_pneumatic": dict(bottom_outer_radius=0.02, top_outer_radius=0.016, bottom_chamber_radius=0.005,
                              top_chamber_radius=0.004, bottom_chamber_offset=0.011, top_chamber_offset=0.009,
                              length=0.02),
}
REFINE = {"bellows": 2.5}          # the reference mesh is h / REFINE (default 3)
LARGE = dict(FAMILIES["rod"], youngs_modulus=E, poisson_ratio=0.3)
LARGE_H = 0.0019                   # ~45,600 second-order DoFs



def case(family: str, nu: float, order: int, reference) -> dict:
    p = dict(FAMILIES[family], youngs_modulus=E, poisson_ratio=nu)
    fam = family_of(family)
    h = fam.default_mesh_size(canonical_parameters(fam, p))
    t0 = time.perf_counter()
    C, fe, mesh, _, t = solve_segment(family, p, mesh_size=h, order=order)
    accuracy = estimate_accuracy_of(family, p, C, mesh)
    total = time.perf_counter() - t0
    true = relative_error(C, reference)
    row = {"family": family, "nu": nu, "order": order, "mesh_size": h, "dofs": int(fe.n_dofs),
           "design_s": t["total_s"], "with_estimate_s": total, "true_error": true, "method": accuracy["method"]}
    if "relative_error" in accuracy:
        row.update(estimate=accuracy["relative_error"], ratio=accuracy["relative_error"] / true,
                   estimate_dofs=estimate_dofs(accuracy), basis=accuracy["basis"],
                   extrapolated_error=relative_error(reference, np.array(accuracy["extrapolated_compliance"])),
                   **{k: accuracy[k] for k in ("size_ratio", "convergence_order") if k in accuracy})
    return row


def estimate_dofs(accuracy: dict) -> int:
    """DoFs of the estimate's solve: on the coarser mesh, or with the raised order."""
    return accuracy.get("coarse_dofs", accuracy.get("raised_dofs"))


def bounds_row(family: str, nu: float, order: int) -> dict:
    p = dict(FAMILIES[family], youngs_modulus=E, poisson_ratio=nu, density=1000.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        entry = design_segment(family, p, order=order, estimate_accuracy=False)
    ratios = bound_ratios(entry)
    return {"family": family, "nu": nu, "order": order, "lower_min": min(ratios["lower"]),
            "upper_max": max(ratios["upper"]), "upper_method": ratios["upper_method"]}


def large_case() -> dict:
    load = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    entry = design_segment("rod", LARGE, mesh_size=LARGE_H, order=2)
    total, cpu = time.perf_counter() - t0, time.process_time() - c0
    log(f"large: {entry.mesh['dofs']} DoFs, {total:.2f} s ({cpu:.2f} s CPU) with estimate; reference at h/1.9")
    reference, fe_ref, *_ = solve_segment("rod", LARGE, mesh_size=LARGE_H / 1.9, order=2, max_elements=1_000_000)
    true = relative_error(entry.compliance, reference)
    acc = entry.accuracy
    return {"mesh_size": LARGE_H, "dofs": entry.mesh["dofs"], "total_s": total, "cpu_s": cpu, "loadavg": load,
            "design_s": total - entry.timings["accuracy_s"], "accuracy_s": entry.timings["accuracy_s"],
            "estimate_dofs": estimate_dofs(acc), "basis": acc["basis"], "estimate": acc["relative_error"],
            "true_error": true,
            "ratio": acc["relative_error"] / true, "reference_dofs": int(fe_ref.n_dofs),
            "extrapolated_error": relative_error(reference, np.array(acc["extrapolated_compliance"]))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="rod and pneumatic at ν = 0.3 only; nothing saved")
    parser.add_argument("--families", help="comma-separated subset of the families; nothing saved")
    parser.add_argument("--nus", help="comma-separated subset of ν (0.3, 0.45, 0.49); nothing saved")
    parser.add_argument("--orders", help="comma-separated subset of the orders (1, 2); nothing saved")
    parser.add_argument("--no-large", action="store_true", help="skip the ~50k-DoF rod; nothing saved")
    args = parser.parse_args(argv)
    families = ["rod", "pneumatic"] if args.quick else list(FAMILIES)
    nus = [0.3] if args.quick else [0.3, 0.45, 0.49]
    families = args.families.split(",") if args.families else families
    nus = [float(x) for x in args.nus.split(",")] if args.nus else nus
    orders = [int(x) for x in args.orders.split(",")] if args.orders else [1, 2]
    partial = args.quick or args.families or args.nus or args.orders or args.no_large
    result = {"date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(), "host": platform.node(),
              "python": platform.python_version(), "loadavg_start": os.getloadavg(), "cases": [], "bounds": []}
    warnings.simplefilter("ignore")                 # order-1 locking warnings: measured here, not the point
    for family in families:
        for nu in nus:
            p = dict(FAMILIES[family], youngs_modulus=E, poisson_ratio=nu)
            fam = family_of(family)
            h = fam.default_mesh_size(canonical_parameters(fam, p))
            log(f"{family} ν = {nu}: reference at h/{REFINE.get(family, 3)}")
            reference, *_ = solve_segment(family, p, mesh_size=h / REFINE.get(family, 3), order=2,
                                          max_elements=1_000_000)
            for order in orders:
                row = case(family, nu, order, reference)
                log(f"  P{order}: true {row['true_error']:.3g}, estimate {row.get('estimate', float('nan')):.3g}"
                    f" ({row.get('basis', row['method'])})")
                result["cases"].append(row)
                if nu in (0.3, 0.49) and not partial:
                    result["bounds"].append(bounds_row(family, nu, order))
    if not args.no_large:
        result["large"] = large_case()
    result["loadavg_end"] = os.getloadavg()
    text = render.markdown("accuracy", result)
    print(text)
    if not partial:
        render.write("accuracy", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
