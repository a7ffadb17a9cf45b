"""The one renderer of the studies' results: Markdown tables (``results/NAME.md``) and the
pictures the docs show, made from the JSON each study writes (``results/NAME.json``).

    python -m benchmarks.render [NAME ...]      # re-render from results/NAME.json (default: all)

A study script calls :func:`write` with its document; :data:`STUDIES` maps each study to its
tables and, where it has them, its pictures. docs/benchmarks.md lists which script makes what.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, RESULTS, write_json


# ------------------------------------------------------------------ shared formatting

def ms3(seconds: float) -> str:
    """Seconds as milliseconds with three decimals."""
    return f"{seconds * 1e3:.3f}"


def fmt_time(s):
    """Seconds in µs, ms or s, three significant-ish digits ("—" where there is no time)."""
    if s is None or not math.isfinite(s):
        return "—"
    if s < 1e-3:
        return f"{s * 1e6:.0f} µs"
    if s < 1.0:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def sci_percent(x):
    """A fraction as a percentage in scientific notation."""
    return f"{100 * x:.2e} %"


# ------------------------------------------------------------------ solver

def solver(res):
    env, out = res["environment"], []
    w = out.append
    w("# Forward solver benchmark\n")
    w(f"`benchmarks/bench_solver.py{' --quick' if res['quick'] else ''}` · {res['date']} · host "
      f"{env['host']} ({env['cpus']} CPUs, shared) · python {env['python']} · numpy {env['numpy']} · "
      f"scipy {env['scipy']} · OMP_NUM_THREADS={env['OMP_NUM_THREADS']} · commit `{env['git']['commit'][:10]}`"
      f"{' + uncommitted solver/ changes (' + str(env['git']['solver_diff_sha1'])[:10] + ')' if env['git']['solver_dirty'] else ''}"
      "\n")
    w(f"Load average (1/5/15 min) at start {res['loadavg_start']}, at end {res['loadavg_end']} "
      f"on {env['cpus']} cores: absolute times are inflated by other jobs; compare ratios within this run. "
      f"Times are medians (min in brackets where given). Total run {res['total_s']:.0f} s.\n")

    w("## Acceptance\n")
    w("| criterion | target | measured | met |")
    w("|---|---|---|---|")
    for a in res["acceptance"]:
        w(f"| {a['criterion']} | {a['target']} | {a['measured']} | {'yes' if a['met'] else '**no**'} |")
    w("")

    sc = res["scaling"]
    w("## 1. Solve time vs number of frames (cantilever, PL²/EI = 1, tol 1e-9)\n")
    w("Solves timed in interleaved rounds over all sizes (median of the round medians; min; CPU time); "
      "the pieces of one iteration timed separately at the converged state.\n")
    w("| links | frames | half bw | solve (min) [CPU] | iterations | tangents + gradients | time / iteration "
      "(wall / CPU) | tangent eval (CPU) | band assembly (CPU) | Cholesky factor+solve (CPU) | LU factor+solve (CPU) "
      "| residual | tip err vs elastica |")
    w("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in sc["rows"]:
        if "skipped" in r:
            w(f"| {r['links']} | {r['frames']} | {r['kd']} | {r['skipped']} |||||||||")
            continue
        w(f"| {r['links']} | {r['frames']} | {r['kd']} | {fmt_time(r['solve']['median_s'])} "
          f"({fmt_time(r['solve']['min_s'])}) [{fmt_time(r['solve']['cpu_median_s'])}] | {r['iterations']} | {r['evaluations_tangent']}+{r['evaluations_gradient']} | "
          f"{fmt_time(r['per_iteration_s'])} / {fmt_time(r['per_iteration_cpu_s'])} | {fmt_time(r['tangent_eval_s'])} | {fmt_time(r['band_assembly_s'])} | "
          f"{fmt_time(r['cholesky_factor_solve_s'])} | {fmt_time(r['lu_factor_solve_s'])} | "
          f"{r['residual']:.1e}{' (r)' if r['rounding_limited'] else ''} | {sci_percent(r['tip_error_vs_elastica'])} |")
    ex = sc["exponents"]
    if ex:
        w(f"\nGrowth exponents (log–log least squares over {ex['range_links'][0]}–{ex['range_links'][1]} links, "
          f"against frames): time per Newton iteration **{ex['per_iteration_s']:.3f}** "
          f"(CPU time {ex['per_iteration_cpu_s']:.3f}, per-size minima {ex['per_iteration_min_s']:.3f}), whole solve {ex['solve_median_s']:.3f}, "
          f"tangent evaluation {ex['tangent_eval_s']:.3f}, band assembly {ex['band_assembly_s']:.3f}, "
          f"banded Cholesky factor+solve {ex['cholesky_factor_solve_s']:.3f}, banded LU factor+solve "
          f"{ex['lu_factor_solve_s']:.3f}, retraction {ex['retraction_s']:.3f}.")
        w("Local exponents (time per iteration / Cholesky factor+solve): " + ", ".join(
            f"{a['links'][0]}→{a['links'][1]}: {a['per_iteration']:.2f} / {a['cholesky_factor_solve']:.2f}"
            for a in sc["local_exponents"]) + ".")
        for c in sc.get("tangent_closed_vs_complex_step", []):
            w(f"Link tangent of {c['links']} links: closed form (solver/links.py, what the model uses, "
              f"kinematics + forces + tangent) {fmt_time(c['closed_form_cpu_s'])} CPU; complex step of "
              f"the same potential (the tests' reference) {fmt_time(c['complex_step_cpu_s'])} CPU; "
              f"largest difference {c['max_relative_difference']:.1e} of the largest entry.")
        w("(r) = stopped as rounding-limited: the Newton correction fell below the floating-point "
          "resolution of the poses.\n")

    g = res["gallery"]
    w("## 2. Gallery scenes (≥ 20 solves after a warm-up)\n")
    w("| scene | frames | dof | cables | chambers | wall median (min) | solver's solve_s | iterations | "
      "load steps | factorization | tangent evals | converged | CPU median |")
    w("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in g["rows"]:
        w(f"| {r['scene']} | {r['frames']} | {r['dof']} | {r['cables']} | {r['chambers']} | "
          f"{fmt_time(r['wall']['median_s'])} ({fmt_time(r['wall']['min_s'])}) | {fmt_time(r['solver_solve_s_median'])} | "
          f"{r['iterations']} | {r['load_steps']} | {r['factorization']} | {r['evaluations']['tangent']} | {r['converged']} | "
          f"{fmt_time(r['wall']['cpu_median_s'])} |")
    c = g["cantilever_20"]
    w(f"\n20-link cantilever: **{fmt_time(c['wall']['solver_solve_s_median'])}** median of the solver's own "
      f"timing (`timings[\"solve_s\"]`; 10–90 % {fmt_time(c['wall']['solver_solve_s_q10_q90'][0])}–"
      f"{fmt_time(c['wall']['solver_solve_s_q10_q90'][1])}); wall median of 61 timed solves "
      f"{fmt_time(c['wall']['median_s'])} (min {fmt_time(c['wall']['min_s'])}, "
      f"CPU median {fmt_time(c['wall']['cpu_median_s'])}), "
      f"{c['iterations']} iterations, {c['evaluations']['tangent']} tangent evaluations of "
      f"{fmt_time(c['tangent_eval_s'])} each (gradient only: {fmt_time(c['gradient_eval_s'])}), banded "
      f"Cholesky factor+solve {fmt_time(c['cholesky_factor_solve_s'])}, retraction {fmt_time(c['retraction_s'])}. "
      f"Target ≤ 1 ms: {'met' if c['met'] else '**not met**'}.\n")
    w("Warm-started re-solves along a trajectory of 1 % changes per tick (`initial=previous.state`):\n")
    w("| scene | change | ticks | cold median (CPU) | cold iterations | warm median (CPU) | warm iterations | speed-up (CPU) | "
      "max \\|warm − cold\\| position | all converged |")
    w("|---|---|---|---|---|---|---|---|---|---|")
    for r in g["warm"]:
        w(f"| {r['scene']} | {r['change']} | {r['ticks']} | {fmt_time(r['cold_median_s'])} "
          f"({fmt_time(r['cold_cpu_median_s'])}) | {r['cold_iterations_median']:.0f} | {fmt_time(r['warm_median_s'])} "
          f"({fmt_time(r['warm_cpu_median_s'])}) | {r['warm_iterations_median']:.0f} | "
          f"{r['speedup']:.2f}× ({r['cold_cpu_median_s'] / r['warm_cpu_median_s']:.2f}×) | {r['max_position_difference_m']:.1e} m | {r['all_converged']} |")
    w("")

    a = res["accuracy"]
    w("## 3. Accuracy vs cost (cantilever, tol 1e-12)\n")
    fine = a["rows"][0]["fine_links"]
    w(f"Tip error in % of L against the inextensible elastica and against {fine} links of the same "
      f"(extensible, shearable) model.\n")
    w("| PL²/EI | links | vs elastica | vs " + str(fine) + " links | iterations | load steps | time (wall / CPU) |")
    w("|---|---|---|---|---|---|---|")
    for r in a["rows"]:
        w(f"| {r['load_parameter']:g} | {r['links']} | {sci_percent(r['error_vs_elastica'])} | {sci_percent(r['error_vs_fine'])} | "
          f"{r['iterations']} | {r['load_steps']} | {fmt_time(r['time']['median_s'])} / {fmt_time(r['time']['cpu_median_s'])} |")
    w("\nFloor (" + str(fine) + " links vs elastica): " + ", ".join(
        f"PL²/EI = {k}: {sci_percent(next(r['fine_vs_elastica'] for r in a['rows'] if str(r['load_parameter']) == k))}"
        for k in a["orders"]) + ".")
    w("Observed order (fit of the error vs " + str(fine) + " links): " + ", ".join(
        f"PL²/EI = {k}: {v:.2f}" for k, v in a["orders"].items()) + ".\n")

    w("Floor check: the same rod made (nearly) inextensible and shear-rigid (single solve each):\n")
    w("| PL²/EI | links | section | tip error vs elastica | converged | iterations | load steps | time |")
    w("|---|---|---|---|---|---|---|---|")
    for r in a["floor_check"]:
        w(f"| {r['load_parameter']:g} | {r['links']} | {r['section']} | {sci_percent(r['error_vs_elastica'])} | "
          f"{r['converged']} | {r['iterations']} | {r['load_steps']} | {fmt_time(r['time_s'])} |")
    w("")

    co = res["coil"]
    w("## 4. Pure end moment: full coil (M = 2πEI/L) and 1.25 coils\n")
    w("| turns | links | converged | iterations | load steps | factorization | closure \\|tip − base\\|/L | "
      "error vs arc / L | tip angle error (rad) | time (wall / CPU) |")
    w("|---|---|---|---|---|---|---|---|---|---|")
    for r in co["rows"]:
        if "error" in r:
            w(f"| {r['turns']} | {r['links']} | crash: {r['error']} ||||||||")
            continue
        w(f"| {r['turns']} | {r['links']} | {r['converged']} | {r['iterations']} | {r['load_steps']} | "
          f"{r['factorization']} | {r['closure']:.1e} | {r['arc_error']:.1e} | {r['tip_angle_error_rad']:.1e} | "
          f"{fmt_time(r['time']['median_s'])} / {fmt_time(r['time']['cpu_median_s'])} |")
    w("")

    t = res["tolerance"]
    w(f"## 5. Newton tolerance ({t['links']} links, PL²/EI = {t['load_parameter']:g})\n")
    w("| tolerance | iterations | final residual | tip error vs tightest / L | tip error vs elastica | time (wall / CPU) |")
    w("|---|---|---|---|---|---|")
    for r in t["rows"]:
        w(f"| {r['tolerance']:.0e} | {r['iterations']} | {r['residual']:.1e}{' (r)' if r['rounding_limited'] else ''} | "
          f"{r['error_vs_tightest']:.1e} | {sci_percent(r['error_vs_elastica'])} | {fmt_time(r['time']['median_s'])} / {fmt_time(r['time']['cpu_median_s'])} |")
    w("")

    o = res["one_step"]
    w("## 6. One linearised step per tick vs converged re-solve (1 % change)\n")
    w("Step = paper eqs. 10–12: tangent and residual at the previous equilibrium's actuation λ0 plus "
      "B(λ − λ0). In brackets: a plain Newton step with the tangent at the new actuation.\n")
    w("| case | tip change / L | error after 1 step / L | 1 step / change | after 2 steps / L | "
      "1 step time (wall / CPU) | converged warm re-solve (wall / CPU) | its iterations |")
    w("|---|---|---|---|---|---|---|---|")
    for r in o["rows"]:
        e1 = f"{r['one_step_error_previous']:.1e}"
        e2 = f"{r['two_steps_error_previous']:.1e}"
        if "one_step_error_new" in r:
            e1 += f" ({r['one_step_error_new']:.1e})"
            e2 += f" ({r['two_steps_error_new']:.1e})"
        rel = r["one_step_relative_previous"]
        w(f"| {r['case']} | {r['tip_change_per_L']:.1e} | {e1} | {rel if rel is not None else float('nan'):.1e} | "
          f"{e2} | {fmt_time(r['one_step_s'])} / {fmt_time(r['one_step_cpu_s'])} | {fmt_time(r['warm_converged_s'])} / "
          f"{fmt_time(r['warm_converged_cpu_s'])} | {r['warm_iterations']} |")
    w("")
    for lp in o["tick_loops"]:
        w(f"* One step per tick, {lp['case']}, {lp['ticks']} ticks, never converging in between: "
          f"max tip error {lp['max_error']:.1e} L, last {lp['last_error']:.1e} L.")
    w("")
    return "\n".join(out)


# ------------------------------------------------------------------ accuracy

def accuracy(result: dict) -> str:
    out = [f"# Accuracy estimate of designed entries ({result['date']}, {result['host']})", "",
           f"Python {result['python']}, one BLAS thread; machine shared (load average {result['loadavg_start'][0]:.1f} "
           f"→ {result['loadavg_end'][0]:.1f}). Error = largest relative compliance error over all loads, "
           "max_w |wᵀ(C_ref − C_h)w| / wᵀC_h w. Estimate: order 1 — the second-order compliance on the same "
           "mesh; order 2 — Richardson extrapolation from a mesh coarser by 1.5 (fallbacks 2, 1.25), p = 2, "
           "size ratio r from the mean edge lengths gmsh achieved. Truth = second-order reference at h/3 "
           "(bellows h/2.5).", "",
           "## Default mesh size, every family, order and ν", "",
           "| family | ν | order | DoFs | estimate DoFs | r | p | true error | estimate | estimate / truth | "
           "error of the better value | design s | with estimate s |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["cases"]:
        if "estimate" not in r:
            out.append(f"| {r['family']} | {r['nu']} | P{r['order']} | {r['dofs']} | – | – | – | "
                       f"{r['true_error']:.3g} | {r['method']} | – | – | {r['design_s']:.2f} | {r['with_estimate_s']:.2f} |")
            continue
        flag = "" if 0.5 <= r["ratio"] <= 2 else " ✗"
        ratio = f"{r['size_ratio']:.2f}" if "size_ratio" in r else "–"
        order = f"{r['convergence_order']:g}" if "convergence_order" in r else "order 2"
        out.append(f"| {r['family']} | {r['nu']} | P{r['order']} | {r['dofs']} | {r['estimate_dofs']} | {ratio} | "
                   f"{order} | {r['true_error']:.3g} | {r['estimate']:.3g} | **{r['ratio']:.2f}**{flag} | "
                   f"{r['extrapolated_error']:.3g} | {r['design_s']:.2f} | {r['with_estimate_s']:.2f} |")
    ratios = [r["ratio"] for r in result["cases"] if "ratio" in r]
    inside = sum(0.5 <= x <= 2 for x in ratios)
    out += ["", f"Within a factor 2 of the truth: {inside} of {len(ratios)} cases "
            f"(estimate / truth from {min(ratios):.2f} to {max(ratios):.2f}).", ""]
    if "large" not in result:
        return "\n".join(out)
    big = result["large"]
    out += ["## ~50,000-DoF second-order rod (acceptance: ≤ 10 s with the estimate, within a factor 2)", "",
            f"`design_segment('rod', R = 10 mm, L = 40 mm, ν = 0.3, h = {1000 * big['mesh_size']:.3g} mm, order 2)`: "
            f"{big['dofs']} DoFs, **{big['total_s']:.2f} s** in all, {big['cpu_s']:.2f} s CPU, load average "
            f"{big['loadavg'][0]:.1f} ({big['design_s']:.2f} s design, {big['accuracy_s']:.2f} s estimate on "
            f"{big['estimate_dofs']} DoFs: {big['basis']}). Estimated error {big['estimate']:.3g}, "
            f"true error {big['true_error']:.3g} against {big['reference_dofs']} DoFs: estimate / truth "
            f"**{big['ratio']:.2f}**; the extrapolated compliance is {big['extrapolated_error']:.3g} from the "
            "reference.", "",
            "## Where designed entries sit between the store's bounds", "",
            "C_ii / lower bound (must stay above 1/100) and C_ii / upper bound (must stay below 10), "
            "smallest and largest over the six diagonal entries; default meshes, density 1000 kg/m³.", "",
            "| family | ν | order | min C/lower | max C/upper | upper bound |", "|---|---|---|---|---|---|"]
    for r in result["bounds"]:
        out.append(f"| {r['family']} | {r['nu']} | P{r['order']} | {r['lower_min']:.3g} | {r['upper_max']:.3g} | "
                   f"{r['upper_method']} |")
    out += ["", "Produced by `benchmarks/bench_accuracy.py`."]
    return "\n".join(out)


# ------------------------------------------------------------------ catalogue_fuzz

def catalogue_fuzz(result: dict) -> str:
    from benchmarks.bench_catalogue_fuzz import COMMANDS
    from tests import corruption

    counts, kinds = result["counts"], result["by_kind"]
    lines = ["# Hostile catalogues: seeded corruption fuzz", "",
             f"{result['date']} on {result['host']} (2 shared cores), Python {result['python']}; load average "
             f"{result['loadavg_start'][0]:.1f} → {result['loadavg_end'][0]:.1f}.", "",
             f"{result['cases']} seeded corruptions (seeds {result['seeds'][0]}…{result['seeds'][1]}) of a "
             f"{result['catalogue_bytes']}-byte catalogue of {len(corruption.SPECS)} designed entries "
             "(rod, tube, bellows, pneumatic; 0–3 cavities), each through four commands in a forked child "
             f"with a {result['deadline_s']:.0f} s deadline. Slowest case {result['max_case_s']:.2f} s "
             f"(all four commands); whole run {result['run_s']:.0f} s.", "",
             "| command | ok | refused | exit 1 | traceback | hang | unsound |", "|---|---:|---:|---:|---:|---:|---:|"]
    for command in COMMANDS:
        c = counts.get(command, {})
        lines.append(f"| {command} | {c.get('ok', 0)} | {c.get('refused', 0)} | {c.get('exit-1', 0)} | "
                     f"{c.get('traceback', 0)} | {c.get('hang', 0)} | {c.get('unsound', 0)} |")
    lines += ["", "By corruption kind (verify):", "", "| kind | cases | refused by verify | file unchanged |",
              "|---|---:|---:|---:|"]
    for kind, row in kinds.items():
        lines.append(f"| {kind} | {row['cases']} | {row['refused']} | {row['unchanged']} |")
    huge = result["huge_attribute"]
    lines += ["", f"## A {huge['megabytes']} MB variable-length attribute", "",
              f"h5py reads it in {huge['h5py_read_s']:.2f} s; `verify` refuses the file in {huge['verify_s']:.3f} s "
              f"and `load` the entry in {huge['load_s']:.3f} s, without reading it:", "",
              f"> {huge['verify_problem']}", "", "Produced by `benchmarks/bench_catalogue_fuzz.py`."]
    return "\n".join(lines)


# ------------------------------------------------------------------ ccx_crosscheck

def or_dash(value, spec):
    return "—" if value is None else format(value, spec)


def ccx_crosscheck(result: dict) -> str:
    lines = ["# CalculiX cross-check of the nonlinear trunk reference", "",
             f"{result['meta']['date']} on {result['meta']['host']} ({result['meta']['cpus']} CPUs, load average "
             f"{result['meta']['load_average']}); {result['meta']['ccx']}. Generated by "
             "`benchmarks/bench_ccx_crosscheck.py`; cases in `benchmarks/nonlinear_cases.py`.", ""]
    lin = result.get("linear")
    if lin:
        lines += ["## Linear regime (CalculiX without NLGEOM vs the linear full-FE chain)", "",
                  f"Three segments ({'; '.join(lin['segments'])}), E = {lin['young']:g} Pa, ν = {lin['poisson']}, "
                  f"{lin['dofs']} DoFs. Relative differences of all vertebra translations / rotations and of "
                  "the pressurised chamber's volume growth.", "",
                  "| load | project quadrature | translations | rotations | volume growth |",
                  "|---|---|---|---|---|"]
        for r in lin["rows"]:
            q = {"project": "project's (11-point tets, exact faces)",
                 "calculix volume": "CalculiX's 4-point tets, exact faces",
                 "calculix": "CalculiX's (4-point tets, 3-point faces)"}[r["quadrature"]]
            lines.append(f"| {r['load']} | {q} | {r['translation_rel']:.1e} | {r['rotation_rel']:.1e} | "
                         f"{or_dash(r.get('volume_growth_rel'), '.1e')} |")
        lines.append("")
    lines += ["## Large deformation (CalculiX NLGEOM vs `designer.nonlinear.NonlinearTrunk`)", "",
              "Tip position difference in % of trunk length (largest over all vertebrae in brackets), tip "
              "rotation difference (angle of R_ccx R_projectᵀ), difference of the tip's bending angle, "
              "relative difference of the pressurised chambers' volume growth, and CalculiX's base "
              "reaction balance: |reaction + loads on the free part| / |those loads|, force / moment (the "
              "moment only without gravity; not checked with a pressurised chamber on the clamped base).", "",
              "| case | material | level | tip bend | tip Δ (% L) | tip rotation Δ | bend Δ | volume growth Δ | "
              "balance F / M |", "|---|---|---|---|---|---|---|---|---|"]
    for case in result["cases"]:
        for r in case["rows"]:
            level = f"{r['level']:g}{(' ' + case['level_unit']) if case['level_unit'] else ''}"
            if not r["compared"]:
                lines.append(f"| {case['name']} | {case['material']} | {level} | "
                             f"{or_dash(r.get('ccx_tip_bend_deg'), '.1f')}° | not reached | | | | |")
                continue
            tip = f"{r['tip_position_pct']:.4f} ({r['max_vertebra_position_pct']:.4f})"
            vol = f"{100 * r['volume_growth_rel_diff']:.3f} %" if "volume_growth_rel_diff" in r else ""
            bal = f"{or_dash(r.get('force_balance'), '.0e')} / {or_dash(r.get('moment_balance'), '.0e')}"
            lines.append(f"| {case['name']} | {case['material']} | {level} | {r['ccx_tip_bend_deg']:.1f}° | {tip} | "
                         f"{r['tip_rotation_diff_deg']:.4f}° | {r['tip_bend_diff_deg']:+.4f}° | {vol} | {bal} |")
    for case in result["cases"]:
        sym = case.get("symmetric")
        if not sym:
            continue
        lines += ["", f"### {case['name']}: CalculiX on the symmetric path", "",
                  "Geometry and loads are symmetric about the xz-plane. CalculiX's Newton iterations stop "
                  "converging in the vertebrae's out-of-plane modes (twist, y) at the level given below while "
                  "the project's tangent stays positive definite; holding the vertebrae in the xz-plane "
                  "(u_y = 0, rotation about y only) lets CalculiX follow the symmetric path the project's "
                  "solution takes (its out-of-plane motion is that of the slightly asymmetric mesh, ~1e-5 rad).",
                  "", "| level | tip bend | tip Δ (% L) | tip rotation Δ | volume growth Δ | CalculiX volume growth / rest |",
                  "|---|---|---|---|---|---|"]
        for r in sym["rows"]:
            level = f"{r['level']:g} {case['level_unit']}"
            if not r["compared"]:
                lines.append(f"| {level} | {or_dash(r.get('ccx_tip_bend_deg'), '.1f')} | not reached | | | |")
                continue
            lines.append(f"| {level} | {r['ccx_tip_bend_deg']:.1f}° | {r['tip_position_pct']:.4f} | "
                         f"{r['tip_rotation_diff_deg']:.4f}° | {100 * r['volume_growth_rel_diff']:.3f} % | "
                         f"{100 * r['ccx_volume_growth_of_rest']:.1f} % |")
        if sym["limit"]:
            lines += ["", f"CalculiX (symmetric path) stopped at {sym['limit']['reached_level']:.4g} "
                          f"{case['level_unit']}: {sym['limit']['message']}"]
    matched = [(c, r) for c in result["cases"] for r in c["rows"] if "matched_tip_position_pct" in r]
    if matched:
        lines += ["", "### The same cases with CalculiX's volume quadrature in the project's FE", "",
                  "The project's trunk re-assembled with 4 quadrature points per tetrahedron (CalculiX's C3D10 "
                  "rule) instead of 11: what remains is the difference between the two codes' solutions of the "
                  "same discrete problem.", "",
                  "| case | level | tip bend | tip Δ (% L), project quadrature | tip Δ (% L), CalculiX quadrature | "
                  "rotation Δ, CalculiX quadrature |", "|---|---|---|---|---|---|"]
        for c, r in matched:
            lines.append(f"| {c['name']} | {r['level']:g} | {r['ccx_tip_bend_deg']:.1f}° | {r['tip_position_pct']:.2e} | "
                         f"{r['matched_tip_position_pct']:.2e} | {r['matched_tip_rotation_diff_deg']:.1e}° |")
    lines += ["", "### Cases, sizes and times", "",
              "| case | segments | length (mm) | DoFs (CalculiX / project) | CalculiX s (passes) | project s | "
              "stopped at |", "|---|---|---|---|---|---|---|"]
    for case in result["cases"]:
        limits = []
        for who in ("ccx", "project"):
            lim = case[who]["limit"]
            if lim:
                limits.append(f"{'CalculiX' if who == 'ccx' else 'project'}: level {lim['reached_level']:.4g}")
        lines.append(f"| {case['name']} | {case['segments']} | {1e3 * case['length_m']:.0f} | {case['ccx']['dofs']} / "
                     f"{case['project']['dofs']} | {case['ccx']['wall_s']:.0f} ({len(case['ccx']['passes'])}) | "
                     f"{case['project']['solve_s']:.0f} | {'; '.join(limits)} |")
    lines += ["", "Descriptions:", ""] + [f"* `{c['name']}`: {c['description']}" for c in result["cases"]]
    summary = result.get("summary")
    if summary:
        lines += ["", "## Summary", ""] + [f"* {line}" for line in summary]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ designer

def designer(result) -> str:
    from vertebra.designer.linsolve import AUTO_THRESHOLD

    out = [f"# Designer benchmark ({result['date']}, {result['host']})", "",
           f"Python {result['python']}, one BLAS thread; machine shared (load average at start "
           f"{result['load_average']}). Error = scale-free compliance difference to the reference "
           "(finest) mesh, max |ΔC_ij| / sqrt(C_ii C_jj).", ""]
    for title, key in (("Rod R = 10 mm, L = 40 mm, E = 1 MPa, ν = 0.3", "rod"),
                       ("Pneumatic segment, 3 chambers, ν = 0.45", "pneumatic")):
        out += [f"## {title}", "",
                "| order | h (mm) | DoFs | solver | mesh s | assemble s | solve s | total s | error |"
                + (" axial / L/EA | lateral / Timoshenko |" if key == "rod" else ""),
                "|---|---|---|---|---|---|---|---|---|" + ("---|---|" if key == "rod" else "")]
        for r in result[key]:
            line = (f"| P{r['order']}{' (ref)' if r.get('reference') else ''} | {1000 * r['mesh_size']:.3g} | "
                    f"{r['dofs']} | {r['solver']} | {r['mesh_s']:.2f} | {r['assemble_s']:.2f} | {r['solve_s']:.2f} | "
                    f"{r['total_s']:.2f} | {r['error']:.2e} |")
            if key == "rod":
                line += f" {r['axial_over_closed_form']:.4f} | {r['lateral_over_timoshenko']:.4f} |"
            out.append(line)
        out.append("")
    out += ["## Direct (SuperLU) vs AMG-PCG solve time", "",
            f"`auto` switches to AMG at {AUTO_THRESHOLD} interior unknowns.", "",
            "| order | h (mm) | interior DoFs | direct solve s | AMG solve s | PCG iterations |", "|---|---|---|---|---|---|"]
    cross = result["crossover"]
    for d, a in zip(cross[::2], cross[1::2]):
        out.append(f"| P{d['order']} | {1000 * d['mesh_size']:.3g} | {d['interior_dofs']} | {d['solve_s']:.2f} | "
                   f"{a['solve_s']:.2f} | {a.get('pcg_iterations', '-')} |")
    out += ["", "## Condensing ~50,000-DoF segments (acceptance ≤ 10 s)", "",
            "| segment | order | h (mm) | DoFs | solver | PCG iterations | mesh s | assemble s | solve s | total s | ≤ 10 s |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    pneumatic_ref = next(r for r in result["pneumatic"] if r.get("reference"))
    for label, big in (("rod", result["large"]), ("pneumatic (3 cavities, ν = 0.45)", pneumatic_ref)):
        out.append(f"| {label} | P{big['order']} | {1000 * big['mesh_size']:.3g} | {big['dofs']} | {big['solver']} | "
                   f"{big.get('pcg_iterations', '-')} | {big['mesh_s']:.2f} | {big['assemble_s']:.2f} | "
                   f"{big['solve_s']:.2f} | **{big['total_s']:.2f}** | {'yes' if big['total_s'] <= 10 else 'NO'} |")
    out.append("")
    acc = result["accuracy_cost"]
    out += ["## Cost of the per-entry accuracy estimate", "",
            f"Default pneumatic segment (P2, default mesh size): design without estimate {acc['without_s']:.2f} s, "
            f"with estimate (Richardson from a second solve on 1.5 h) {acc['with_s']:.2f} s; estimated "
            f"relative error {acc.get('relative_error', acc.get('relative_change')):.3g}.", ""]
    return "\n".join(out)


# ------------------------------------------------------------------ nonlinear

def _series(cases: list) -> tuple[str, str, str]:
    """Table cells of a load series: angles, fitted and linear tip errors in % (`*`: out of range)."""
    angles = "/".join(f"{c['angle_deg']:.0f}" for c in cases)
    fit = "/".join("–" if c["fit"] is None else f"{100 * c['fit']:.3f}" + ("*" if c.get("left_range") else "")
                   for c in cases)
    lin = "/".join("–" if c["linear"] is None else f"{100 * c['linear']:.2f}" for c in cases)
    return angles, fit, lin


def nonlinear(results: dict) -> str:
    out = ["# Nonlinear condensation: cost and accuracy of fitted segment energies", "",
           "Produced by `benchmarks/bench_nonlinear.py` (see docs/nonlinear-condensation.md). Errors against "
           "the full nonlinear FE of the same trunk (same meshes, rigid vertebrae): tip position in % of the "
           "trunk length; the fit alone (the chain of fitted energies solved to round-off).", ""]
    if "kernel" in results:
        k = results["kernel"]
        out += [f"## Runtime kernel ({k['links']} links per call, median of interleaved rounds)", "",
                "| energy | terms | monomials | links with ψ µs | quadratic links µs | ratio |", "|---|---|---|---|---|---|"]
        out += [f"| {r['case']} | {r['terms']} | {r['monomials']} | {r['energy_us']:.0f} | {r['linear_us']:.0f} | "
                f"{r['ratio']:.2f} |" for r in k["rows"]]
        out.append("")
    if "rod" in results:
        r = results["rod"]
        c = r["cost"]
        out += ["## Neo-Hookean rod (R 10 mm, L 40 mm, E 1 MPa, ν 0.3)", "",
                f"Cost of one entry at {c['dofs']} DoFs on 2 workers: linear entry {c['linear_entry_s']:.0f} s, "
                f"sampling {c['sampling_s']:.0f} s ({c['solves']} FE solves), fit {c['fit_s']:.1f} s, total "
                f"{c['total_s']:.0f} s. Held-out load error {c['held_out']['load_max']:.2%} of the range "
                f"(linear entry {c['held_out']['linear_load_max']:.1%}).", "",
                "| degree | paths | unknowns | held-out load max | trunk | angles ° | fit tip % | linear tip % |",
                "|---|---|---|---|---|---|---|---|"]
        for row in r["study"]:
            for trunk, cases in row["trunks"].items():
                angles, fit, lin = _series(cases)
                out.append(f"| {row['degree']} | {row['paths']} | {row['unknowns']} | "
                           f"{row['held_out']['load_max']:.2%} | {trunk} | {angles} | {fit} | {lin} |")
        out += ["", "`*`: the state left the fitted range (reported by the kernel).", ""]
    if "family" in results:
        out += ["## Rods and tubes, both materials (default sampling)", "",
                "| family | L/R | material | DoFs | segments | held-out load max | loads | angles ° | fit tip % | linear tip % |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for row in results["family"]:
            p = row["parameters"]
            ratio = p["length"] / p.get("radius", p.get("outer_radius"))
            for kind, cases in row["trunks"].items():
                angles, fit, lin = _series(cases)
                out.append(f"| {row['family']} | {ratio:g} | {row['material']} | {row['dofs']} | {row['segments']} | "
                           f"{row['held_out']['load_max']:.2%} | {kind} | {angles} | {fit} | {lin} |")
        out.append("")
    if "pneumatic" in results:
        r = results["pneumatic"]
        out += ["## CBHA-like pneumatic slices (4 stacked, one chamber pressurised)", "",
                f"{r['dofs']} DoFs per slice, {r['unknowns']} unknowns ({r['terms']} terms), {r['solves']} FE solves "
                f"in {r['sampling_s']:.0f} s; pressures sampled to {max(r['pressure_upper']):.4g} Pa; limit point "
                f"{r['limit_pressure']}; fold pressure {r['fold_pressure']}. Held-out: load "
                f"{r['held_out']['load_max']:.2%}, volume {r['held_out'].get('volume_max', float('nan')):.2%} of the range.",
                "", "| bar | tip angle ° | fit: tip % | angle | volume | linear: tip % | angle | volume |",
                "|---|---|---|---|---|---|---|---|"]
        for row in r["rows"]:
            f, lin = row["fit"], row["linear"]
            out.append(f"| {row['pressure'] / 1e5:.2f} | {row['angle_deg']:.1f} | {100 * f['tip']:.3f} | "
                       f"{100 * f['angle']:+.2f} % | {100 * f['volume']:+.2f} % | {100 * lin['tip']:.2f} | "
                       f"{100 * lin['angle']:+.1f} % | {100 * lin['volume']:+.1f} % |")
        out.append("")
    return "\n".join(out) + "\n"


def nonlinear_pictures(results: dict, directory: Path) -> list:
    if "rod" not in results:
        return
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    study = results["rod"]["study"]
    for degree, marker in ((4, "o"), (6, "s"), (8, "^")):
        rows = [r for r in study if r["degree"] == degree]
        solves = [r["training_samples"] for r in rows]
        inside = [max((c["fit"] or np.nan) for t in r["trunks"].values() for c in t if not c.get("left_range"))
                  * 100 for r in rows]
        every = [max((c["fit"] or np.nan) for t in r["trunks"].values() for c in t) * 100 for r in rows]
        held = [r["held_out"]["load_max"] * 100 for r in rows]
        line, = axes[0].semilogy(solves, inside, marker=marker, label=f"degree {degree}")
        axes[0].semilogy(solves, every, marker=marker, ls=":", color=line.get_color(), alpha=0.6)
        axes[1].semilogy(solves, held, marker=marker, label=f"degree {degree}")
    linear = max(c["linear"] for r in study for t in r["trunks"].values() for c in t
                 if c["linear"] and not c.get("left_range"))
    axes[0].axhline(linear * 100, color="k", ls="--", label="linear entries (in range)")
    axes[0].set_ylim(top=linear * 100 * 1.6)
    axes[0].set(xlabel="FE samples in the fit (sampling cost)", ylabel="worst tip error, % of trunk length",
                title="Rod trunks, 2 and 4 segments (dotted: with states out of range)")
    axes[1].set(xlabel="FE samples in the fit", ylabel="held-out load error, % of range",
                title="Held-out fit error")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    path = directory / "nonlinear-fit-error-vs-cost.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


# ------------------------------------------------------------------ nonlinear_acceptance

def nonlinear_acceptance(document: dict) -> str:
    meta = document["meta"]
    lines = [
        "# Large deformation: trunks of nonlinear entries against the full nonlinear FE", "",
        f"`benchmarks/bench_nonlinear_acceptance.py` · {meta['date']} · host {meta['host']} (load average "
        f"{meta['load']:.1f}) · vertebra {meta['version']}. Cases: `benchmarks/nonlinear_cases.py` "
        "(docs/nonlinear-reference.md). Reference: the project's full nonlinear FE trunk on the same meshes; "
        "CalculiX column where the cross-check ran that level.", "",
        "Errors of the runtime solver with the designed nonlinear entries (and, for comparison, with the "
        "same entries' linear condensation): tip position in % of the trunk length, tip rotation; for "
        "the pneumatic case the bending angle and the pressurised chamber's volume growth (relative). "
        "`range`: quantities reported outside the fitted range.", "",
        "| case | level | FE tip rotation | nonlinear tip % L | vs CalculiX % L | rotation Δ ° | bend Δ % | "
        "volume Δ % | range | linear tip % L | bend Δ % | volume Δ % | ms nonlinear / linear |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def fmt(value, spec):
        return "" if value is None else format(value, spec)

    for case in document["cases"]:
        for row in case["rows"]:
            if "nonlinear" not in row:
                lines.append(f"| {case['name']} | {row['level']} {case['level_unit']} | full FE stopped: "
                             f"{row.get('fe_failed', '')[:80]} |||||||||||")
                continue
            nl, li = row["nonlinear"], row["linear"]
            lines.append(
                f"| {case['name']} | {row['level']} {case['level_unit']} | {row['fe_tip_rotation_deg']:.1f}° | "
                f"**{nl['tip_error_pct']:.4f}**{'' if nl['converged'] else ' (not converged)'} | "
                f"{fmt(nl.get('tip_error_vs_ccx_pct'), '.4f')} | {nl['tip_rotation_error_deg']:.4f} | "
                f"{fmt(nl.get('bend_error_pct'), '+.2f')} | {fmt(nl.get('volume_error_pct'), '+.2f')} | "
                f"{nl['out_of_range']} | {li['tip_error_pct']:.3f} | {fmt(li.get('bend_error_pct'), '+.1f')} | "
                f"{fmt(li.get('volume_error_pct'), '+.1f')} | {1e3 * nl['solve_cpu_s']:.1f} / "
                f"{1e3 * li['solve_cpu_s']:.1f} |")
    lines += ["", "## Verdicts (≤ 0.1 % of length to 50°, ≤ 0.2 % to 90°; pneumatic tip ≤ 0.2 %, bend and "
              "volume ≤ 1 %)", "", "| case | segments | material | tags | met | failures |", "|---|---|---|---|---|---|"]
    for case in document["cases"]:
        v = case["verdict"]
        lines.append(f"| {case['name']} | {case['segments']} | {case['material']} | {', '.join(case['tags'])} | "
                     f"{'yes' if v['met'] else '**no**'} | {'; '.join(v['failures'])} |")
    lines += ["", "## Entries", "", "| case | entry | DoFs | terms | held-out load error | design s |",
              "|---|---|---|---|---|---|"]
    for case in document["cases"]:
        for name, e in case["entries"].items():
            held = e["held_out"]
            held_text = ", ".join(f"{k} {v:.3g}" for k, v in held.items() if isinstance(v, (int, float)))
            lines.append(f"| {case['name']} | {name} | {e['dofs']} | {e['terms']} | {held_text} | "
                         f"{e['seconds']:.0f}{' (read back)' if e['seconds'] == 0 else ''} |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ nonlinear_fe

def nonlinear_fe(results) -> str:
    lines = [f"# Nonlinear FE benchmark ({results['date']}, load average {results['machine']['load_average_start'][0]:.1f}"
             f" → {results['machine']['load_average_end'][0]:.1f} on 2 cores)", "",
             *([f"Sections rerun then: {', '.join(results['sections_rerun'])}; the others are from the run of "
                f"{results['kept_from']['date']} (load average {results['kept_from']['machine']['load_average_start'][0]:.1f}).",
                ""] if "kept_from" in results else []),
             "## Segment pose solve (neo-Hookean, E = 1 MPa, ν = 0.45)", "",
             "| family | order | h (mm) | solver | DoFs | cold bend (rad) | cold (s) | s/pose (median) | Newton/pose | factorizations/pose | Krylov/pose |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["pose_cost"]:
        lines.append(f"| {r['family']} | P{r['order']} | {1e3 * r['mesh_size']:.2g} | {r['linear_solver']} | {r['dofs']} | "
                     f"{r['bend_rad']} | {r['cold_s']:.2f} | {r['pose_s_median']:.2f} | {r['newton_per_pose']:.1f} | "
                     f"{r['factorizations_per_pose']:.2f} | {r['krylov_per_pose']:.1f} |")
    lines += ["", "## Trunk (rod segments, dead tip force PL²/EI = 1.5)", "",
              "| segments | h (mm) | DoFs | solve (s) | Newton | load steps | factorizations | tip rotation (°) |",
              "|---|---|---|---|---|---|---|---|"]
    for r in results["trunk_cost"]:
        lines.append(f"| {r['segments']} | {1e3 * r['mesh_size']:.2g} | {r['dofs']} | {r['solve_s']:.1f} | {r['iterations']} | "
                     f"{r['load_steps']} | {r['factorizations']} | {r['tip_rotation_deg']:.1f} |")
    lines += ["", "## Thick-walled tube, clamped ends, L = 6 b (a = 5 mm, b = 10 mm): radial displacement at mid-length (mm)", "",
              "| p (kPa) | inner FE | inner NH plane strain | FE/NH − 1 | inner Lamé | outer FE | outer NH plane strain | FE/NH − 1 | outer Lamé |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in results["tube"]:
        lines.append(f"| {r['pressure_Pa'] / 1e3:g} | {r['inner_u_fe_mm']:.4f} | {r['inner_u_nh_mm']:.4f} | "
                     f"{r['inner_u_fe_mm'] / r['inner_u_nh_mm'] - 1:+.2%} | {r['inner_u_lame_mm']:.4f} | "
                     f"{r['outer_u_fe_mm']:.4f} | {r['outer_u_nh_mm']:.4f} | "
                     f"{r['outer_u_fe_mm'] / r['outer_u_nh_mm'] - 1:+.2%} | {r['outer_u_lame_mm']:.4f} |")
    lines += ["", "## Rod (L/R = 8) bent to a constant curvature: moment / (EIθ/L)", "", "| θ (rad) | ratio |", "|---|---|"]
    lines += [f"| {r['theta_rad']} | {r['moment_over_EI_theta_over_L']:.4f} |" for r in results["rod_bending"]]
    lines += ["", "## Slender trunk (6 rod segments of L/R = 4, 24 R in all) vs the planar elastica", "",
              "Against the elastica with EI, and with the FE trunk's own small-load bending stiffness (rigid "
              "vertebrae every 4 R and shear make it differ from EI): the second column isolates the "
              "geometric nonlinearity.", "",
              "| PL²/EI | DoFs | EI_FE / EI | tip error (% of L), EI | tip error (% of L), EI_FE | tip rotation FE (°) | elastica EI / EI_FE (°) | solve (s) |",
              "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['force_ratio']} | {r['dofs']} | {r.get('EI_fe_over_EI', float('nan')):.4f} | "
              f"{r['tip_error_percent_of_L']:.3f} | {r.get('tip_error_fe_stiffness_percent_of_L', float('nan')):.3f} | "
              f"{r['fe_tip_rotation_deg']:.2f} | {r['elastica_tip_rotation_deg']:.2f} / "
              f"{r.get('elastica_fe_stiffness_tip_rotation_deg', float('nan')):.2f} | {r['solve_s']:.1f} |"
              for r in results["elastica"]]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ prepare_ranges

def prepare_ranges(results: dict) -> str:
    from benchmarks.bench_prepare_ranges import LEVELS, WORKERS

    out = ["# Nonlinear entries prepared for a scene's range", "",
           "Produced by `benchmarks/bench_prepare_ranges.py` (see docs/prepare.md, \"Ranges of nonlinear "
           f"entries\"). Machine: {results['machine']['host']}, shared 2 cores, {results['machine']['date']}.", ""]
    if "pressure" in results:
        r = results["pressure"]
        out += [f"## Pressure box: {r['slices']} CBHA-like slices, one chamber bounded at {r['bound']:.3g} Pa", "",
                f"{r['dofs']} DoFs per slice; load average {r['loadavg']}. Prepared (scene bound) vs default "
                "(up to 90 % of the inflation limit point) entries against the full nonlinear FE trunk. "
                f"Prepared: {r['prepared_s']:.0f} s in all (the entry's sampling serial in one sweep worker); "
                f"default: {r['default_s']:.0f} s (sampling on {WORKERS} local workers).", "",
                "| entry | pressures sampled to (Pa) | limit point | held-out load | held-out volume | solves | "
                "sampling s |", "|---|---|---|---|---|---|---|"]
        for name in ("prepared", "default"):
            e = r[name]
            held = e["held_out"]
            limit = "none met" if e["limit_pressure"] is None else f"{e['limit_pressure']:.4g}"
            out.append(f"| {name} | {max(e['pressure_upper']):.4g} | {limit} | "
                       f"{100 * held.get('load_max', float('nan')):.2f} % | "
                       f"{100 * held.get('volume_max', float('nan')):.2f} % | {e['solves']} | {e['sampling_s']:.0f} |")
        out += ["", "| bar | entry | tip % of length | tip angle | volume growth | left range |",
                "|---|---|---|---|---|---|"]
        for k, level in enumerate(LEVELS):
            for name in ("prepared", "default"):
                row = r[name]["rows"][k]
                out.append(f"| {level / 1e5:.2f} | {name} | {100 * row['tip']:.4f} | {100 * row['angle']:+.2f} % | "
                           f"{100 * row['volume']:+.2f} % | {row['left_range']} |")
        out.append("")
    if "twist" in results:
        r = results["twist"]
        out += ["## Twisted rods (0.1 N m tip twist, cable up to 6 N), default sampling density", "",
                f"prepare {r['prepared_s']:.1f} s; settings {r['settings']['settings']}; load average {r['loadavg']}.",
                "", "| actuation | prepared entry: out of range | default-range entry: out of range |", "|---|---|---|"]
        for a, b in zip(r["prepared"], r["default"]):
            out.append(f"| {a['actuation']} | {', '.join(a['out_of_range']) or 'none'} | "
                       f"{', '.join(b['out_of_range']) or 'none'} |")
        out.append("")
    return "\n".join(out)


# ------------------------------------------------------------------ robustness

def _spread(s: dict) -> str:
    return "—" if not s else f"median {s['median'] * 1e3:.1f} ms, max {s['max'] * 1e3:.1f} ms"


def robustness(res: dict) -> str:
    out = []
    w = out.append
    w("# Robustness at the extremes (`benchmarks/bench_robustness.py`)\n")
    w(f"{res['date']}, {res['host']}, load average {res['loadavg']}; CPU time of the thread.\n")
    f = res["forward"]
    w("## 1. Random representable tendon robots, forward from rest in one load step\n")
    w(f"{f['converged']}/{f['seeds']} converged, {f['stable']} with a positive definite tangent; "
      f"{f['draws_per_robot']:.2f} draws per representable robot. Iterations median "
      f"{f['iterations']['median']:.0f}, p90 {f['iterations']['p90']:.0f}, max {f['iterations']['max']:.0f}; CPU "
      f"per solve median {f['cpu_s']['median'] * 1e3:.2f} ms, p90 {f['cpu_s']['p90'] * 1e3:.2f} ms, max "
      f"{f['cpu_s']['max'] * 1e3:.2f} ms. Tip within 1 % of the length of the refined reference's: "
      f"{f['tip_within_1pct_of_reference']}/{f['converged']} (median {f['tip_vs_reference']['median']:.1e} L; the "
      "others are the mirror images of a symmetric buckling, equally stable).\n")
    a = f["all_draws"]
    w(f"Every draw ({a['count']}, representable or not): {a['converged']} converged ({a['representable']} "
      f"representable, of which {a['failed_representable']} failed); failures by reason "
      f"{a['failure_reasons']}, CPU {_spread(a['failure_cpu_s'])}; converged solves CPU {_spread(a['converged_cpu_s'])}.\n")
    w("## 2. polymer_5v_16t in tick mode (every tick settled to an equilibrium)\n")
    w("| gravity | trajectory | ticks | equilibria | bound / change violations | error after 10 ticks (max) | "
      "first ticks (mm) | tick CPU median / p90 |")
    w("|---|---|---|---|---|---|---|---|")
    for r in res["polymer_tick"]:
        w(f"| {r['gravity']} | {r['trajectory']} | {r['ticks']} | {r['equilibria']} | {r['bound_violations']} / "
          f"{r['change_violations']} | {r['max_error_after_10_m'] * 1e3:.3f} mm | "
          f"{', '.join(f'{e * 1e3:.2f}' for e in r['error_first_10_m'][:6])} | "
          f"{r['tick_cpu_s']['median'] * 1e3:.3f} / {r['tick_cpu_s']['p90'] * 1e3:.3f} ms |")
    w("\n## 3. polymer_5v_16t in converged mode\n")
    w("| gravity | targets | reached | max error | CPU per target median / max | outer iterations median / max |")
    w("|---|---|---|---|---|---|")
    for r in res["polymer_converged"]:
        w(f"| {r['gravity']} | {r['trajectory']} ({r['targets']}) | {r['reached']} | {r['max_error_m']:.1e} m | "
          f"{r['cpu_s']['median'] * 1e3:.1f} / {r['cpu_s']['max'] * 1e3:.1f} ms | "
          f"{r['iterations']['median']:.0f} / {r['iterations']['max']:.0f} |")
    w("\n## 4. Random robots of a control experiment's size\n")
    w("| seed | gravity | vertebrae | tendons | length | circle: error after 10 ticks | jump | jump: tick error "
      "after 10 | jump converged | tick CPU median |")
    w("|---|---|---|---|---|---|---|---|---|---|")
    for r in res["control"]:
        c = r["jump_converged"]
        w(f"| {r['seed']} | {r['gravity']} | {r['vertebrae']} | {r['tendons']} | {r['length_m'] * 100:.1f} cm | "
          f"{r['circle']['max_error_after_10_m'] * 1e3:.3f} mm | {r['jump_m'] * 100:.1f} cm | "
          f"{r['jump_tick']['max_error_after_10_m'] * 1e3:.3f} mm | {c['status']} {c['error_m']:.0e} m "
          f"{c['cpu_s'] * 1e3:.0f} ms | {r['circle']['tick_cpu_s']['median'] * 1e3:.3f} ms |")
    w("\n## 5. Extremes\n")
    w("| case | converged | iterations | CPU | largest link turn / reason |")
    w("|---|---|---|---|---|")
    for r in res["extremes"]:
        detail = f"{r['largest_turn_deg']:.0f}°" if r["converged"] else r["reason"][:160]
        w(f"| {r['case']} | {r['converged']} | {r['iterations']} | {r['cpu_s'] * 1e3:.1f} ms | {detail} |")
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ runtime_nonlinear

def runtime_nonlinear(results: dict) -> str:
    out = ["# Runtime with nonlinear catalogue entries", "",
           f"Machine: {results['machine']['host']}, Python {results['machine']['python']}, "
           f"{results['machine']['date']}. Produced by `benchmarks/bench_runtime_nonlinear.py`.", ""]
    speed = results.get("speed")
    if speed:
        out += ["## Speed: 20-link forward solve, nonlinear vs linear entries (same trunk, same load)", "",
                f"CPU-time medians of {speed['rounds']} interleaved rounds × {speed['repeats']} solves; "
                "links: the link energies' response and material tangent at the equilibrium (one Newton "
                "evaluation's link part).", "",
                "| case | terms | tip angle | nonlinear ms (it) | linear ms (it) | ratio | per iteration | "
                "links µs nonlinear / linear | out of range |",
                "|---|---|---|---|---|---|---|---|---|"]
        for r in speed["rows"]:
            nl, li = r["nonlinear"], r["linear"]
            out.append(f"| {r['case']} | {r['terms']} | {r['tip_angle_deg']:.0f}° | {nl['solve_ms']:.3f} "
                       f"({nl['iterations']}) | {li['solve_ms']:.3f} ({li['iterations']}) | **{r['ratio']:.2f}×** | "
                       f"{r['ratio_per_iteration']:.2f}× | {nl['links_evaluation_us']:.0f} / "
                       f"{li['links_evaluation_us']:.0f} | {r['out_of_range']} |")
        out.append("")
    tick = results.get("tick")
    if tick:
        nl, li = tick["nonlinear"], tick["linear"]
        out += [f"Control tick (tick mode), eight CBHA slices, tip on a 2 mm circle: nonlinear "
                f"{nl['tick_ms']:.3f} ms, linear {li['tick_ms']:.3f} ms per tick (**{tick['ratio']:.2f}×**); "
                f"largest lag after the first quarter {1e3 * nl['max_error_m']:.3f} / {1e3 * li['max_error_m']:.3f} mm.",
                ""]
    rods = results.get("accuracy_rods")
    if rods:
        out += ["## Accuracy spot check: rod trunks against the full nonlinear FE", "",
                "Tip error in % of the trunk length (same meshes and material, rigid vertebrae); "
                "`range`: quantities reported outside the fitted range.", "",
                "| case | FE tip angle | nonlinear entries | range | linear entries |", "|---|---|---|---|---|"]
        for r in rods:
            out.append(f"| {r['case']} ×{r['level']:g} | {r['fe_tip_angle_deg']:.0f}° | "
                       f"{r['nonlinear']['tip_error_pct']:.4f} % | {r['nonlinear']['out_of_range']} | "
                       f"{r['linear']['tip_error_pct']:.3f} % |")
        out.append("")
    cbha = results.get("accuracy_cbha")
    if cbha:
        out += ["## Accuracy spot check: four CBHA-like slices, chamber 0 pressurised", "",
                "| pressure | FE tip angle | nonlinear: tip | angle | volume | range | linear: tip | angle | volume |",
                "|---|---|---|---|---|---|---|---|---|"]
        for r in cbha:
            nl, li = r["nonlinear"], r["linear"]
            out.append(f"| {r['pressure'] / 1e5:.2f} bar | {r['fe_tip_angle_deg']:.1f}° | {nl['tip_error_pct']:.3f} % | "
                       f"{nl['angle_error_pct']:+.2f} % | {nl['volume_error_pct']:+.2f} % | {nl['out_of_range']} | "
                       f"{li['tip_error_pct']:.2f} % | {li['angle_error_pct']:+.1f} % | {li['volume_error_pct']:+.1f} % |")
        out.append("")
    entries = results.get("entries")
    if entries:
        out += ["Entries (coarse meshes): " + "; ".join(
            f"{name}: {e['dofs']} DoFs, {e['terms']} terms, held-out load error "
            f"{100 * e['held_out'].get('load_max', float('nan')):.2g} % of the range" for name, e in entries.items()), ""]
    return "\n".join(out)


# ------------------------------------------------------------------ sweep

def sweep(result: dict) -> str:
    lines = [
        "# Sweep throughput (benchmarks/bench_sweep.py)", "",
        f"{result['date']}, commit {result['commit']}, {result['host']}, {result['cpus']} CPUs shared with other "
        f"work (load average at start {result['load_start']:.2f}); Python {result['python']}.", "",
        f"## Real coarse rod entries ({result['real']['entries']} rods of radius 4-7.5 mm, length 20 mm, "
        f"P{result['real']['order']}, no accuracy estimate, a fresh HDF5 catalogue for each run; "
        f"best of {result['real']['repeat']} interleaved runs per row)", "",
        "| mesh size m | DoFs (mean) | executor | workers | entries | best wall s | median wall s | entries/min (best) "
        "| mean task s | mean task CPU s | efficiency | load before | same keys | complete runs |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["real"]["rows"]:
        lines.append(f"| {r['mesh_size']} | {r['dofs_mean'] or 0:.0f} | {r['executor']} | {r['workers']} | "
                     f"{r['entries']} | {r['wall_s']:.1f} | {r['median_wall_s']:.1f} | "
                     f"{(r['entries_per_minute'] or 0):.2f} | {r['mean_task_s']:.2f} | {r['mean_task_cpu_s']:.2f} | "
                     f"{r['efficiency']:.2f} | "
                     f"{r['load_before']:.1f} | {r['same_keys_as_local_1']} | {r['complete_runs']}/{r['runs']} |")
    lines += ["", "Wall time includes starting the pool or the dask LocalCluster. Efficiency = sum of worker "
              "task seconds / (workers x wall). Mean task s is the wall time a worker spent per entry, mean task "
              "CPU s the CPU time its process got meanwhile: when they differ, the worker waited for a core "
              "(the 2 cores are shared with other jobs; the load average is the 1-minute one before each row).", "",
              f"## Executor overhead (no-op job, {result['overhead'][0]['tasks']} tasks)", "",
              "| executor | workers | start s | first result s | per task ms | shutdown s |",
              "|---|---|---|---|---|---|"]
    for r in result["overhead"]:
        lines.append(f"| {r['executor']} | {r['workers']} | {r['start_s']:.2f} | {r['first_result_s']:.2f} | "
                     f"{r['per_task_ms']:.2f} | {r['shutdown_s']:.2f} |")
    lines += ["", "start: entering the executor (dask: LocalCluster and Client); first result: until the first "
              "task came back (local: spawning workers and importing vertebra in them); per task: "
              "(last - first result) / (tasks - 1), i.e. throughput cost per task once running.", "",
              f"## Planning ({result['planning'][0]['tasks']} rod tasks, real canonical parameters and keys, "
              "no meshing)", "",
              "| catalogue | per task ms | total s |", "|---|---|---|"]
    for r in result["planning"]:
        lines.append(f"| {r['catalogue']} | {r['per_task_ms']:.3f} | {r['total_s']:.2f} |")
    lines += ["", "Without a catalogue file the store is asked per key (committed shards only); with one, "
              "every key is read once."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ trade

FLOOR_UM = 1e-6     # errors below this (µm) are drawn at it: log axes


def um(x_mm: float) -> float:
    return max(1e3 * x_mm, FLOOR_UM)


def percent(x: float) -> str:
    return "—" if x is None or not math.isfinite(x) else (f"{x:.4f} %" if x < 0.01 else
                                                          f"{x:.3f} %" if x < 1 else f"{x:.2f} %")


def markdown_mesh(section) -> list:
    rows = section["rows"]
    angles = [lv["fe_angle_deg"] for lv in rows[0]["levels"]]
    head = " / ".join(f"{a:.0f}°" for a in angles)
    out = ["## (a) Mesh size and element order of the designed entry", "",
           f"Two neo-Hookean rod segments (R 10 mm, L 40 mm, E 1 MPa, ν 0.3), dead tip force; reference: the "
           f"full nonlinear FE on a P{section['reference']['order']} mesh of "
           f"{1e3 * section['reference']['mesh_size']:g} mm. "
           "Tip error in % of the trunk length at the FE tip angles "
           f"{head}. `own-mesh FE`: the full FE on the entry's mesh (its discretisation error alone); "
           "cost: wall time of the design on 2 workers (linear condensation / total).", "",
           "| entry | DoFs | design s (linear / total) | held-out load | own-mesh FE | nonlinear entry "
           "| linear entry |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        lv = r["levels"]
        out.append(f"| P{r['order']} h {1e3 * r['mesh_size']:g} mm | {r['dofs']} | {r['cost']['linear_s']:.2f} / "
                   f"{r['cost']['total_s']:.0f} | {100 * r['held_out_load_max']:.2f} % | "
                   + " / ".join(f"{x['same_mesh_fe_pct']:.3f}" for x in lv) + " % | "
                   + " / ".join(f"{x['nonlinear']['tip_error_pct']:.3f}"
                                + ("*" if x["nonlinear"]["out_of_range"] else "") for x in lv) + " % | "
                   + " / ".join(f"{x['linear']['tip_error_pct']:.3f}" for x in lv) + " % |")
    out += ["", "`*`: the runtime reported states outside the fitted range.", ""]
    est = section.get("reference_error")
    if est:
        out += [f"Own-mesh FE distances of the P2 meshes at {est['angle_deg']:.0f}° fit e(h) = c (h^q − h_ref^q) "
                f"with q = {est['order']:.2f} (largest misfit {est['fit_residual_pct']:.3f} % of length): the "
                f"reference itself is then ~{est['reference_error_pct']:.2f} % of length from the mesh-converged "
                "answer (an estimate, not a measurement).", ""]
    return out


def plot_mesh(ax, section):
    rows = section["rows"]
    top = -1
    for order, marker in ((1, "s"), (2, "o")):
        sel = [r for r in rows if r["order"] == order]
        if not sel:
            continue
        x = [r["cost"]["total_s"] for r in sel]
        ax.plot(x, [r["levels"][top]["nonlinear"]["tip_error_pct"] for r in sel], marker + "-",
                label=f"P{order} nonlinear entry")
        ax.plot([r["cost"]["linear_s"] for r in sel], [r["levels"][top]["linear"]["tip_error_pct"] for r in sel],
                marker + "--", mfc="none", label=f"P{order} linear entry")
        for r, xi in zip(sel, x):
            ax.annotate(f"{1e3 * r['mesh_size']:g} mm", (xi, r["levels"][top]["nonlinear"]["tip_error_pct"]),
                        fontsize=7, xytext=(3, 3), textcoords="offset points")
    angle = rows[0]["levels"][top]["fe_angle_deg"]
    ax.set(xlabel="design cost (wall s, 2 workers)", ylabel="tip error, % of length",
           title=f"(a) mesh size and order (2 rods, {angle:.0f}°)")


def markdown_fit(section) -> list:
    out = ["## (b) Fit degree and sampling density of ψ", "",
           f"Read from `{section['source']}` ({section['date']}; rod entry at {section['dofs']} DoFs, "
           f"{section['per_solve_s']:.2f} wall s per FE sample on {section['workers']} workers). Tip error: "
           "largest over trunks of 2 and 4 rods, planar and 3D, while the state stays in the fitted range "
           "(linear entries on the same cases in the last column); kernel: the links' part of one Newton "
           "evaluation for 20 links.", "",
           "| degree | loading paths | samples | sampling s (est.) | kernel µs | held-out load | tip error (in range) "
           "| up to | linear entries |", "|---|---|---|---|---|---|---|---|---|"]
    for r in section["rows"]:
        kernel = "—" if r["kernel_us"] is None else f"{r['kernel_us']:.0f}"
        out.append(f"| {r['degree']} | {r['paths']} | {r['samples']} | {r['sampling_s_estimate']:.0f} | {kernel} | "
                   f"{100 * r['held_out_load_max']:.2f} % | {percent(r['tip_max_in_range_pct'])} | "
                   f"{r['max_angle_in_range']:.0f}° | {percent(r['linear_max_in_range_pct'])} |")
    return out + [""]


def plot_fit(ax, section):
    for degree, marker in ((4, "s"), (6, "o"), (8, "^")):
        sel = sorted((r for r in section["rows"] if r["degree"] == degree), key=lambda r: r["samples"])
        if sel:
            ax.plot([r["sampling_s_estimate"] for r in sel], [r["tip_max_in_range_pct"] for r in sel],
                    marker + "-", label=f"degree {degree}")
    linear = max(r["linear_max_in_range_pct"] for r in section["rows"])
    ax.axhline(linear, color="grey", ls=":", label="linear entries")
    ax.set(xlabel="sampling cost (wall s, est.)", ylabel="largest tip error in range, % of length",
           title="(b) fit degree and sampling density")


def markdown_links(section) -> list:
    s = section["rod"]
    out = ["## (c) Links per segment (analytic beams)", "",
           f"A catalogue entry is one link between its two vertebrae by construction (`elements` must be 1); "
           f"the knob belongs to analytic beams. Soft slender rod: {s['count']} segments of "
           f"{1e3 * s['length']:g} mm, radius {1e3 * s['radius']:g} mm, E {s['youngs_modulus']:.0e} Pa, dead tip "
           f"force P L²/EI = k. Tip error in % of length against the inextensible elastica (closed form; the "
           f"extensible, shearable beam differs from it by a floor) and against {section['fine_links_per_segment']} "
           "links per segment of the same model; CPU ms per forward solve (interleaved medians).", "",
           "| k | tip angle | links per segment | links | vs elastica | vs fine | solve ms | iterations |",
           "|---|---|---|---|---|---|---|---|"]
    for r in section["rows"]:
        out.append(f"| {r['load_parameter']:g} | {r['tip_angle_deg']:.0f}° | {r['links_per_segment']} | "
                   f"{r['links']} | "
                   f"{percent(r['elastica_pct'])} | {percent(r['fine_pct'])} | {r['solve_ms']:.3f} | {r['iterations']} |")
    return out + [""]


def plot_links(ax, section):
    for k, marker in zip(sorted({r["load_parameter"] for r in section["rows"]}), "os^"):
        sel = [r for r in section["rows"] if r["load_parameter"] == k]
        line, = ax.plot([r["solve_ms"] for r in sel], [r["fine_pct"] for r in sel], marker + "-",
                        label=f"PL²/EI = {k:g} (vs fine)")
        ax.plot([r["solve_ms"] for r in sel], [r["elastica_pct"] for r in sel], marker + ":", mfc="none",
                color=line.get_color(), label=f"PL²/EI = {k:g} (vs elastica)")
        for r in sel:
            ax.annotate(str(r["links_per_segment"]), (r["solve_ms"], r["fine_pct"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    ax.set(xlabel="forward solve (CPU ms)", ylabel="tip error, % of length", title="(c) links per segment (beams)")


def markdown_entries(section) -> list:
    out = ["## (d) Linear vs nonlinear entries at increasing bending (the headline)", "",
           f"Trunks of four neo-Hookean rod segments (entry `{section['entry']}`, {section['dofs']} DoFs, "
           f"ψ of {section['terms']} terms), dead loads; reference: the full nonlinear FE of the same meshes. Tip "
           "error in % of the trunk length; CPU ms per forward solve from rest (interleaved medians) with its "
           "Newton iterations; `*`: states reported outside the fitted range.", "",
           "| case | FE tip angle | nonlinear: tip error | ms (it) | linear: tip error | ms (it) | FE wall s |",
           "|---|---|---|---|---|---|---|"]
    for r in section["rows"]:
        nl, li = r["nonlinear"], r["linear"]
        fe = "cached" if r["fe_seconds"] is None else f"{r['fe_seconds']:.0f}"
        out.append(f"| {r['case']} ×{r['level']:g} | {r['fe_angle_deg']:.0f}° | {percent(nl['tip_error_pct'])}"
                   f"{'*' if nl['out_of_range'] else ''} | {nl['solve_ms']:.2f} ({nl['iterations']}) | "
                   f"{percent(li['tip_error_pct'])} | {li['solve_ms']:.2f} ({li['iterations']}) | {fe} |")
    return out + [""]


def plot_entries(ax, section):
    for case, marker in zip(sorted({r["case"] for r in section["rows"]}), "os"):
        sel = [r for r in section["rows"] if r["case"] == case]
        for kind, style in (("nonlinear", "-"), ("linear", "--")):
            x = [r[kind]["solve_ms"] for r in sel]
            y = [r[kind]["tip_error_pct"] for r in sel]
            ax.plot(x, y, marker + style, mfc="none" if kind == "linear" else None, label=f"{case}: {kind} entries")
            for r, xi, yi in zip(sel, x, y):
                ax.annotate(f"{r['fe_angle_deg']:.0f}°", (xi, yi), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
    ax.set(xlabel="forward solve (CPU ms)", ylabel="tip error vs full nonlinear FE, % of length",
           title="(d) linear vs nonlinear entries (labels: tip angle)")


def plot_entries_by_angle(ax, section):
    """The same errors against the FE tip angle (the companion of the headline panel)."""
    for case, marker in zip(sorted({r["case"] for r in section["rows"]}), "os"):
        sel = [r for r in section["rows"] if r["case"] == case]
        for kind, style in (("nonlinear", "-"), ("linear", "--")):
            ax.plot([r["fe_angle_deg"] for r in sel], [r[kind]["tip_error_pct"] for r in sel], marker + style,
                    mfc="none" if kind == "linear" else None, label=f"{case}: {kind} entries")
    ax.set(xlabel="tip angle of the full FE (°)", ylabel="tip error vs full nonlinear FE, % of length",
           title="(d) the same against bending")


def markdown_tolerance(section) -> list:
    out = ["## (e) Newton tolerance", "",
           f"{section['case']} (nonlinear entries, FE tip angle {section['fe_angle_deg']:.0f}°): tip difference "
           "to a solve at 1e-13 and tip error against the full nonlinear FE, in % of length; CPU ms per solve "
           "from rest. The tolerance bounds the scaled residual (see the solver docs).", "",
           "| tolerance | iterations | residual | vs tightest | vs full FE | solve ms |", "|---|---|---|---|---|---|"]
    for r in section["rows"]:
        out.append(f"| {r['tolerance']:g} | {r['iterations']} | {r['residual']:.1e} | {r['vs_tightest_pct']:.1e} % | "
                   f"{percent(r['vs_fe_pct'])} | {r['solve_ms']:.2f} |")
    return out + [""]


def plot_tolerance(ax, section):
    rows = section["rows"]
    floor = 1e-12
    x = [r["solve_ms"] for r in rows]
    ax.plot(x, [max(r["vs_tightest_pct"], floor) for r in rows], "o-", label="vs tightest solve")
    ax.plot(x, [r["vs_fe_pct"] for r in rows], "s--", label="vs full nonlinear FE")
    for r, xi in zip(rows, x):
        ax.annotate(f"{r['tolerance']:g}", (xi, max(r["vs_tightest_pct"], floor)), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")
    ax.set(xlabel="forward solve (CPU ms)", ylabel="tip error, % of length", title="(e) Newton tolerance")


def markdown_tick(section) -> list:
    out = ["## (f) Tick vs converged inverse", "",
           f"{section['slices']} CBHA-like slices with nonlinear entries, three chambers (0–1.5 bar); the tip "
           f"target runs once round a horizontal circle of {1e3 * section['radius_m']:g} mm radius about the tip "
           "reached at 0.6/0.3/0.3 bar. Error: distance from the target of the equilibrium that the commanded "
           "pressures reach (a tick's own state is a linear prediction, so every step is solved to equilibrium "
           "after the run); time: CPU ms per step of the timed run (median of interleaved repeats).", "",
           "| mode | targets per lap | target step | ms per step | mean error | max error |",
           "|---|---|---|---|---|---|"]
    for r in section["rows"]:
        out.append(f"| {r['mode']} | {r['points_per_lap']} | {r['target_step_mm']:.2f} mm | {r['step_ms']:.2f} | "
                   f"{1e3 * r['mean_error_mm']:.3g} µm | {1e3 * r['max_error_mm']:.3g} µm |")
    return out + [""]


def plot_tick(ax, section):
    for mode, marker in (("tick", "o"), ("converged", "s")):
        sel = [r for r in section["rows"] if r["mode"] == mode]
        ax.plot([r["step_ms"] for r in sel], [um(r["max_error_mm"]) for r in sel], marker + "-", label=f"{mode}: max")
        ax.plot([r["step_ms"] for r in sel], [um(r["mean_error_mm"]) for r in sel], marker + ":", mfc="none",
                label=f"{mode}: mean")
        for r in sel:
            ax.annotate(f"{r['points_per_lap']}/lap", (r["step_ms"], um(r["max_error_mm"])), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    ax.set(xlabel="inverse step (CPU ms)", ylabel="tracking error at equilibrium (µm)", title="(f) tick vs converged")


def markdown_qp(section) -> list:
    out = ["## (g) QP tolerance and regularisation of the inverse", "",
           f"{section['slices']} CBHA slices (nonlinear entries), {section['targets']} targets round the circle "
           "of (f). "
           "The regularisation is swept with the exact QP (`daqp`, which has no tolerance); the QP tolerance "
           "with the iterative Gauss–Seidel QP at the default regularisation. Error: distance of the "
           "equilibrium reached from the target (µm); CPU ms per step.", "",
           "| mode | QP | regularisation | QP tolerance | ms per step | mean error µm | max error µm |",
           "|---|---|---|---|---|---|---|"]
    for r in section["rows"]:
        tol = "—" if r["backend"] == "daqp" else f"{r['qp_tolerance']:g}"
        out.append(f"| {r['mode']} | {r['backend']} | {r['regularisation']:g} | {tol} | {r['step_ms']:.2f} | "
                   f"{1e3 * r['mean_error_mm']:.3g} | {1e3 * r['max_error_mm']:.3g} |")
    return out + [""]


def plot_qp(ax, section):
    groups = sorted({(r["mode"], r["backend"]) for r in section["rows"]})
    for (mode, backend), marker in zip(groups, "os^d"):
        sel = [r for r in section["rows"] if r["mode"] == mode and r["backend"] == backend]
        knob = "regularisation" if backend == "daqp" else "qp_tolerance"
        ax.plot([r["step_ms"] for r in sel], [um(r["max_error_mm"]) for r in sel], marker + "-",
                label=f"{mode}, {backend}: {knob.replace('_', ' ')}")
        for r in sel:
            ax.annotate(f"{r[knob]:g}", (r["step_ms"], um(r["max_error_mm"])), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
    ax.set(xlabel="inverse step (CPU ms)", ylabel="max target error at equilibrium (µm)",
           title="(g) QP regularisation and tolerance (labels)")


def markdown_cbha(section) -> list:
    out = ["## (h) CBHA-like pneumatic section: forward and inverse, linear vs nonlinear entries", "",
           f"{section['slices']} slices (R 40 mm, three chambers r 10 mm at 21.5 mm, L 30 mm, E 0.5 MPa, ν 0.45; "
           f"entry {section['entry']}, {section['dofs']} DoFs, ψ of {section['terms']} terms) against the full "
           "nonlinear FE with follower pressure on the same meshes.", "",
           "### Forward: chamber 0 pressurised", "",
           "Tip error in % of length; bending angle and chamber volume growth relative to the FE; CPU ms per "
           "solve.", "",
           "| pressure | FE angle | nonlinear: tip | angle | volume | ms | linear: tip | angle | volume | ms |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in section["forward"]:
        if "failed" in r:
            out.append(f"| {r['pressure_bar']:g} bar | FE failed: {r['failed']} |||||||||")
            continue
        nl, li = r["nonlinear"], r["linear"]
        out.append(f"| {r['pressure_bar']:g} bar | {r['fe_angle_deg']:.1f}° | {percent(nl['tip_error_pct'])}"
                   f"{'*' if nl['out_of_range'] else ''} | {nl['angle_error_pct']:+.2f} % | "
                   f"{nl['volume_error_pct']:+.2f} % | "
                   f"{nl['solve_ms']:.2f} | {percent(li['tip_error_pct'])} | {li['angle_error_pct']:+.1f} % | "
                   f"{li['volume_error_pct']:+.1f} % | {li['solve_ms']:.2f} |")
    out += ["", "### Inverse: chamber pressures for a target tip position, applied to the full FE", "",
            "The target is the FE tip under the pressures of the first column (so it is reachable); each model "
            "computes pressures (converged inverse, bounds 0–1.5 bar), which are then applied to the full "
            "nonlinear FE. `model error`: what the model believes; `FE error`: the achieved tip's distance from "
            "the target, in % of length.", "",
            "| target from (bar) | offset | nonlinear: pressures (bar) | model error | FE error | ms | "
            "linear: pressures (bar) | model error | FE error | ms |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in section["inverse"]:
        if "failed" in r:
            out.append(f"| {r['pressures_bar']} | FE failed: {r['failed']} |||||||||")
            continue
        cells = []
        for kind in ("nonlinear", "linear"):
            k = r[kind]
            fe = percent(k["fe_error_pct"]) if k["fe_error_pct"] is not None else f"FE failed ({k['fe_failed'][:40]})"
            cells.append(f"{' / '.join(f'{x:.3f}' for x in k['pressures_bar'])} | {percent(k['model_error_pct'])} | "
                         f"{fe} | {k['invert_ms']:.1f}")
        out.append(f"| {' / '.join(f'{x:g}' for x in r['pressures_bar'])} | {r['target_offset_pct']:.1f} % | "
                   + " | ".join(cells) + " |")
    return out + [""]


def plot_cbha(ax, section):
    rows = [r for r in section["forward"] if "failed" not in r]
    for kind, style in (("nonlinear", "o-"), ("linear", "s--")):
        ax.plot([r[kind]["solve_ms"] for r in rows], [r[kind]["tip_error_pct"] for r in rows], style,
                mfc="none" if kind == "linear" else None, label=f"forward, {kind} entries")
        for r in rows:
            ax.annotate(f"{r['pressure_bar']:g} bar", (r[kind]["solve_ms"], r[kind]["tip_error_pct"]), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
    inv = [r for r in section["inverse"] if "failed" not in r]
    for kind, marker in (("nonlinear", "*"), ("linear", "X")):
        sel = [r for r in inv if r[kind]["fe_error_pct"] is not None]
        ax.plot([r[kind]["invert_ms"] for r in sel], [r[kind]["fe_error_pct"] for r in sel], marker, ms=9,
                label=f"inverse → FE, {kind} entries")
    ax.set(xlabel="solve / inverse (CPU ms)", ylabel="tip error vs full nonlinear FE, % of length",
           title="(h) CBHA section, 0–1.5 bar")


def trade(results: dict) -> str:
    m = results["machine"]
    out = ["# The speed–accuracy trade", "",
           f"Machine: {m['host']}, Python {m['python']}, {m['date']}, load average {m['loadavg'][0]:.1f} → "
           f"{m['loadavg'][1]:.1f}. Produced by `benchmarks/bench_trade.py`; how to read it: `docs/trade.md`. "
           "Timings: CPU time of the thread, one BLAS thread, medians of interleaved rounds.", ""]
    for name, (write, *_) in TRADE.items():
        if results.get(name):
            out += write(results[name])
    return "\n".join(out)


def trade_pictures(results: dict, directory: Path) -> list:
    """One picture per knob (error vs cost, log axes; a companion panel where a section has one)
    and a summary of all the knobs' main panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def draw(ax, plot, section, xlog=True):
        plot(ax, section)
        ax.set_xscale("log" if xlog else "linear")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)

    names = [name for name in TRADE if results.get(name)]
    written = []
    cols = 2
    rows = (len(names) + cols - 1) // cols
    summary, axes = plt.subplots(rows, cols, figsize=(6.2 * cols, 4.4 * rows), squeeze=False)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    for name, ax in zip(names, axes.flat):
        main_plot, *extra = TRADE[name][1:]
        draw(ax, main_plot, results[name])
        fig, panels = plt.subplots(1, 1 + len(extra), figsize=(6.4 * (1 + len(extra)), 4.6), squeeze=False)
        draw(panels[0, 0], main_plot, results[name])
        for ax_extra, plot in zip(panels[0, 1:], extra):
            draw(ax_extra, plot, results[name], xlog=False)
        fig.tight_layout()
        path = directory / f"trade-{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    summary.tight_layout()
    path = directory / "trade.png"
    summary.savefig(path, dpi=90)
    plt.close(summary)
    return written + [path]


