"""Beyond the fitted range: trunks of default-designed nonlinear entries against the linear entries
and the full nonlinear FE, at loads that carry their segments out of the sampled box.

1. Sweeps. A trunk of four rods (R 10 mm, L 20 mm, E 1 MPa, ν 0.3, P2, h 2.5 mm), each segment the
   entry ``vertebra design rod … --material M`` makes with its default sampling (bending ≤ 46° per
   segment), under a dead tip force swept from 0.5 to 8 N — normal to the trunk, and tilted
   (along (1, 0, −1)) so that the tip turns past 90° — for neo-Hookean and St Venant–Kirchhoff. At
   every level: the full nonlinear FE of the same trunk (``NonlinearTrunk``, same meshes, rigid
   vertebrae, continued from level to level), the runtime with the nonlinear entries and with
   their linear parts; the tip error in % of the trunk length, convergence, and the largest
   bending per segment reported outside the range.
2. Convergence (runtime only) at every level and direction: with the tail beyond the box, with
   the polynomial evaluated outside it instead, and with the linear entries.
3. Random trunks. 200 trunks of 2–8 repetitions of those entries under random tip forces and
   moments up to 3× the load box (the largest segment load up to three times the sampled
   bound): every solve converges or stops with a reason; the states outside the range are
   reported where they are (the solve's own report checked against the range test).

Run: ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_range_extension
[--materials neo_hookean svk] [--random 200] [--entries DIR]``; writes
``benchmarks/results/range_extension.json`` (``--suffix`` to run the parts apart:
``--random 0`` for the sweeps alone, ``--no-sweeps`` for the random trunks alone).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.bench_nonlinear_acceptance import designed, rotation_angle_deg, runtime_model  # noqa: E402
from benchmarks.common import RESULTS, loadavg, log, now, write_json  # noqa: E402
from benchmarks.nonlinear_cases import E, SegmentSpec, TrunkCase, project_trunk, trunk_loads  # noqa: E402
from vertebra import __version__, solver  # noqa: E402
from vertebra.core import lie  # noqa: E402

ROD = SegmentSpec.of("rod", 0.0025, 4, radius=0.01, length=0.02, youngs_modulus=E, poisson_ratio=0.3, density=0.0)
LEVELS = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)       # N of tip force
DIRECTIONS = {"normal": (1.0, 0.0, 0.0), "tilted": (1.0 / math.sqrt(2.0), 0.0, -1.0 / math.sqrt(2.0))}


def case_of(material: str, direction: str) -> TrunkCase:
    return TrunkCase(f"rod4_{direction}_{material}", f"4 rods R 10 mm L 20 mm ν 0.3 h 2.5 mm, {direction} tip force",
                     material, (ROD,), levels=LEVELS, forces={-1: DIRECTIONS[direction]}, tags=("range",))


def bending_out(result) -> float:
    """The largest bending strain per segment reported outside the range (degrees; 0: none)."""
    values = [e.value for e in result.out_of_range if e.quantity == "bending strain"]
    return math.degrees(max(values, default=0.0))


def sweep(case: TrunkCase, entry) -> dict:
    linear = dataclasses.replace(entry, energy=None)
    reference = project_trunk(case)
    length = case.length
    rows, state = [], None
    for level in case.levels:
        start = time.process_time()
        row = {"force_N": level}
        try:
            fe = reference.solve(trunk_loads(case, level), initial=state)
            state = fe.state
            row.update(fe_tip_rotation_deg=rotation_angle_deg(fe.rotations[-1]), fe_cpu_s=time.process_time() - start)
        except Exception as error:  # noqa: BLE001 - the reference's failure ends the FE column, reported
            fe = None
            row["fe_failed"] = f"{type(error).__name__}: {str(error)[:200]}"
        for kind, chosen in (("nonlinear", entry), ("linear", linear)):
            model = runtime_model(case, [chosen], level)
            start = time.process_time()
            result = model.solve(raise_on_failure=False)
            out = {"converged": bool(result.converged), "iterations": int(result.iterations),
                   "cpu_s": time.process_time() - start, "out_of_range": len(result.out_of_range),
                   "bending_out_of_range_deg": bending_out(result),
                   "largest_link_turn_deg": math.degrees(float(result.largest_turn))}
            if not result.converged:
                out["message"] = result.message
            if fe is not None and result.converged:
                tip = result.state.positions[-1]
                R = lie.qmatrix(result.state.quaternions[-1:])[0]
                out["tip_error_pct"] = 100 * float(np.linalg.norm(tip - fe.positions[-1])) / length
                out["tip_rotation_error_deg"] = rotation_angle_deg(R @ fe.rotations[-1].T)
            row[kind] = out
        rows.append(row)
        nl, li = row["nonlinear"], row["linear"]
        log(f"  {case.name} {level} N ({row.get('fe_tip_rotation_deg', float('nan')):.1f}°): nonlinear "
            f"{nl.get('tip_error_pct', float('nan')):.4f} % ({'ok' if nl['converged'] else 'FAILED'}, "
            f"{nl['out_of_range']} out of range, bending {nl['bending_out_of_range_deg']:.1f}°), linear "
            f"{li.get('tip_error_pct', float('nan')):.4f} % ({'ok' if li['converged'] else 'FAILED'})")
    return {"name": case.name, "material": case.material, "description": case.description, "length_m": length,
            "entry": entry.name, "range_bending_deg": math.degrees(float(entry.energy.range.pose_upper[2])),
            "rows": rows, "verdict": verdict(rows)}


def verdict(rows: list) -> dict:
    """Nonlinear converges wherever linear does; its tip error never above the linear one's; ≤ 0.2 %
    of the length where no quantity left the range."""
    failures = []
    for row in rows:
        nl, li = row["nonlinear"], row["linear"]
        if li["converged"] and not nl["converged"]:
            failures.append(f"{row['force_N']} N: nonlinear fails where linear converges")
        if "tip_error_pct" in nl and "tip_error_pct" in li and nl["tip_error_pct"] > li["tip_error_pct"]:
            failures.append(f"{row['force_N']} N: nonlinear {nl['tip_error_pct']:.3g} % > linear "
                            f"{li['tip_error_pct']:.3g} %")
        if "tip_error_pct" in nl and nl["out_of_range"] == 0 and nl["tip_error_pct"] > 0.2:
            failures.append(f"{row['force_N']} N: inside the range but {nl['tip_error_pct']:.3g} % > 0.2 %")
    return {"met": not failures, "failures": failures}


def random_trunks(entries: dict, n: int, seed: int = 0) -> dict:
    """``n`` trunks of 2–8 repetitions of one of ``entries`` under a random tip force and moment
    whose base moment is up to 3× the entry's sampled bending-moment bound."""
    rng = np.random.default_rng(seed)
    rows, names = [], sorted(entries)
    for k in range(n):
        name = names[k % len(names)]
        entry = entries[name]
        count = int(rng.integers(2, 9))
        box = entry.energy.range
        length = float(np.linalg.norm(entry.rest_translation))
        factor = 3.0 * rng.random()
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        force = factor * float(box.load_upper[2]) / (count * length) * direction * rng.random()
        moment = factor * rng.random() * np.array([float(box.load_upper[2]) * rng.normal(),
                                                   float(box.load_upper[2]) * rng.normal(),
                                                   float(box.load_upper[3]) * rng.normal()]) / 2.0
        data = {"catalogue": {"path": "unused.h5"},
                "segment": [{"type": "entry", "entry": entry.name, "count": count}],
                "load": [{"vertebra": -1, "force": force.tolist(), "moment": moment.tolist()}],
                "effector": [{"name": "tip", "vertebra": -1}]}
        row = {"entry": name, "count": count, "load_factor_of_box": factor, "force_N": force.tolist(),
               "moment_Nm": moment.tolist()}
        for kind, chosen in (("nonlinear", entry), ("linear", dataclasses.replace(entry, energy=None))):
            model = solver.build_model(solver.parse_scene(data), {entry.name: chosen})
            start = time.process_time()
            result = model.solve(raise_on_failure=False)
            out = {"converged": bool(result.converged), "cpu_s": time.process_time() - start,
                   "out_of_range": len(result.out_of_range), "bending_out_of_range_deg": bending_out(result)}
            if not result.converged:
                out["message"] = result.message
            if kind == "nonlinear" and result.converged:
                # the report is where the range test says: every link outside reported, none inside
                xi = result.state.carried_strains().xi if result.state.carried_strains() is not None else None
                if xi is not None:
                    s = xi - model.trunk.links.rest
                    rho, _ = entry.energy.range.gauge(s)
                    reported = {e.link for e in result.out_of_range if e.quantity.endswith("strain")}
                    out["strain_report_matches_gauge"] = reported == set(np.flatnonzero(rho > 1.0).tolist())
            row[kind] = out
        rows.append(row)
    nl = [r["nonlinear"] for r in rows]
    li = [r["linear"] for r in rows]
    summary = {"trunks": n, "nonlinear_converged": sum(o["converged"] for o in nl),
               "linear_converged": sum(o["converged"] for o in li),
               "nonlinear_failed_where_linear_converged": sum(1 for a, b in zip(nl, li)
                                                              if b["converged"] and not a["converged"]),
               "stopped_messages": sorted({o["message"][:160] for o in nl if not o["converged"]}),
               "reported_out_of_range": sum(1 for o in nl if o["out_of_range"]),
               "report_matches_range_test": sum(1 for o in nl if o.get("strain_report_matches_gauge")),
               "checked_reports": sum(1 for o in nl if "strain_report_matches_gauge" in o)}
    log(f"random trunks: {summary}")
    return {"summary": summary, "rows": rows}


