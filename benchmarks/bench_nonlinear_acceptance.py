"""Large deformation, end to end: trunks of nonlinear catalogue entries against the full nonlinear FE.

For every case of ``benchmarks/nonlinear_cases.py`` (2–16 rod or tube segments, E = 1 MPa,
ν 0.3–0.45, length/radius 0.5–4, neo-Hookean and St Venant–Kirchhoff, planar and 3-D loads with
torsion, axial load and gravity, and four CBHA-like pneumatic slices to 1.5 bar) this script

1. designs each distinct segment as a nonlinear catalogue entry (the case's mesh, order and
   material, the default sampling; the pneumatic slice sampled to the case's largest pressure),
   exactly as ``vertebra design --material`` does, and keeps it in a catalogue so that re-runs
   only solve;
2. solves the case's trunk at every load level with the runtime solver, once with the nonlinear
   entries and once with their linear parts (the linear condensation of the same designs);
3. solves the same trunk with the project's full nonlinear FE (``NonlinearTrunk`` on the same
   meshes, rigid vertebrae), continuing from level to level;
4. reports the tip position error in % of the trunk length, the tip rotation error, for pressurised
   chambers the relative errors of the tip's bending angle and of the chamber volume growth, the
   quantities the runtime reported outside the fitted range, and — where CalculiX results exist
   (``benchmarks/results/ccx_crosscheck.json``) — the tip error against CalculiX as well.

Acceptance checked: tip within 0.1 % of the trunk length up to 50° of tip rotation and 0.2 % up
to 90°; pneumatic: tip within 0.2 %, bending angle and volume growth within 1 %.

Run: ``.venv/bin/python -m benchmarks.bench_nonlinear_acceptance [--cases NAME …] [--entries DIR]``;
writes ``benchmarks/results/nonlinear_acceptance.md/.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS, log  # noqa: E402

from benchmarks.nonlinear_cases import BAR, CASES, n_cavities, project_trunk, scaled_loads, trunk_loads  # noqa: E402
from vertebra import __version__, solver  # noqa: E402
from vertebra.core import lie  # noqa: E402

CCX = RESULTS / "ccx_crosscheck.json"
MAX_PRESSURE = 1.5 * BAR          # the pneumatic acceptance range: 0-1.5 bar
LIMITS = ((50.0, 0.1), (90.0, 0.2))    # (tip rotation up to, tip error allowed in % of length)



#: ``--nonlinear-mesh-size``: the entries' nonlinear part sampled on this coarser mesh (multi-fidelity)
NONLINEAR_MESH = {}


def sampling_of(case, spec) -> dict:
    """The sampling settings of a case's entry: the defaults, and for segments with cavities the
    case's largest pressure (at most 1.5 bar), as ``vertebra prepare`` takes a scene's bound;
    with ``--nonlinear-mesh-size`` the coarser mesh of the nonlinear part."""
    out = dict(NONLINEAR_MESH)
    if not n_cavities(spec):
        return out
    largest = max(float(np.max(p)) for p in case.pressures.values()) * max(case.levels)
    return {**out, "pressure": min(largest, MAX_PRESSURE), "limit_fraction": 0.95}


def designed(case, spec, path: Path):
    """The nonlinear entry of ``spec`` in ``case``'s material (designed once into ``path``) and the
    seconds its design took (0 when read back)."""
    from vertebra import designer
    from vertebra.store import catalogue

    sampling = sampling_of(case, spec)
    options = dict(mesh_size=spec.mesh_size, order=spec.order, material=case.material, sampling=sampling)
    key = designer.entry_key(spec.family, spec.p, **options)
    if catalogue.has_entry(path, key):
        with catalogue.open_catalogue(path) as cat:
            return cat.load(key), 0.0
    log(f"  designing {spec.family} {spec.p} h={spec.mesh_size} {case.material} {sampling or ''}")
    start = time.perf_counter()
    entry = designer.design_segment(spec.family, spec.p, **options, estimate_accuracy=False, executor="local",
                                    workers=2, name=f"{spec.family}-{key[:8]}")
    seconds = time.perf_counter() - start
    log(f"    {seconds:.0f} s, {entry.energy.coefficients.size} terms")
    catalogue.add_entry(path, entry)
    return entry, seconds


def runtime_model(case, entries: list, level: float):
    """The runtime model of ``case`` at ``level`` from ``entries`` (one per SegmentSpec, in order)."""
    loads = scaled_loads(case, level)
    n = case.n_segments
    data = {"catalogue": {"path": "unused.h5"},
            "segment": [{"type": "entry", "entry": e.name, "count": spec.count,
                         "vertebra": {"mass": case.vertebra_mass}} for spec, e in zip(case.segments, entries)],
            "effector": [{"name": "tip", "vertebra": -1}]}
    vertebrae = sorted(set(loads["forces"]) | set(loads["moments"]))
    data["load"] = [{"vertebra": k, "force": list(map(float, loads["forces"].get(k, np.zeros(3)))),
                     "moment": list(map(float, loads["moments"].get(k, np.zeros(3))))} for k in vertebrae]
    if loads["gravity"] is not None:
        data["gravity"] = {"vector": list(map(float, loads["gravity"]))}
    if loads["pressures"]:
        m = len(next(iter(loads["pressures"].values())))
        segments = sorted(loads["pressures"])
        if segments != list(range(n)) or any(not np.array_equal(loads["pressures"][s], loads["pressures"][0])
                                             for s in segments):
            raise ValueError(f"{case.name}: only one pressure per cavity along the whole trunk is written here")
        data["chamber"] = [{"name": f"c{k}", "cavity": k, "from": 1, "to": n,
                            "pressure": float(loads["pressures"][0][k]), "max_pressure": 2 * MAX_PRESSURE}
                           for k in range(m)]
    by_name = {e.name: e for e in entries}
    return solver.build_model(solver.parse_scene(data), by_name)


def rotation_angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def bend_deg(R: np.ndarray) -> float:
    """Angle between the tip's axis and the base's."""
    return math.degrees(math.acos(float(np.clip(R[2, 2], -1.0, 1.0))))


def ccx_tips(case_name: str) -> dict:
    """CalculiX tip positions by level (m), where the cross-check ran the case."""
    if not CCX.exists():
        return {}
    for case in json.loads(CCX.read_text())["cases"]:
        if case["name"] == case_name:
            return {float(level): np.asarray(v["positions"][-1], float)
                    for level, v in case.get("ccx_levels", {}).items() if v and v.get("positions")}
    return {}


def run_case(case, path: Path) -> dict:
    log(f"{case.name}: {case.description}")
    entries, design_s = [], {}
    for spec in case.segments:
        entry, seconds = designed(case, spec, path)
        entries.append(entry)
        design_s[entry.name] = {"seconds": seconds, "terms": int(entry.energy.coefficients.size),
                                "dofs": int(entry.mesh.get("dofs", 0)),
                                "held_out": entry.energy.fit_error.get("held_out", {})}
    linear = [dataclasses.replace(e, energy=None) for e in entries]
    reference = project_trunk(case)
    length = case.length
    ccx = ccx_tips(case.name)
    pneumatic = bool(case.pressures)
    rows, state = [], None
    for level in case.levels:
        if pneumatic and level * BAR > MAX_PRESSURE * (1 + 1e-12):
            break
        start = time.process_time()
        try:
            fe = reference.solve(trunk_loads(case, level), initial=state)
        except Exception as error:  # noqa: BLE001 - the reference's end (limit point) ends the case, reported
            log(f"  level {level}: full FE stopped ({type(error).__name__}: {str(error)[:120]})")
            rows.append({"level": level, "fe_failed": f"{type(error).__name__}: {str(error)[:200]}"})
            break
        fe_s = time.process_time() - start
        state = fe.state
        R_fe = fe.rotations[-1]
        row = {"level": level, "fe_tip_rotation_deg": rotation_angle_deg(R_fe), "fe_bend_deg": bend_deg(R_fe),
               "fe_cpu_s": fe_s}
        if pneumatic:
            row["fe_volume_growth"] = float(sum(v[0] for v in fe.volume_growth))
        for kind, chosen in (("nonlinear", entries), ("linear", linear)):
            model = runtime_model(case, chosen, level)
            start = time.process_time()
            result = model.solve(raise_on_failure=False)
            seconds = time.process_time() - start
            tip = result.state.positions[-1]
            R = lie.qmatrix(result.state.quaternions[-1:])[0]
            out = {"converged": bool(result.converged), "solve_cpu_s": seconds,
                   "tip_error_pct": 100 * float(np.linalg.norm(tip - fe.positions[-1])) / length,
                   "tip_rotation_error_deg": rotation_angle_deg(R @ R_fe.T),
                   "out_of_range": len(result.out_of_range)}
            if level in ccx:
                out["tip_error_vs_ccx_pct"] = 100 * float(np.linalg.norm(tip - ccx[level])) / length
            if pneumatic:
                growth = float(model.chamber_volume_growth(result.state, model.default_actuation[model.n_cables:])[0])
                out["bend_error_pct"] = 100 * (bend_deg(R) / row["fe_bend_deg"] - 1)
                out["volume_error_pct"] = 100 * (growth / row["fe_volume_growth"] - 1)
            row[kind] = out
        rows.append(row)
        nl, li = row["nonlinear"], row["linear"]
        extra = (f", bend {nl['bend_error_pct']:+.2f} %, volume {nl['volume_error_pct']:+.2f} %" if pneumatic else "")
        log(f"  level {level} ({row['fe_tip_rotation_deg']:.1f}°): nonlinear {nl['tip_error_pct']:.4f} %{extra} "
            f"(range {nl['out_of_range']}), linear {li['tip_error_pct']:.3f} %")
    return {"name": case.name, "description": case.description, "material": case.material,
            "segments": case.n_segments, "length_m": length, "tags": list(case.tags),
            "level_unit": case.level_unit, "entries": design_s, "rows": rows, "verdict": verdict(rows, pneumatic)}


def verdict(rows: list, pneumatic: bool) -> dict:
    """Is every solved level within the acceptance limits (see the module docstring)?"""
    failures = []
    for row in rows:
        if "nonlinear" not in row:
            continue
        nl = row["nonlinear"]
        if not nl["converged"]:
            failures.append(f"level {row['level']}: runtime did not converge")
            continue
        if pneumatic:
            checks = (("tip", nl["tip_error_pct"], 0.2), ("bend", abs(nl["bend_error_pct"]), 1.0),
                      ("volume", abs(nl["volume_error_pct"]), 1.0))
        else:
            allowed = next((limit for angle, limit in LIMITS if row["fe_tip_rotation_deg"] <= angle), None)
            if allowed is None:
                continue                # beyond 90°: reported, not judged
            checks = (("tip", nl["tip_error_pct"], allowed),)
        failures += [f"level {row['level']}: {name} {value:.3g} % > {limit} %" for name, value, limit in checks
                     if value > limit]
    return {"met": not failures, "failures": failures}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--entries", type=Path, default=Path(tempfile.gettempdir()) / "vertebra-acceptance",
                        help="directory of the designed entries' catalogue (kept between runs)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--nonlinear-mesh-size", type=float, default=None, metavar="H",
                        help="multi-fidelity entries: their nonlinear part sampled on this coarser mesh (m)")
    args = parser.parse_args(argv)
    if args.nonlinear_mesh_size is not None:
        NONLINEAR_MESH["nonlinear_mesh_size"] = args.nonlinear_mesh_size
    args.entries.mkdir(parents=True, exist_ok=True)
    path = args.entries / "entries.h5"
    document = {"meta": {"date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
                         "host": platform.node(), "python": platform.python_version(), "version": __version__,
                         "load": os.getloadavg()[0]}, "cases": []}
    for name in args.cases:
        document["cases"].append(run_case(CASES[name], path))
        render.write("nonlinear_acceptance", document, args.out)
    print(render.markdown("nonlinear_acceptance", document))
    return 0 if all(c["verdict"]["met"] for c in document["cases"]) else 1


if __name__ == "__main__":
    sys.exit(main())
