"""Design cost of nonlinear entries: what one entry costs at production meshes.

Sections (all by default; name some to run only those):

``ab``
    Old against new code on one entry (neo-Hookean P2 rod, R 10 mm, L 40 mm, E 1 MPa, ν 0.3, at
    ``--ab-mesh``), each design a fresh process, serial executor, alternated (old, new, old,
    new …) so that a shared machine's load hits both alike. Per run: wall and CPU seconds, FE
    solves, assemblies (with and without tangent, energy-only), factorizations and factor
    applications (right-hand sides), the held-out fit error. Needs ``--baseline DIR``: a
    directory holding the old code as a ``vertebra`` package (``git archive <commit>``).
``rod``
    One neo-Hookean rod entry per mesh size (``--rod-meshes``, mm), default sampling, the local
    pool of ``--workers`` workers: wall and CPU seconds (the workers' included), DoFs, solves,
    held-out error; the growth exponent of the design time with the DoFs (least squares on
    log-log).
``cbha``
    The CBHA-like pneumatic slice (outer radius 40 mm, 3 chambers r 10 mm at 21.5 mm, L 30 mm,
    E 0.5 MPa, ν 0.45) at ``--cbha-mesh`` (P2, neo-Hookean, default sampling): the same numbers
    plus the inflation-limit ramp's solves and seconds.
``growth``
    The ``rod`` section's entries by the default path of ``vertebra design`` (above
    ``designer.multifidelity.AUTO_DOFS`` the nonlinear part on the chosen coarser mesh, checked
    on the entry's mesh), e.g. ``--rod-meshes 8 5 3.5 1.83``: the growth exponent of the default
    path; each run kept under ``--label`` (growth, growth-2, …).

Each finished row is saved at once (benchmarks/results/designcost.json and .md), so a long run
that is stopped keeps what it measured. Record the machine's load with the numbers: on a
shared machine compare the ``ab`` ratios, not wall times across runs.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_designcost [SECTION ...] \\
        [--baseline /tmp/old] [--rounds 2] [--rod-meshes 8 5 3.5] [--cbha-mesh 6] [--workers 2] [--label growth]
"""

from __future__ import annotations

import argparse
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
CBHA = dict(outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215, length=0.03, chambers=3,
            youngs_modulus=5e5, poisson_ratio=0.45)
FAMILIES = {"rod": ("rod", ROD), "cbha": ("pneumatic", CBHA)}
#: the issue's measurements before this work (docs/trade.md (a), 2 workers, load 4-9): DoFs → seconds
BEFORE = {"rod": [(1101, 12.0), (3696, 93.0), (8436, 308.0)]}
OUT = RESULTS / "designcost.json"

# ------------------------------------------------------------------ one design (run in a fresh process for `ab`)

_COUNTS = {"assemblies_tangent": 0, "assemblies_gradient": 0, "energy_evaluations": 0, "factorizations": 0,
           "factor_applications": 0, "factor_columns": 0}


def _count_operations() -> None:
    """Count the nonlinear FE's expensive operations (assemblies by order, factorizations, factor
    applications) by wrapping the classes both old and new code share."""
    from vertebra.designer import linsolve
    from vertebra.designer.nonlinear import fe_assembly, krylov

    evaluate = fe_assembly.SolidModel.evaluate
    names = {0: "energy_evaluations", 1: "assemblies_gradient", 2: "assemblies_tangent"}

    def counted_evaluate(self, u, pressures=None, order=2):
        _COUNTS[names[order]] += 1
        return evaluate(self, u, pressures, order)

    refactor = krylov.ReusedFactorSolver.refactor

    def counted_refactor(self, A):
        _COUNTS["factorizations"] += 1
        return refactor(self, A)

    apply = linsolve.DirectFactor.apply

    def counted_apply(self, B):
        _COUNTS["factor_applications"] += 1
        _COUNTS["factor_columns"] += 1 if np.ndim(B) == 1 else int(np.shape(B)[1])
        return apply(self, B)

    fe_assembly.SolidModel.evaluate = counted_evaluate
    krylov.ReusedFactorSolver.refactor = counted_refactor
    linsolve.DirectFactor.apply = counted_apply


