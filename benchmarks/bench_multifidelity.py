"""Multi-fidelity nonlinear entries: ψ ≈ ψ_lin (entry's mesh) + ψ_nl (a coarser mesh).

The nonlinear part of a segment's energy is sampled and fitted on a coarser mesh of the same
segment (``sampling.nonlinear_mesh_size``, ``vertebra design --nonlinear-mesh-size``), the
linear part is the entry mesh's exact condensation, and the entry's held-out error is measured
on a few loading paths solved with the FE of the entry's mesh. Sections (all by default):

``design``
    The neo-Hookean P2 rod (R 10 mm, L 40 mm, E 1 MPa, ν 0.3) at ``--fine`` mm: the full entry
    (everything on the fine mesh) and multi-fidelity entries with the nonlinear part from each
    of ``--coarse`` mm, plus the coarse meshes' own full entries; each design a fresh process on
    the local pool of ``--workers`` workers, alternated over ``--rounds`` rounds (a shared
    machine's load hits all alike: compare ratios within the run). Per design: wall and CPU
    seconds (workers included), FE solves, held-out load error (multi-fidelity: on the fine
    mesh's check paths; the coarse sampling's own as well).
``trunk``
    Four of these rods under a dead tip force along (1, 0, −1) at ``LEVELS``: the tip error in %
    of the trunk length of the runtime trunk built from each entry against the full nonlinear
    FE of the trunk on the fine mesh (rigid vertebrae), cached in ``--cache``.
``large``
    A multi-fidelity entry on ``--large`` mm (47k DoFs at 1.83 mm) with the nonlinear part
    from ``--large-coarse`` mm: design time and the held-out check on the large mesh.
``chambered``
    The CBHA-like slice of the acceptance study (outer radius 40 mm, 3 chambers r 10 mm at
    21.5 mm, L 30 mm, E 0.5 MPa, ν 0.45, sampled to 1.5 bar at 95 % of the limit) at
    ``--cbha-fine`` mm with the nonlinear part from ``--cbha-coarse`` mm: the check on the
    fine mesh (held-out paths and the inflation path), its verdict by the default rule
    (``designer.multifidelity.check_verdict``), the cost. The trunk built from such entries:
    ``benchmarks/bench_nonlinear_acceptance.py --cases cbha4_pneumatic_nh --nonlinear-mesh-size H``.
    For comparison, the full entry at ``--cbha-fine`` mm (designed once into ``--cache``): its
    own free inflation response errors, on its inflation path.

Results: benchmarks/results/multifidelity.json and .md (each row saved as it finishes).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_multifidelity [SECTION ...] \\
        [--fine 3.5] [--coarse 8 5] [--rounds 1] [--large 1.83] [--large-coarse 3.5] [--workers 2]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, loadavg, log, machine  # noqa: E402

ROD = dict(radius=0.01, length=0.04, youngs_modulus=1e6, poisson_ratio=0.3)
MATERIAL = "neo_hookean"
OUT = RESULTS / "multifidelity.json"
CACHE = Path(__file__).resolve().parents[1] / "tmp" / "cache"
SEGMENTS = 4
FORCE = np.array([1.2, 0.0, -1.2])      # N at the tip at level 1 (dead, planar)
LEVELS = (0.15, 0.32, 0.47, 0.72)


# ------------------------------------------------------------------ one design (a fresh process)

def sampling_of(coarse_mm: float | None) -> dict:
    return {} if coarse_mm is None else {"nonlinear_mesh_size": coarse_mm / 1000.0}


def design(mesh_mm: float, coarse_mm: float | None, workers: int, catalogue_path: str) -> dict:
    """Design one entry here, add it to ``catalogue_path`` and return what it cost."""
    from vertebra import designer
    from vertebra.store import catalogue

    self0, children0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    load0, start = loadavg(), time.perf_counter()
    entry = designer.design_segment("rod", ROD, mesh_size=mesh_mm / 1000.0, order=2, material=MATERIAL,
                                    sampling=sampling_of(coarse_mm), estimate_accuracy=False, executor="local",
                                    workers=workers,
                                    progress=lambda m: log(f"  [{time.perf_counter() - start:7.1f} s] {m}"))
    wall = time.perf_counter() - start
    self1, children1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = sum(b.ru_utime + b.ru_stime - a.ru_utime - a.ru_stime for a, b in ((self0, self1), (children0, children1)))
    catalogue.add_entry(catalogue_path, entry)
    energy = entry.energy
    held = {k: v for k, v in energy.fit_error.get("held_out", {}).items() if k != "by_level"}
    own = {k: v for k, v in energy.fit_error.get("nonlinear_mesh_held_out", {}).items() if k != "by_level"}
    check = energy.sampling.get("entry_mesh_check", {})
    return {"mesh_mm": mesh_mm, "coarse_mm": coarse_mm, "key": entry.key, "dofs": int(entry.mesh["dofs"]),
            "nonlinear_dofs": energy.sampling.get("nonlinear_mesh", {}).get("dofs", int(entry.mesh["dofs"])),
            "wall_s": wall, "cpu_s": cpu, "load_before": load0, "load_after": loadavg(),
            "timings": {k: float(v) for k, v in entry.timings.items()},
            "solves": int(energy.sampling.get("solves", 0)), "check_solves": int(check.get("solves", 0)),
            "check_paths": check.get("paths"), "check_stopped": check.get("stopped"),
            "held_out": held, "nonlinear_mesh_held_out": own or None,
            "limit_pressure": energy.range.limit_pressure}


def _child(mesh_mm: float, coarse_mm: float | None, workers: int, catalogue_path: Path) -> dict:
    code = ("import json; from benchmarks.bench_multifidelity import design; "
            f"print('ROW', json.dumps(design({mesh_mm!r}, {coarse_mm!r}, {workers!r}, {str(catalogue_path)!r}), "
            "default=float))")
    done = subprocess.run([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                          cwd=str(Path(__file__).resolve().parents[1]))      # progress on our stderr
    rows = [line[4:] for line in done.stdout.splitlines() if line.startswith("ROW ")]
    if done.returncode or not rows:
        raise RuntimeError(f"design {mesh_mm} mm (nonlinear {coarse_mm}) failed (its messages above)")
    return json.loads(rows[-1])


# ------------------------------------------------------------------ results

def _load() -> dict:
    return json.loads(OUT.read_text()) if OUT.exists() else {}


def _save(results: dict, section: str) -> None:
    """Write ``section`` of ``results``, keeping the other sections as another run saved them."""
    merged = _load()
    merged[section] = results[section]
    merged["machine"] = machine()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(merged, indent=1, default=float) + "\n")
    OUT.with_suffix(".md").write_text(markdown(merged))
    log(f"wrote {OUT} and {OUT.with_suffix('.md')}")


def label(row: dict) -> str:
    return (f"{row['mesh_mm']:g} mm" if row["coarse_mm"] is None
            else f"{row['mesh_mm']:g} mm + ψ_nl from {row['coarse_mm']:g} mm")


# ------------------------------------------------------------------ sections

def section_design(results: dict, fine: float, coarse: list, rounds: int, workers: int, cache: Path) -> None:
    plan = [(fine, None)] + [(fine, c) for c in coarse] + [(c, None) for c in coarse]
    runs = {label({"mesh_mm": m, "coarse_mm": c}): [] for m, c in plan}
    results["design"] = {"fine_mm": fine, "workers": workers, "runs": runs}
    for r in range(rounds):
        for mesh_mm, coarse_mm in plan:
            name = label({"mesh_mm": mesh_mm, "coarse_mm": coarse_mm})
            log(f"round {r + 1}/{rounds}: {name}")
            row = _child(mesh_mm, coarse_mm, workers, cache / f"multifidelity-round{r}.h5")
            runs[name].append(row)
            log(f"  wall {row['wall_s']:.1f} s, cpu {row['cpu_s']:.1f} s, held-out {row['held_out'].get('load_max')}")
            _save(results, "design")


def ratios(design_results: dict) -> dict:
    """Per entry, the full fine entry's wall and CPU time over its own (median over the rounds
    both ran in)."""
    runs = design_results["runs"]
    full = runs.get(label({"mesh_mm": design_results["fine_mm"], "coarse_mm": None}), [])
    return {name: {key: float(np.median([f[key] / o[key] for f, o in zip(full, rows)])) for key in ("wall_s", "cpu_s")}
            for name, rows in runs.items() if rows and full and rows is not full}


def _reference(fine_mm: float, cache: Path) -> list:
    """The full nonlinear FE of the four-rod trunk on the fine mesh at every level (cached)."""
    from vertebra.designer.nonlinear.fe_trunk import NonlinearTrunk, TrunkLoads
    from vertebra.designer.nonlinear_condensation import FamilySolid
    from vertebra.designer.families import canonical_parameters, family_of

    spec = FamilySolid("rod", json.dumps(canonical_parameters(family_of("rod"), ROD), sort_keys=True),
                       fine_mm / 1000.0, 2, MATERIAL)
    path = cache / "multifidelity-references.json"
    data = json.loads(path.read_text()) if path.exists() else {}
    key = hashlib.sha256(json.dumps([spec.key(), SEGMENTS, FORCE.tolist(), LEVELS]).encode()).hexdigest()[:24]
    if key in data:
        return data[key]
    trunk = NonlinearTrunk([spec.build()] * SEGMENTS)
    rows, state = [], None
    for level in LEVELS:
        start = time.perf_counter()
        response = trunk.solve(TrunkLoads(forces={SEGMENTS: level * FORCE}), initial=state)
        state = response.state
        R = response.rotations[-1]
        rows.append({"level": level, "tip": response.positions[-1].tolist(), "rotation": R.tolist(),
                     "angle_deg": math.degrees(math.acos(float(np.clip(R[2, 2], -1.0, 1.0)))),
                     "seconds": time.perf_counter() - start, "load": loadavg()})
        log(f"  full FE ({fine_mm} mm) at level {level}: {rows[-1]['angle_deg']:.1f}°, {rows[-1]['seconds']:.0f} s")
    data[key] = rows
    path.write_text(json.dumps(data))
    return rows


def section_trunk(results: dict, fine: float, cache: Path) -> None:
    from vertebra import solver
    from vertebra.store import catalogue

    design_rows = _load().get("design", {}).get("runs", {})
    if not design_rows:
        raise SystemExit("the trunk section needs the design section's entries (run `design` first)")
    reference = _reference(fine, cache)
    length = SEGMENTS * ROD["length"]
    rows = []
    for name, runs in design_rows.items():
        first = runs[0]
        with catalogue.open_catalogue(cache / "multifidelity-round0.h5") as cat:
            entry = cat.load(first["key"])
        errors = []
        for ref in reference:
            data = {"catalogue": {"path": "unused.h5"}, "solver": {"tolerance": 1e-10},
                    "segment": [{"type": "entry", "entry": entry.name, "count": SEGMENTS}],
                    "load": [{"vertebra": SEGMENTS, "force": list(map(float, ref["level"] * FORCE))}],
                    "effector": [{"name": "tip", "vertebra": -1}]}
            model = solver.build_model(solver.parse_scene(data), {entry.name: entry})
            result = model.solve(raise_on_failure=False)
            tip = result.state.positions[-1]
            errors.append({"level": ref["level"], "angle_deg": ref["angle_deg"], "converged": bool(result.converged),
                           "out_of_range": len(result.out_of_range),
                           "tip_error_pct": 100 * float(np.linalg.norm(tip - np.asarray(ref["tip"]))) / length})
        rows.append({"entry": name, "dofs": first["dofs"], "nonlinear_dofs": first["nonlinear_dofs"],
                     "levels": errors})
        log(f"  {name}: " + ", ".join(f"{e['angle_deg']:.0f}°: {e['tip_error_pct']:.4f} %" for e in errors))
    results["trunk"] = {"fine_mm": fine, "segments": SEGMENTS, "force_N": FORCE.tolist(), "rows": rows,
                        "reference_seconds": [r["seconds"] for r in reference]}
    _save(results, "trunk")


def section_large(results: dict, large: float, coarse: float, workers: int, cache: Path) -> None:
    log(f"multi-fidelity entry at {large} mm with the nonlinear part from {coarse} mm")
    row = _child(large, coarse, workers, cache / "multifidelity-large.h5")
    results["large"] = {"rows": results.get("large", {}).get("rows", []) + [row]}   # every run kept
    _save(results, "large")


CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)


def section_chambered(results: dict, fine: float, coarse: float, workers: int, cache: Path) -> None:
    from vertebra import designer
    from vertebra.designer import multifidelity

    log(f"CBHA-like slice at {fine} mm with the nonlinear part from {coarse} mm")
    self0, children0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    load0, start = loadavg(), time.perf_counter()
    entry = designer.design_segment("pneumatic", CBHA, mesh_size=fine / 1e3, material=MATERIAL,
                                    estimate_accuracy=False, sampling={"pressure": 1.5e5, "limit_fraction": 0.95},
                                    nonlinear_mesh_size=coarse / 1e3, executor="local", workers=workers,
                                    progress=lambda m: log(f"  [{time.perf_counter() - start:7.1f} s] {m}"))
    wall = time.perf_counter() - start
    self1, children1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    energy = entry.energy
    check = energy.sampling["entry_mesh_check"]
    passed, why = multifidelity.check_verdict({**check, "held": energy.fit_error["held_out"]},
                                              energy.fit_error["nonlinear_mesh_held_out"], None)

    def strip(held: dict) -> dict:
        return {k: v for k, v in held.items() if k != "by_level"}

    results["chambered"] = {
        "fine_mm": fine, "coarse_mm": coarse, "dofs": int(entry.mesh["dofs"]),
        "nonlinear_dofs": int(energy.sampling["nonlinear_mesh"]["dofs"]), "wall_s": wall,
        "cpu_s": sum(b.ru_utime + b.ru_stime - a.ru_utime - a.ru_stime
                     for a, b in ((self0, self1), (children0, children1))),
        "load_before": load0, "load_after": loadavg(), "check": check,
        "held_out": strip(energy.fit_error["held_out"]),
        "nonlinear_mesh_held_out": strip(energy.fit_error["nonlinear_mesh_held_out"]),
        "limit_pressure": energy.range.limit_pressure, "ramp_mesh_size": energy.sampling.get("ramp_mesh_size"),
        "default_rule": {"passed": passed, "why": why}, "timings": dict(entry.timings)}
    results["chambered"]["full_entry_inflation"] = _full_inflation(fine, workers, cache)
    _save(results, "chambered")


def _full_inflation(fine: float, workers: int, cache: Path) -> dict:
    """The free inflation response errors of the full CBHA-like entry at ``fine`` mm on its own
    inflation path (the entry designed once into ``cache``)."""
    from vertebra import designer
    from vertebra.core.energy import linear_terms
    from vertebra.designer.energy_fit import FitResult, inflation_errors
    from vertebra.designer.energy_sampling import LoadBox, SamplingSettings, path_endpoints, pressure_path, run_paths
    from vertebra.designer.nonlinear_condensation import FamilySolid, _tasks
    from vertebra.store import catalogue

    options = dict(mesh_size=fine / 1e3, material=MATERIAL, sampling={"pressure": 1.5e5, "limit_fraction": 0.95})
    key = designer.entry_key("pneumatic", CBHA, **options)
    path = cache / "multifidelity-chambered-full.h5"
    if catalogue.has_entry(path, key):
        with catalogue.open_catalogue(path) as cat:
            entry = cat.load(key)
    else:
        log(f"the full CBHA-like entry at {fine} mm")
        entry = designer.design_segment("pneumatic", CBHA, estimate_accuracy=False, executor="local",
                                        workers=workers, **options)
        catalogue.add_entry(path, entry)
    energy = entry.energy
    settings = SamplingSettings.from_dict(energy.sampling["settings"]).resolved(entry.n_cavities, MATERIAL)
    spec = FamilySolid(family="pneumatic", parameters=json.dumps(entry.parameters, sort_keys=True),
                       mesh_size=fine / 1e3, order=2, material=MATERIAL)
    linear = linear_terms(entry.compliance, entry.rest_translation)
    endpoints, _ = path_endpoints(entry.n_cavities, settings)
    task = _tasks(spec, entry, linear, LoadBox(**energy.sampling["load_box"]),
                  np.array(energy.sampling["pose_caps"], dtype=float), endpoints, settings, 1,
                  indices=[pressure_path(entry.n_cavities, settings)])[0]
    fit = FitResult(exponents=energy.exponents, coefficients=energy.coefficients, scales=energy.scales, unknowns=0,
                    errors={}, fold=energy.fold_pressure)
    return inflation_errors(fit, linear, run_paths(task).samples, 0)


# ------------------------------------------------------------------ report

def _err(held: dict | None) -> str:
    return "–" if not held else f"{held.get('load_max', math.nan):.3g}"


def _inflation(inflation: dict | None) -> str:
    """The free inflation response's errors of a chambered check, as a sentence."""
    if not inflation:
        return ""
    fine, own = inflation.get("entry_mesh", {}), inflation.get("nonlinear_mesh", {})
    return (f" Free inflation response: pose error {fine.get('pose_max', math.nan):.3g}, volume growth error "
            f"{fine.get('volume_max', math.nan):.3g} on the fine mesh; {own.get('pose_max', math.nan):.3g} and "
            f"{own.get('volume_max', math.nan):.3g} on the coarse mesh's own path.")