# ------------------------------------------------------------------ inverse

def inverse(document: dict) -> str:
    head = ("| frames | actuators | effectors | linearise ms | W ms | QP ms | step ms | tick ms (CPU) | tick wall ms "
            "| inside the tick: linearise / W / QP / step / total ms |")
    sep = "|---|---|---|---|---|---|---|---|---|---|"

    def fmt(r):
        return (f"| {r['frames']} | {r['actuators']} | {r['effectors']} | {ms3(r['linearise_s'])} | "
                f"{ms3(r['W_s'])} | {ms3(r['qp_s'])} | {ms3(r['step_s'])} | {ms3(r['tick_s'])} | "
                f"{ms3(r['wall_tick_s'])} | " + " / ".join(ms3(r['in_tick'][k]) for k in
                                                          ("linearise_s", "W_s", "qp_s", "step_s", "total_s")) + " |")

    vertebrae, exponents = document["vertebrae"], document["vertebrae_exponents"]
    lines = ["# Inverse step timings (median CPU time of the thread; see median_time)", "", document["host"], "",
             "Columns linearise … step time each piece alone through its public function (W: "
             "`ConstraintSpace.project`); 'tick' is `InverseController.step` in tick mode, and "
             "'inside the tick' the medians of its own `timings` (wall clock).", "",
             "## Gallery robots (3 interleaved rounds, median of the rounds)", "",
             "| scene " + head + " paper |", "|---" + sep + "---|"]
    for r in document["scenes"]:
        lines.append(f"| {r['scene']} " + fmt(r) + f" {r['paper']} |")
    lines += ["", "## Growing frames (paper_5v_16t, links per segment)", "", "| links/segment " + head,
              "|---" + sep]
    for r in document["frames"]:
        lines.append(f"| {r['elements_per_segment']} " + fmt(r))
    lines += ["", "## Growing vertebrae (paper_5v_16t with k× the vertebrae, tendons running k× as far: "
              "same band width)", "", "| k " + head, "|---" + sep]
    for r in vertebrae:
        lines.append(f"| {r['factor']} " + fmt(r))
    lines += ["", "Growth exponents against frames (log–log fit over k = "
              f"{vertebrae[0]['factor']}…{vertebrae[-1]['factor']}): W alone {exponents['W_s']:.2f}, "
              f"W inside the tick {exponents['W_in_tick']:.2f}, linearise {exponents['linearise_s']:.2f}, "
              f"whole tick {exponents['tick_s']:.2f}."]
    lines += ["", "## Growing actuators (paper_5v_16t, tendons)", "", head, sep]
    for r in document["actuators"]:
        lines.append(fmt(r))
    lines += ["", "## One step per tick vs converged (paper_5v_16t along a reachable loop)", "",
              "| effectors | mode | median step ms | max step ms | median error m | max error m | target spacing m |",
              "|---|---|---|---|---|---|---|"]
    for r in document["modes"]:
        lines.append(f"| {r['effectors']} | {r['mode']} | {ms3(r['median_step_s'])} | {ms3(r['max_step_s'])} | "
                     f"{r['median_error_m']:.2e} | {r['max_error_m']:.2e} | {r['loop_step_m']:.2e} |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ qp

def qp(document: dict) -> str:
    summary = {}
    for r in document["rows"]:
        key = (r["backend"], r["n_act"], r["n_rows"], r["stroke"])
        s = summary.setdefault(key, dict(times=[], err=[], obj=[], viol=[], fail=0))
        s["times"].append(r["time_s"])
        s["err"].append(r["effort_error"])
        s["obj"].append(r["objective_rel"])
        s["viol"].append(r["bound_violation"])
        s["fail"] += not r["converged"]
    lines = ["# QP backends (synthetic constraint-space problems)", "",
             f"host: {document['host']} · python {document['python']} · "
             f"OMP_NUM_THREADS={document['OMP_NUM_THREADS']}", "",
             "Objective: excess over DAQP's optimum relative to ½‖δe_free‖² (> 0: worse). Effort error: max |Δλ| /"
             " max |λ| vs DAQP — large only where the optimum is flat (redundant actuators: the"
             " null space is decided by the 1e-8 regulariser alone).", "",
             "| backend | actuators | rows | stroke limits | median time | max objective excess | max effort error | max bound violation | not converged |",
             "|---|---|---|---|---|---|---|---|---|"]
    for (backend, n_act, n_rows, stroke), s in sorted(summary.items(), key=lambda kv: (kv[0][1], kv[0][2], kv[0][3], kv[0][0])):
        lines.append(f"| {backend} | {n_act} | {n_rows} | {stroke} | {np.median(s['times']) * 1e6:.0f} µs | "
                     f"{max(s['obj']):.1e} | {max(s['err']):.1e} | {max(s['viol']):.1e} | {s['fail']} |")
    lines += ["", "## Regularisation ε (16 tendons, one 3-D target; DAQP)", "",
              "| ε | reachable bias (error / free gap) | circle: max step / median step | mean total tension |",
              "|---|---|---|---|"]
    for r in document["epsilon"]:
        lines.append(f"| {r['epsilon']:.0e} | {r['bias_max']:.1e} | {r['smoothness']:.2f}"
                     f"{'' if r['all_converged'] else ' (some failed)'} | {r['mean_tension']:.3g} |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ catalogue

def catalogue(result: dict) -> str:
    md = ["# Catalogue store benchmark", "",
          f"{result['date']} on {result['host']} (2 shared cores), Python {result['python']}, "
          f"load average {result['loadavg_start'][0]:.1f} → {result['loadavg_end'][0]:.1f}. "
          "Entries have one cavity (7×7 compliance) and realistic metadata.", "",
          "| measurement | value | note |", "|---|---:|---|"]
    md += [f"| {a} | {b} | {c} |" for a, b, c in result["rows"]]
    md += ["", "Produced by `benchmarks/bench_catalogue.py`."]
    return "\n".join(md) + "\n"


# ------------------------------------------------------------------ prepare

def prepare(rows: list) -> str:
    date, host, cpus = rows[0]["date"], rows[0]["host"], rows[0]["cpus"]
    lines = ["# vertebra prepare on gallery:cbha_design (16 coarse P2 slices, no accuracy estimate)", "",
             f"{date}, {host}, {cpus} CPUs", "",
             "| executor | workers | load | first run s | entries/min | second run s | range estimate s (solves) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['executor']} | {r['workers']} | {r['loadavg']} | {r['first_s']:.1f} | "
                     f"{r['entries_per_minute']:.1f} | {r['second_s']:.2f} | {r['ranges_s']:.2f} "
                     f"({r['range_solves']}, {r['range_failed']} failed) |")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ workspace

def workspace(document: dict) -> str:
    serial, parallel = document["acceptance"]["serial"], document["acceptance"]["two_workers"]
    calibration, orders, tolerances = document["calibration"], document["orders"], document["tolerance"]
    quick, target = document["quick"], document["target_s"]
    load_start, load_end = document["load_average_start"], document["load_average_end"]
    slowdown = calibration["slowdown"]
    lines = [
        "# Workspace sampling benchmark", "",
        f"`benchmarks/bench_workspace.py` · {document['date']} · host "
        f"{document['host']} ({document['cpus']} CPUs, shared) · python {document['python']} · numpy "
        f"{document['numpy']} · commit `{document['commit']}`" + (" · **--quick**" if quick else ""), "",
        f"Load average (1/5/15 min) at start {[round(v, 2) for v in load_start]}, at end "
        f"{[round(v, 2) for v in load_end]} on {document['cpus']} cores: wall times are inflated by other jobs; "
        "CPU time (`time.process_time`, worker processes included) is the figure to compare.", "",
        f"## 1. Acceptance: {serial['samples']} samples of paper_5v_16t ≤ {target:g} s", "",
        "| workers | wall s | CPU s | samples/s (wall) | samples/s (CPU) | CPU ms/sample | order s | "
        "Newton iterations mean (max) | iterations histogram | failures | met (wall) |",
        "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in (serial, parallel):
        lines.append(f"| {row.get('workers', 1)} | {row['wall_s']:.2f} | {row['cpu_s']:.2f} | "
                     f"{row['samples_per_s_wall']:.0f} | {row['samples_per_s_cpu']:.0f} | "
                     f"{row['cpu_ms_per_sample']:.3f} | {row['order_s']:.2f} | {row['iterations_mean']:.2f} "
                     f"({row['iterations_max']}) | {row['iterations_histogram']} | {row['failures']} | "
                     f"{'-' if quick else ('yes' if row['wall_s'] <= target else 'no')} |")
    if slowdown:
        quiet_s, quiet_load = calibration["quiet_reference_cpu_s"], calibration["quiet_reference_loadavg"]
        lines += ["", f"Slowdown at the time of this run: a reference solve (paper_5v_16t, 3 N on every fourth "
                  f"tendon, from rest) took {1e3 * np.mean(calibration['reference_solve_cpu_s']):.3f} ms CPU against "
                  f"{1e3 * quiet_s:.3f} ms in `results/solver.json` (load {quiet_load[0]}): ×{slowdown:.2f}. "
                  f"Divided by it, the single-process run is ≈ {calibration['serial_cpu_s_on_quiet_machine']:.1f} s "
                  f"CPU on the quiet machine, and two workers would take ≈ "
                  f"{calibration['two_workers_wall_s_on_quiet_machine']:.1f} s wall on two free cores "
                  "(estimates, not measurements)."]
    lines += ["", f"## 2. Solve orders ({orders[0]['samples']} samples, same actuations)", "",
              "Each sample starts from its parent in the order: from the Euler predictor off the parent's "
              "equilibrium (`sample_workspace`), or from that equilibrium itself (baseline).", "",
              "| ordering | start | Newton iterations mean (max) | CPU ms/sample | failures |", "|---|---|---|---|---|"]
    for r in orders:
        lines.append(f"| {r['ordering']} | {'Euler predictor' if r['predictor'] else 'parent equilibrium'} | "
                     f"{r['iterations_mean']:.2f} ({r['iterations_max']}) | {r['cpu_ms_per_sample']:.3f} | "
                     f"{r['failures']} |")
    lines += ["", f"## 3. Newton tolerance ({tolerances[0]['samples']} samples; error against solves at 1e-13)", "",
              "| tolerance | Newton iterations mean | CPU ms/sample | median error m | max error m |",
              "|---|---|---|---|---|"]
    for r in tolerances:
        lines.append(f"| {r['tolerance']:g} | {r['iterations_mean']:.2f} | {r['cpu_ms_per_sample']:.3f} | "
                     f"{r['median_error_m']:.1e} | {r['max_error_m']:.1e} |")
    lines += ["", "Picture: `workspace_tolerance.png` (section 3, error vs cost)."]
    return "\n".join(lines) + "\n"


def tolerance_picture(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    cost = [r["cpu_ms_per_sample"] for r in rows]
    error = [max(r["max_error_m"], 1e-16) for r in rows]
    ax.semilogy(cost, error, "o-")
    for r, c, e in zip(rows, cost, error):
        ax.annotate(f"tol {r['tolerance']:g}", (c, e), textcoords="offset points", xytext=(5, 3), fontsize=7)
    ax.set_xlabel("CPU time per sample [ms]")
    ax.set_ylabel("largest effector error vs tolerance 1e-13 [m]")
    ax.set_title("paper_5v_16t workspace: Newton tolerance, error vs cost")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def workspace_pictures(document: dict, directory: Path) -> list:
    path = directory / "workspace_tolerance.png"
    tolerance_picture(document["tolerance"], path)
    return [path]


# ------------------------------------------------------------------ the studies

TRADE = {
    "mesh": (markdown_mesh, plot_mesh),
    "fit": (markdown_fit, plot_fit),
    "links": (markdown_links, plot_links),
    "entries": (markdown_entries, plot_entries, plot_entries_by_angle),
    "tolerance": (markdown_tolerance, plot_tolerance),
    "tick": (markdown_tick, plot_tick),
    "qp": (markdown_qp, plot_qp),
    "cbha": (markdown_cbha, plot_cbha),
}

# study: (its tables, its pictures or None, where the pictures go: docs/ or the results folder)
STUDIES = {
    "accuracy": (accuracy, None, None),
    "catalogue": (catalogue, None, None),
    "catalogue_fuzz": (catalogue_fuzz, None, None),
    "ccx_crosscheck": (ccx_crosscheck, None, None),
    "designer": (designer, None, None),
    "inverse": (inverse, None, None),
    "nonlinear": (nonlinear, nonlinear_pictures, DOCS),
    "nonlinear_acceptance": (nonlinear_acceptance, None, None),
    "nonlinear_fe": (nonlinear_fe, None, None),
    "prepare": (prepare, None, None),
    "prepare_ranges": (prepare_ranges, None, None),
    "qp": (qp, None, None),
    "robustness": (robustness, None, None),
    "runtime_nonlinear": (runtime_nonlinear, None, None),
    "solver": (solver, None, None),
    "sweep": (sweep, None, None),
    "trade": (trade, trade_pictures, DOCS),
    "workspace": (workspace, workspace_pictures, RESULTS),
}


def study_of(stem: str) -> str:
    """The study a results file belongs to (``solver-quick`` → ``solver``)."""
    return stem.removesuffix("-quick")


def markdown(study: str, document) -> str:
    """The Markdown tables of ``document``, a result of ``study`` (ending in one newline)."""
    return STUDIES[study][0](document).rstrip("\n") + "\n"


def pictures(study: str, document, directory: Path | None = None) -> list:
    """Draw ``study``'s pictures of ``document`` into ``directory`` (default: the study's own
    place); the paths written."""
    _, draw, default = STUDIES[study]
    if draw is None:
        return []
    directory = default if directory is None else directory
    directory.mkdir(parents=True, exist_ok=True)
    return draw(document, directory) or []


def write(study: str, document, out: Path = RESULTS, *, stem: str | None = None, pictures_to: Path | None = None,
          draw: bool = True) -> list:
    """``document`` as ``out/STEM.json``, its tables as ``out/STEM.md`` and (``draw``) its pictures;
    the paths written. ``stem`` defaults to the study's name."""
    stem = stem or study
    written = [write_json(document, out / f"{stem}.json"), out / f"{stem}.md"]
    written[1].write_text(markdown(study, document))
    if draw:
        written += pictures(study, document, pictures_to)
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="re-render the studies' tables and pictures from their JSON")
    parser.add_argument("names", nargs="*", help=f"results to render (default: every one of {', '.join(STUDIES)} "
                                                 "found in the results folder)")
    parser.add_argument("--results", type=Path, default=RESULTS, help="results folder (default benchmarks/results)")
    parser.add_argument("--pictures", type=Path, default=None,
                        help="draw the pictures into this folder (default: each study's own, docs/ or the results folder)")
    parser.add_argument("--no-pictures", action="store_true", help="tables only")
    args = parser.parse_args(argv)
    names = args.names or [name for name in STUDIES if (args.results / f"{name}.json").exists()]
    failed = []
    for name in names:
        if study_of(name) not in STUDIES:
            parser.error(f"unknown study {name!r} (known: {', '.join(STUDIES)})")
        document = json.loads((args.results / f"{name}.json").read_text())
        try:
            text = markdown(study_of(name), document)
        except KeyError as missing:       # a document written before its table gained a field
            print(f"{name}: not rendered, the JSON has no field {missing} (rerun the study)", file=sys.stderr)
            failed.append(name)
            continue
        (args.results / f"{name}.md").write_text(text)
        drawn = [] if args.no_pictures else pictures(study_of(name), document, args.pictures)
        print(f"{name}: {args.results / (name + '.md')}" + "".join(f", {p}" for p in drawn))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
