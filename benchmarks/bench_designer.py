"""Designer benchmark: cost and accuracy of condensing a segment, per mesh size and element order.

For a rod (R = 10 mm, L = 40 mm, E = 1 MPa, ν = 0.3 — the reference cylinder) and one
pneumatic segment (3 chambers, ν = 0.45): DoFs, mesh / assemble / solve seconds and the
compliance error against the finest mesh (scale-free: max |ΔC_ij| / sqrt(C_ii C_jj)); the
rod rows also give the axial and lateral compliance over the closed forms. Then direct vs
AMG solve time (the ``auto`` threshold) and the time to condense a ~50,000-DoF segment
(acceptance: ≤ 10 s). Prints a table, writes benchmarks/results/designer.json and .md.

    python -m benchmarks.bench_designer [--quick]          (BLAS pinned to one thread inside)
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import socket
import sys
import time
from datetime import datetime, timezone

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS  # noqa: E402
from vertebra.designer.accuracy import compliance_change
from vertebra.designer.linear import solve_segment
from vertebra.designer.segment import design_segment
from vertebra.designer.threads import pin_blas_threads

E, NU = 1.0e6, 0.3
ROD = dict(radius=0.01, length=0.04, youngs_modulus=E, poisson_ratio=NU)
PNEUMATIC = dict(outer_radius=0.02, chamber_radius=0.005, chamber_offset=0.011, length=0.02,
                 youngs_modulus=E, poisson_ratio=0.45, density=1100.0)


def rod_closed_forms():
    R, L = ROD["radius"], ROD["length"]
    A, I, G = math.pi * R ** 2, math.pi * R ** 4 / 4, E / (2 * (1 + NU))
    kappa = 6 * (1 + NU) / (7 + 6 * NU)
    return {"axial": L / (E * A), "lateral": L ** 3 / (3 * E * I) + L / (kappa * G * A)}


def run_case(family, parameters, h, order, linear_solver="auto"):
    C, fe, mesh, cond, t = solve_segment(family, parameters, mesh_size=h, order=order, linear_solver=linear_solver)
    row = {"family": family, "order": order, "mesh_size": h, "dofs": int(fe.n_dofs),
           "interior_dofs": int(cond.info["interior_dofs"]), "solver": cond.info["solver"],
           "mesh_s": t["mesh_s"], "assemble_s": t["assemble_s"], "solve_s": t["solve_s"], "total_s": t["total_s"]}
    if "iterations" in cond.info:
        row["pcg_iterations"] = max(cond.info["iterations"])
    return row, C


def mesh_study(family, parameters, sizes, reference, log):
    log(f"{family}: reference P{reference[1]} h = {reference[0]}")
    ref_row, C_ref = run_case(family, parameters, reference[0], reference[1])
    ref_row["reference"] = True
    rows = [ref_row]
    for order, hs in sizes.items():
        for h in hs:
            row, C = run_case(family, parameters, h, order)
            row["error"] = compliance_change(C_ref, C)
            if family == "rod":
                forms = rod_closed_forms()
                row["axial_over_closed_form"] = C[2, 2] / forms["axial"]
                row["lateral_over_timoshenko"] = C[0, 0] / forms["lateral"]
            rows.append(row)
            log(f"  P{order} h={h:<7} dofs={row['dofs']:>6} err={row['error']:.2e} total={row['total_s']:.2f}s")
    ref_row["error"] = 0.0
    if family == "rod":
        forms = rod_closed_forms()
        ref_row["axial_over_closed_form"] = C_ref[2, 2] / forms["axial"]
        ref_row["lateral_over_timoshenko"] = C_ref[0, 0] / forms["lateral"]
    return rows


def crossover(sizes, log):
    rows = []
    for order, h in sizes:
        for solver in ("direct", "amg"):
            row, _ = run_case("rod", ROD, h, order, linear_solver=solver)
            rows.append(row)
            log(f"  P{order} h={h} {solver:6} interior={row['interior_dofs']:>6} solve={row['solve_s']:.2f}s")
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer, coarser meshes (smoke run)")
    args = parser.parse_args(argv)
    pin_blas_threads(1)

    def log(message):
        print(message, file=sys.stderr, flush=True)

    start = time.perf_counter()
    if args.quick:
        rod_sizes = {1: [0.01, 0.005], 2: [0.01, 0.005]}
        rod_ref, pn_ref = (0.0035, 2), (0.004, 2)
        pn_sizes = {1: [0.006], 2: [0.006]}
        cross_sizes, large_h = [(2, 0.005)], 0.004
    else:
        rod_sizes = {1: [0.01, 0.007, 0.005, 0.0035, 0.0025, 0.00177], 2: [0.01, 0.007, 0.005, 0.0035, 0.0025]}
        rod_ref = (0.0019, 2)
        pn_sizes = {1: [0.006, 0.004, 0.003, 0.002], 2: [0.008, 0.006, 0.004, 0.003]}
        pn_ref = (0.0022, 2)
        cross_sizes = [(1, 0.0025), (1, 0.0016), (2, 0.005), (2, 0.0035), (2, 0.0028)]
        large_h = 0.0019
    result = {"date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(), "host": socket.gethostname(),
              "python": platform.python_version(), "load_average": [round(x, 2) for x in os.getloadavg()],
              "rod_parameters": ROD, "pneumatic_parameters": PNEUMATIC}
    result["rod"] = mesh_study("rod", ROD, rod_sizes, rod_ref, log)
    result["pneumatic"] = mesh_study("pneumatic", PNEUMATIC, pn_sizes, pn_ref, log)
    log("direct vs AMG")
    result["crossover"] = crossover(cross_sizes, log)
    log(f"large segment: P2 rod h = {large_h}")
    result["large"], _ = run_case("rod", ROD, large_h, 2)
    t0 = time.perf_counter()
    design_segment("pneumatic", PNEUMATIC, estimate_accuracy=False)
    without = time.perf_counter() - t0
    t0 = time.perf_counter()
    entry = design_segment("pneumatic", PNEUMATIC, estimate_accuracy=True)
    result["accuracy_cost"] = {"without_s": without, "with_s": time.perf_counter() - t0,
                               "relative_error": entry.accuracy["relative_error"]}
    result["benchmark_s"] = time.perf_counter() - start
    text = render.markdown("designer", result)
    print(text)
    if not args.quick:
        render.write("designer", result)
        log(f"written {RESULTS / 'designer.json'} and designer.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