def design(family: str, mesh_mm: float, executor: str, workers: int | None, count: bool = False) -> dict:
    """Design one nonlinear entry here and return what it cost."""
    from vertebra import designer

    if count:
        _count_operations()
    name, parameters = FAMILIES[family]
    self0, children0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    load0, start = loadavg(), time.perf_counter()
    entry = designer.design_segment(name, parameters, mesh_size=mesh_mm / 1000.0, order=2, material="neo_hookean",
                                    estimate_accuracy=False, executor=executor, workers=workers,
                                    progress=lambda m: log(f"  [{time.perf_counter() - start:7.1f} s] {m}"))
    wall = time.perf_counter() - start
    self1, children1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = sum(b.ru_utime + b.ru_stime - a.ru_utime - a.ru_stime
              for a, b in ((self0, self1), (children0, children1)))
    energy = entry.energy
    sampling = energy.sampling
    row = {"family": family, "mesh_mm": mesh_mm, "dofs": int(entry.mesh["dofs"]), "executor": executor,
           "workers": workers, "wall_s": wall, "cpu_s": cpu, "load_before": load0, "load_after": loadavg(),
           "sampling_s": float(entry.timings.get("sampling_s", 0.0)), "fit_s": float(entry.timings.get("fit_s", 0.0)),
           "solves": int(sampling.get("solves", 0)), "paths": int(sampling.get("paths", 0)),
           "ramp_solves": sampling.get("ramp_solves"), "ramp_s": sampling.get("ramp_s"),
           "limit_pressure": energy.range.limit_pressure, "terms": int(energy.coefficients.size),
           "held_out": energy.fit_error.get("held_out", {}),
           "nonlinear_mesh": sampling.get("nonlinear_mesh"), "entry_mesh_check": sampling.get("entry_mesh_check"),
           "nonlinear_mesh_fallback": sampling.get("nonlinear_mesh_fallback"),
           "nonlinear_mesh_held_out": energy.fit_error.get("nonlinear_mesh_held_out"),
           "timings": {k: float(v) for k, v in entry.timings.items()}}
    if count:
        row["operations"] = dict(_COUNTS)
    return row


# ------------------------------------------------------------------ sections

def _load() -> dict:
    return json.loads(OUT.read_text()) if OUT.exists() else {}


def _save(results: dict) -> None:
    """Write the results, keeping the sections another run saved meanwhile (sections run in
    parallel processes each own theirs)."""
    for key, value in _load().items():
        results.setdefault(key, value)
    results["machine"] = machine()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(results, indent=1, default=float) + "\n")
    OUT.with_suffix(".md").write_text(markdown(results))
    log(f"wrote {OUT} and {OUT.with_suffix('.md')}")