def convergence(entries: dict) -> list:
    """Runtime only, every material, direction and level: does the trunk converge with the tail
    beyond the box, with the polynomial evaluated outside it instead (the kernel's tail switched
    off for the study), and with the linear entries; iterations, tip rotation, quantities out of
    range and the largest bending reported."""
    from vertebra.core import energy

    rows = []
    tail = energy.FixedPressures._extend
    for material, entry in entries.items():
        for direction in DIRECTIONS:
            case = case_of(material, direction)
            for level in case.levels:
                row = {"material": material, "direction": direction, "force_N": level}
                for kind, chosen, extend in (("nonlinear", entry, True), ("polynomial", entry, False),
                                             ("linear", dataclasses.replace(entry, energy=None), True)):
                    energy.FixedPressures._extend = tail if extend else (lambda *args, **kwargs: None)
                    try:
                        result = runtime_model(case, [chosen], level).solve(raise_on_failure=False)
                    finally:
                        energy.FixedPressures._extend = tail
                    R = lie.qmatrix(result.state.quaternions[-1:])[0]
                    row[kind] = {"converged": bool(result.converged), "iterations": int(result.iterations),
                                 "tip_rotation_deg": rotation_angle_deg(R), "out_of_range": len(result.out_of_range),
                                 "bending_out_of_range_deg": bending_out(result)}
                rows.append(row)
                log(f"  {material} {direction} {level} N: " + ", ".join(
                    f"{k} {'ok' if row[k]['converged'] else 'FAILED'} ({row[k]['out_of_range']} out)"
                    for k in ("nonlinear", "polynomial", "linear")))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", nargs="*", default=["neo_hookean", "svk"])
    parser.add_argument("--directions", nargs="*", default=list(DIRECTIONS), choices=list(DIRECTIONS))
    parser.add_argument("--random", type=int, default=200, help="random trunks (0: none)")
    parser.add_argument("--no-sweeps", action="store_true", help="skip the sweeps against the full FE")
    parser.add_argument("--entries", type=Path, default=Path(tempfile.gettempdir()) / "vertebra-range-extension")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--suffix", default="", help="appended to the result's name (parts run apart)")
    args = parser.parse_args(argv)
    args.entries.mkdir(parents=True, exist_ok=True)
    path = args.entries / "entries.h5"
    document = {"meta": {"date": now(), "version": __version__, "load": loadavg()}, "sweeps": [], "random": None}
    out = args.out / f"range_extension{args.suffix}.json"
    entries = {}
    for material in args.materials:
        case = case_of(material, args.directions[0] if args.directions else "normal")
        entries[material], seconds = designed(case, ROD, path)
        log(f"{material}: entry {entries[material].name}, bending range "
            f"{math.degrees(float(entries[material].energy.range.pose_upper[2])):.1f}° ({seconds:.0f} s to design)")
    document["convergence"] = convergence(entries)
    write_json(document, out)
    if args.random:
        document["random"] = random_trunks(entries, args.random)
        write_json(document, out)
    if not args.no_sweeps:
        for material in args.materials:
            for direction in args.directions:
                document["sweeps"].append(sweep(case_of(material, direction), entries[material]))
                write_json(document, out)
    log(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