def markdown(results: dict) -> str:
    machine = results.get("machine", {})
    lines = ["# Multi-fidelity nonlinear entries", "",
             f"Machine {machine.get('host')} ({machine.get('cores')} cores), {machine.get('date')}; load averages "
             "per row (a shared machine: compare ratios within one run).", ""]
    if "design" in results:
        d = results["design"]
        lines += [f"## Design cost and held-out error (P2 rod, {d['workers']} local workers, fresh process each)", "",
                  "| entry | DoFs (nonlinear part) | wall s | CPU s | FE solves (+ check) | held-out load error "
                  "(entry mesh) | on the nonlinear mesh | linear entry | load 1/5/15 min |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, rows in d["runs"].items():
            for row in rows:
                lines.append(f"| {name} | {row['dofs']:,} ({row['nonlinear_dofs']:,}) | {row['wall_s']:.0f} | "
                             f"{row['cpu_s']:.0f} | {row['solves']} (+{row['check_solves']}) | "
                             f"{_err(row['held_out'])} | {_err(row['nonlinear_mesh_held_out'])} | "
                             f"{row['held_out'].get('linear_load_max', math.nan):.3g} | {row['load_before']} |")
        for name, ratio in ratios(d).items():
            lines.append(f"\nFull {d['fine_mm']:g} mm entry / {name}: wall {ratio['wall_s']:.2f}×, "
                         f"CPU {ratio['cpu_s']:.2f}× (median over rounds).")
        lines.append("")
    if "trunk" in results:
        t = results["trunk"]
        ref = t["rows"][0]["levels"] if t["rows"] else []
        lines += [f"## {t['segments']}-rod trunk, dead tip force {t['force_N']} N × level, against the full "
                  f"nonlinear FE on the {t['fine_mm']:g} mm mesh", "",
                  "| entry | " + " | ".join(f"{lv['angle_deg']:.0f}°" for lv in ref) + " |",
                  "|---|" + "---|" * len(ref)]
        for row in t["rows"]:
            lines.append(f"| {row['entry']} | " + " | ".join(
                f"{lv['tip_error_pct']:.4f} %" + ("" if lv["converged"] else " (not converged)")
                for lv in row["levels"]) + " |")
        lines += ["", "Tip error in % of the trunk length; reference seconds per level: "
                  + ", ".join(f"{s:.0f}" for s in t["reference_seconds"]), ""]
    if "large" in results:
        lines += ["## Large mesh", "", "| entry | DoFs (nonlinear part) | wall s | CPU s | FE solves (+ check) | "
                  "held-out load error (entry mesh) | on the nonlinear mesh | linear entry | load |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for row in results["large"]["rows"]:
            lines.append(f"| {label(row)} | {row['dofs']:,} ({row['nonlinear_dofs']:,}) | {row['wall_s']:.0f} | "
                         f"{row['cpu_s']:.0f} | {row['solves']} (+{row['check_solves']}) | {_err(row['held_out'])} | "
                         f"{_err(row['nonlinear_mesh_held_out'])} | "
                         f"{row['held_out'].get('linear_load_max', math.nan):.3g} | {row['load_before']} |")
        lines.append("")
    if "chambered" in results:
        c = results["chambered"]
        held, own = c["held_out"], c["nonlinear_mesh_held_out"]
        lines += [f"## CBHA-like slice at {c['fine_mm']:g} mm, nonlinear part from {c['coarse_mm']:g} mm", "",
                  f"{c['dofs']:,} DoFs ({c['nonlinear_dofs']:,} in the nonlinear part); {c['wall_s']:.0f} s wall, "
                  f"{c['cpu_s']:.0f} s CPU at load {c['load_before']} → {c['load_after']}; check paths "
                  f"{c['check']['paths']} ({c['check']['solves']} solves on the fine mesh). Held-out on the fine mesh: "
                  f"load {held['load_max']:.3g}, volume {held.get('volume_max', math.nan):.3g}; the coarse fit's own: "
                  f"load {own['load_max']:.3g}, volume {own.get('volume_max', math.nan):.3g}. Default rule: "
                  f"{'passed' if c['default_rule']['passed'] else 'failed'} ({c['default_rule']['why']})."
                  + _inflation(c["check"].get("inflation"))
                  + (f" The full {c['fine_mm']:g} mm entry's own: pose {c['full_entry_inflation']['pose_max']:.3g}, "
                     f"volume {c['full_entry_inflation']['volume_max']:.3g}." if "full_entry_inflation" in c else ""),
                  ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sections", nargs="*", help="design, trunk, large, chambered (default: all)")
    parser.add_argument("--fine", type=float, default=3.5, help="mm")
    parser.add_argument("--coarse", type=float, nargs="+", default=[8.0, 5.0], help="mm")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--large", type=float, default=1.83, help="mm")
    parser.add_argument("--large-coarse", type=float, default=3.5, help="mm")
    parser.add_argument("--cbha-fine", type=float, default=12.0, help="mm")
    parser.add_argument("--cbha-coarse", type=float, default=16.0, help="mm")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=CACHE)
    args = parser.parse_args(argv)
    sections = args.sections or ["design", "trunk", "large", "chambered"]
    unknown = sorted(set(sections) - {"design", "trunk", "large", "chambered"})
    if unknown:
        parser.error(f"unknown section {unknown[0]!r} (known: design, trunk, large, chambered)")
    args.cache.mkdir(parents=True, exist_ok=True)
    results = _load()
    if "design" in sections:
        section_design(results, args.fine, args.coarse, args.rounds, args.workers, args.cache)
    if "trunk" in sections:
        section_trunk(results, args.fine, args.cache)
    if "large" in sections:
        section_large(results, args.large, args.large_coarse, args.workers, args.cache)
    if "chambered" in sections:
        section_chambered(results, args.cbha_fine, args.cbha_coarse, args.workers, args.cache)
    print(markdown(_load()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