def _child(tree: Path, mesh_mm: float) -> dict:
    """One serial design in a fresh interpreter whose ``vertebra`` is the one under ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    code = ("import json, sys; from benchmarks.bench_designcost import design; "
            f"print('ROW', json.dumps(design('rod', {mesh_mm!r}, 'serial', None, count=True), default=float))")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          cwd=str(Path(__file__).resolve().parents[1]))
    rows = [line[4:] for line in done.stdout.splitlines() if line.startswith("ROW ")]
    if done.returncode or not rows:
        raise RuntimeError(f"design under {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(rows[-1])


def section_ab(results: dict, baseline: Path, rounds: int, mesh_mm: float) -> None:
    import vertebra

    new_tree = Path(vertebra.__file__).parents[1]                       # the directory holding this vertebra/
    if not (baseline / "vertebra").is_dir():
        raise SystemExit(f"--baseline {baseline}: no vertebra package there")
    runs = {"old": [], "new": []}
    for r in range(rounds):
        for label, tree in (("old", baseline), ("new", new_tree)):
            log(f"ab round {r + 1}/{rounds}: {label} ({tree})")
            row = _child(tree, mesh_mm)
            runs[label].append(row)
            log(f"  wall {row['wall_s']:.1f} s, cpu {row['cpu_s']:.1f} s, {row['operations']}")
    ratio = {key: float(np.median([o[key] / n[key] for o, n in zip(runs["old"], runs["new"])]))
             for key in ("wall_s", "cpu_s")}
    ops = {key: runs["old"][0]["operations"][key] / max(runs["new"][0]["operations"][key], 1)
           for key in runs["new"][0]["operations"]}
    results["ab"] = {"mesh_mm": mesh_mm, "baseline": str(baseline), "runs": runs, "median_ratio_old_over_new": ratio,
                     "operations_ratio_old_over_new": ops}
    _save(results)


def _exponent(rows: list) -> float | None:
    pts = [(r["dofs"], r["wall_s"]) for r in rows]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def section_rod(results: dict, meshes: list, workers: int, label: str = "rod") -> None:
    rows = [r for r in results.get(label, {}).get("rows", []) if r["mesh_mm"] not in meshes]
    for h in meshes:
        log(f"rod entry at {h} mm on {workers} local workers")
        rows.append(design("rod", h, "local", workers))
        rows.sort(key=lambda r: r["dofs"])
        results[label] = {"rows": rows, "exponent_wall": _exponent(rows),
                          "exponent_cpu": _exponent([dict(r, wall_s=r["cpu_s"]) for r in rows]),
                          "before": BEFORE["rod"]}
        _save(results)


def section_cbha(results: dict, mesh_mm: float, workers: int) -> None:
    log(f"CBHA-like slice at {mesh_mm} mm on {workers} local workers")
    rows = [r for r in results.get("cbha", {}).get("rows", []) if r["mesh_mm"] != mesh_mm]
    rows.append(design("cbha", mesh_mm, "local", workers))
    results["cbha"] = {"rows": sorted(rows, key=lambda r: r["dofs"])}
    _save(results)


# ------------------------------------------------------------------ report

def _held(row: dict) -> str:
    held = row.get("held_out", {})
    text = f"{held.get('load_max', math.nan):.3g}"
    if "volume_max" in held:
        text += f" (volume {held['volume_max']:.3g})"
    return text


def _coarse(row: dict) -> str:
    """The nonlinear mesh of a row: none (the entry's), the one kept (its check's seconds), or the
    one dropped after a failed check."""
    mesh, fallback = row.get("nonlinear_mesh"), row.get("nonlinear_mesh_fallback")
    if fallback:
        return (f"{fallback['nonlinear_mesh']['mesh_size'] * 1e3:.3g} mm dropped: "
                f"{fallback['entry_mesh_check']['verdict']['why']}")
    if not mesh:
        return "–"
    own = (row.get("nonlinear_mesh_held_out") or {}).get("load_max", math.nan)
    return (f"{mesh['mesh_size'] * 1e3:.3g} mm, {mesh['dofs']:,} DoFs, own held-out {own:.3g} "
            f"(check {row.get('timings', {}).get('check_s', math.nan):.0f} s)")


def markdown(results: dict) -> str:
    lines = ["# Design cost of nonlinear entries", ""]
    machine = results.get("machine", {})
    lines += [f"Machine {machine.get('host')} ({machine.get('cores')} cores), {machine.get('date')}; load averages "
              f"are recorded per row (a shared machine: compare ratios measured in one run).", ""]
    if "ab" in results:
        ab = results["ab"]
        lines += [f"## Old against new code, one rod entry at {ab['mesh_mm']} mm (serial, alternated runs)", "",
                  "| run | wall s | CPU s | solves | tangent assemblies | energy-only | factorizations | "
                  "factor columns | held-out load error |", "|---|---|---|---|---|---|---|---|---|"]
        for label in ("old", "new"):
            for i, row in enumerate(ab["runs"][label]):
                o = row["operations"]
                lines.append(f"| {label} {i + 1} | {row['wall_s']:.1f} | {row['cpu_s']:.1f} | {row['solves']} | "
                             f"{o['assemblies_tangent']} | {o['energy_evaluations']} | {o['factorizations']} | "
                             f"{o['factor_columns']} | {_held(row)} |")
        ratio = ab["median_ratio_old_over_new"]
        lines += ["", f"Median old/new: wall {ratio['wall_s']:.2f}×, CPU {ratio['cpu_s']:.2f}×.", ""]
    growth = [(key, f"Rod entries, the default path (nonlinear mesh chosen above the threshold), run {key!r}")
              for key in sorted(results) if key.startswith("growth")]
    for key, title in (("rod", "Rod entries (P2, default sampling)"), ("cbha", "CBHA-like slice (P2, default sampling)"),
                       *growth):
        if key not in results:
            continue
        lines += [f"## {title}", "", "| mesh | DoFs | wall s | CPU s | solves | ramp solves / s | held-out load error | "
                  "nonlinear mesh (check) | load before / after |", "|---|---|---|---|---|---|---|---|---|"]
        for row in results[key]["rows"]:
            ramp = "–" if row.get("ramp_solves") is None else f"{row['ramp_solves']} / {row['ramp_s']:.0f}"
            lines.append(f"| {row['mesh_mm']} mm | {row['dofs']:,} | {row['wall_s']:.0f} | {row['cpu_s']:.0f} | "
                         f"{row['solves']} | {ramp} | {_held(row)} | {_coarse(row)} | {row.get('load_before')} / "
                         f"{row.get('load_after')} |")
        if results[key].get("exponent_wall") is not None:
            lines += ["", f"Growth exponent of the design time with the DoFs: wall {results[key]['exponent_wall']:.2f}, "
                          f"CPU {results[key]['exponent_cpu']:.2f}."]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sections", nargs="*", help="ab, rod, cbha (default: all)")
    parser.add_argument("--baseline", type=Path, default=None, help="directory holding the old code as vertebra/")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--ab-mesh", type=float, default=5.0, help="mm")
    parser.add_argument("--rod-meshes", type=float, nargs="+", default=[8.0, 5.0, 3.5], help="mm")
    parser.add_argument("--cbha-mesh", type=float, default=6.0, help="mm")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--label", default="growth", help="results key of a growth run (growth…; each run kept)")
    args = parser.parse_args(argv)
    if not args.label.startswith("growth"):
        parser.error(f"--label {args.label!r}: must start with 'growth'")
    sections = args.sections or ["ab", "rod", "cbha"]
    unknown = sorted(set(sections) - {"ab", "rod", "cbha", "growth"})
    if unknown:
        parser.error(f"unknown section {unknown[0]!r} (known: ab, rod, cbha, growth)")
    results = _load()
    if "ab" in sections:
        if args.baseline is None:
            parser.error("the ab section needs --baseline")
        section_ab(results, args.baseline, args.rounds, args.ab_mesh)
    if "rod" in sections:
        section_rod(results, args.rod_meshes, args.workers)
    if "cbha" in sections:
        section_cbha(results, args.cbha_mesh, args.workers)
    if "growth" in sections:
        section_rod(results, args.rod_meshes, args.workers, label=args.label)
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
