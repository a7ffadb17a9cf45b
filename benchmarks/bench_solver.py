"""Benchmark of the runtime forward solver (solver/): speed and accuracy rows.

Sections (each a table in ``results/solver.md`` and a key in ``results/solver.json``):

1. ``scaling``     cantilever (steel rod r = 1 mm, L = 0.5 m, dead tip load PL²/EI = 1, fixed as
                   the frames grow) with 10 … 10 000 links: median solve time, Newton iterations,
                   tangent evaluations, time per iteration, and the banded factor + solve alone;
                   log–log least-squares growth exponents between 100 and 10 000 links.
2. ``gallery``     every gallery scene: median wall time of ≥ 20 solves after a warm-up, the
                   solver's own ``timings["solve_s"]``, iterations; cold vs warm-started re-solves
                   along a trajectory of 1 % load/actuation changes (what a control loop does).
3. ``accuracy``    cantilever tip error (% of L) vs the inextensible elastica and vs a fine
                   discretisation (320 links) of the same extensible/shearable model, with time;
                   observed convergence order.
4. ``coil``        pure end moment of 1 and 1.25 full turns: closure / arc error, iterations, time.
5. ``tolerance``   Newton tolerance 1e-4 … 1e-12 (20 links, PL²/EI = 5): tip error vs the tightest
                   solve, iterations, time.
6. ``one_step``    one linearised Newton step after a 1 % load change vs a converged warm re-solve,
                   and a 20-tick trajectory run with one step per tick.

The machine may be shared: every timing is a median (the minimum is kept too), the load average
is recorded before and after each section, and only ratios measured in the same run should be
compared.

Run: ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_solver [--quick]``;
writes ``benchmarks/results/solver.json`` and ``benchmarks/results/solver.md`` (``--quick`` writes
``solver-quick.*`` into ``--out`` or, by default, a temporary directory: a smoke run never touches
the committed results). Per-commit speed and A/B comparisons of commits: the asv benchmarks
(docs/benchmarks.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import gc  # noqa: E402
import hashlib  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from benchmarks import render  # noqa: E402
from benchmarks.common import RESULTS, ROOT, loadavg, timed  # noqa: E402
from benchmarks.render import fmt_time, sci_percent  # noqa: E402
from tests.reference.complex_step import link_gradient, pair_tangent  # noqa: E402
from vertebra import solver  # noqa: E402
from vertebra.solver import analytic, gallery  # noqa: E402
from vertebra.solver.banded import factor_cholesky, factor_lu  # noqa: E402
from vertebra.solver.links import Links, link_tangent  # noqa: E402

# gallery scenes the runtime builds as they are (scenes of design segments need `vertebra prepare`)
RUNTIME_SCENES = [name for name in gallery.names() if not getattr(gallery.load(name), "design_segments", ())]

# the rod of the gallery cantilever: steel, r = 1 mm, L = 0.5 m
E, NU, RADIUS, LENGTH = 200e9, 0.3, 1e-3, 0.5
EI = E * math.pi * RADIUS ** 4 / 4.0


# --------------------------------------------------------------------------- helpers
def rod_segment(links):
    """One beam segment, ``links`` links in one repetition (the gallery's way of writing it)."""
    return {"type": "beam", "count": 1, "length": LENGTH, "elements": int(links),
            "youngs_modulus": E, "poisson_ratio": NU, "section": {"shape": "circle", "radius": RADIUS}}


def cantilever(links, load_parameter=1.0, tolerance=1e-9, max_iterations=100, force_scale=1.0):
    P = load_parameter * EI / LENGTH ** 2 * force_scale
    return solver.parse_scene({
        "name": f"cantilever-{links}",
        "solver": {"tolerance": tolerance, "max_iterations": max_iterations},
        "segment": [rod_segment(links)],
        "load": [{"vertebra": -1, "force": [P, 0.0, 0.0]}],
        "effector": [{"name": "tip", "vertebra": -1}],
    })


def end_moment(links, turns, tolerance=1e-9):
    M = turns * 2.0 * math.pi * EI / LENGTH
    return solver.parse_scene({
        "name": f"coil-{links}-{turns}",
        "solver": {"tolerance": tolerance, "max_iterations": 100},
        "segment": [rod_segment(links)],
        "load": [{"vertebra": -1, "moment": [0.0, M, 0.0]}],
    })


def tip_xz(result):
    p = result.state.positions[-1]
    return np.array([p[0], p[2]])


def count_evaluations(model, fn):
    """Run ``fn()`` once with the Newton solver's gradient evaluations and tangent assemblies
    counted (not timed)."""
    from vertebra.solver import newton
    original, original_tangent = newton.evaluate, newton.tangent
    counts = {"tangent": 0, "gradient": 0}

    def counted(*args):
        counts["gradient"] += 1
        return original(*args)

    def counted_tangent(*args):
        counts["tangent"] += 1
        return original_tangent(*args)

    newton.evaluate, newton.tangent = counted, counted_tangent
    try:
        out = fn()
    finally:
        newton.evaluate, newton.tangent = original, original_tangent
    return out, counts


def evaluation_pieces(model, state, act, reps, budget_s=None):
    """Timings of one Newton iteration's pieces at ``state``: gradient (``evaluate``), gradient and
    tangent, the tangent's symmetric band; returns (tangent, rhs, timings)."""
    from vertebra.solver.potential import tangent
    trunk = model.trunk
    matrix, t_tan = timed(lambda: tangent(trunk, model.evaluate(state, act)), reps, budget_s=budget_s)
    ev, t_grad = timed(lambda: model.evaluate(state, act), reps, budget_s=budget_s)
    # a fresh Tangent per call: a tangent keeps its band once gathered
    _, t_band = timed(lambda: type(matrix)(matrix.assembler, matrix.terms).symmetric_band(), reps,
                      budget_s=budget_s)
    return matrix, -ev.gradient[1:].reshape(-1), {"tangent": t_tan, "gradient": t_grad, "band": t_band}


def fit_exponent(x, y):
    """Least-squares slope of log y against log x."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    slope, _ = np.polyfit(lx, ly, 1)
    return float(slope)


def active_actuation(model):
    """The scene's actuation, or (when it is all zero, as in the paper scenes) 3 N on every fourth
    cable (t1, t5, …: one tendon per termination group, bending the trunk to one side)."""
    a = model.default_actuation.copy()
    if not np.any(a):
        a[:model.n_cables:4] = 3.0
    return a


def git_info():
    def run(*args):
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=20).stdout
        except Exception:  # noqa: BLE001
            return ""
    diff = run("diff", "HEAD", "--", "solver")
    return {"commit": run("rev-parse", "HEAD").strip(),
            "solver_dirty": bool(diff.strip()),
            "solver_diff_sha1": hashlib.sha1(diff.encode()).hexdigest() if diff.strip() else None,
            "solver_diff_files": run("diff", "--stat", "HEAD", "--", "solver").strip().splitlines()}


# --------------------------------------------------------------------------- 1. scaling
def bench_scaling(quick):
    sizes = [10, 30, 100, 300, 1000] if quick else [10, 30, 100, 300, 1000, 3000, 10000]
    rows = []
    # all sizes are timed in interleaved rounds, so that load changes on the shared machine hit
    # every size alike (the growth exponent compares sizes)
    models, results, walls, cpus = {}, {}, {}, {}
    for links in sizes:
        model = solver.build_model(cantilever(links))
        if model.trunk.assembler.kd > 11 and links > 300:
            rows.append({"links": links, "frames": model.n_frames, "kd": model.trunk.assembler.kd, "skipped":
                         "band not narrow (half bandwidth > 11) — dense-like cost, skipped"})
            continue
        models[links] = model
        t0 = time.perf_counter()
        results[links] = model.solve()                     # warm-up
        walls[links], cpus[links] = [], []
        results[links + 0.5] = time.perf_counter() - t0
    rounds = 3 if quick else 7
    for _ in range(rounds):
        for links, model in models.items():
            per_round = int(max(1, min(8, 0.25 / max(results[links + 0.5], 1e-6))))
            _, t = timed(lambda: model.solve(), per_round, warmup=0)
            walls[links].append(t["median_s"]), cpus[links].append(t["cpu_median_s"])
    for links, model in models.items():
        la = loadavg()
        kd = model.trunk.assembler.kd
        result = results[links]
        budget = 4.0 if quick else 12.0
        t = {"median_s": float(np.median(walls[links])), "min_s": float(np.min(walls[links])),
             "cpu_median_s": float(np.median(cpus[links])), "rounds": rounds}
        solve_s = float(result.timings["solve_s"])
        # the pieces of one iteration, at the converged state
        state, act = result.state, model.default_actuation
        reps = 7 if links >= 3000 else 21
        _, evals = count_evaluations(model, lambda: model.solve())
        matrix, rhs, pieces = evaluation_pieces(model, state, act, reps, budget / 4)
        t_tan, t_grad, t_band = pieces["tangent"], pieces["gradient"], pieces["band"]
        ab = matrix.symmetric_band()
        fac, t_fac = timed(lambda: factor_cholesky(ab), reps, budget_s=budget / 4)
        _, t_sol = timed(lambda: fac.solve(rhs), reps, budget_s=budget / 4)
        _, t_fs = timed(lambda: factor_cholesky(ab).solve(rhs), reps, budget_s=budget / 4)
        gab = model.trunk.assembler.general_band(matrix.blocks())
        _, t_lu = timed(lambda: factor_lu(gab, kd).solve(rhs), reps, budget_s=budget / 4)
        _, t_step = timed(lambda: model.step(state, rhs * 0.0), reps, budget_s=budget / 4)
        ref = analytic.elastica_tip(1.0, LENGTH)
        err = float(np.linalg.norm(tip_xz(result) - ref) / LENGTH)
        row = {"links": links, "frames": model.n_frames, "dof": model.n_dof, "kd": kd,
               "converged": bool(result.converged), "rounding_limited": bool(result.rounding_limited),
               "residual": float(result.residual), "iterations": int(result.iterations),
               "load_steps": int(result.load_steps), "factorization": result.factorization,
               "evaluations_tangent": evals["tangent"], "evaluations_gradient": evals["gradient"],
               "solve": t, "solver_solve_s": solve_s,
               "per_iteration_s": t["median_s"] / max(result.iterations, 1),
               "per_iteration_cpu_s": t["cpu_median_s"] / max(result.iterations, 1),
               "per_evaluation_s": t["median_s"] / max(evals["gradient"], 1),
               "tangent_eval_s": t_tan["cpu_median_s"], "gradient_eval_s": t_grad["cpu_median_s"],
               "band_assembly_s": t_band["cpu_median_s"], "cholesky_factor_s": t_fac["cpu_median_s"],
               "cholesky_solve_s": t_sol["cpu_median_s"], "cholesky_factor_solve_s": t_fs["cpu_median_s"],
               "lu_factor_solve_s": t_lu["cpu_median_s"], "retraction_s": t_step["cpu_median_s"],
               "tip_error_vs_elastica": err, "loadavg": la}
        rows.append(row)
        print(f"  {links:>6} links  {fmt_time(t['median_s']):>10} [CPU {fmt_time(t['cpu_median_s'])}]  it {result.iterations:>2}  "
              f"evals {evals['tangent']}+{evals['gradient']}  /it {fmt_time(row['per_iteration_s']):>9}  "
              f"tangent {fmt_time(t_tan['median_s']):>9}  chol f+s {fmt_time(t_fs['median_s']):>9}  "
              f"res {result.residual:.1e}{' (rounding)' if result.rounding_limited else ''}  load {la}",
              flush=True)
    # diagnostic: the model's closed-form link tangent (solver/links.py) against the complex-step
    # tangent of the same potential (tests/reference/complex_step.py): cost and agreement
    chunk_rows = []
    for links, model in models.items():
        if links not in (10, 100, 1000, 10000):
            continue
        st = results[links].state
        x, q = st.positions, st.quaternions
        stiffness = model.trunk.links.energies[0].stiffness
        args = (q[:-1], x[:-1], q[1:], x[1:], stiffness, model.link_rest)

        def closed():
            links_ = Links.of(*args[:4])
            w = (stiffness @ (links_.xi - model.link_rest)[:, :, None])[:, :, 0]
            return link_tangent(links_, w, stiffness, links_.gradient(w))

        reps = 3 if links >= 10000 else 11
        H_closed, t_closed = timed(closed, reps)
        stepped, t_step = timed(lambda: pair_tangent(link_gradient, *args), reps)
        H_step = stepped[2]
        diff = float(np.max(np.abs(H_closed - H_step)) / np.max(np.abs(H_step)))
        chunk_rows.append({"links": links, "closed_form_cpu_s": t_closed["cpu_median_s"],
                           "complex_step_cpu_s": t_step["cpu_median_s"], "max_relative_difference": diff})
        print(f"  link tangent {links} links: closed form {fmt_time(t_closed['cpu_median_s'])} CPU, "
              f"complex step {fmt_time(t_step['cpu_median_s'])} CPU, max rel. difference {diff:.1e}", flush=True)
    ok = [r for r in rows if "skipped" not in r and r["links"] >= 100]
    fits = {}
    if len(ok) >= 2:
        frames = [r["frames"] for r in ok]
        for key in ("per_iteration_s", "per_evaluation_s", "tangent_eval_s", "cholesky_factor_solve_s",
                    "lu_factor_solve_s", "band_assembly_s", "retraction_s"):
            fits[key] = fit_exponent(frames, [r[key] for r in ok])
        fits["solve_median_s"] = fit_exponent(frames, [r["solve"]["median_s"] for r in ok])
        fits["per_iteration_cpu_s"] = fit_exponent(frames, [r["per_iteration_cpu_s"] for r in ok])
        fits["per_iteration_min_s"] = fit_exponent(frames, [r["solve"]["min_s"] / max(r["iterations"], 1)
                                                            for r in ok])
        fits["range_links"] = [ok[0]["links"], ok[-1]["links"]]
    local = []
    for a, b in zip(ok[:-1], ok[1:]):
        local.append({"links": [a["links"], b["links"]],
                      "per_iteration": fit_exponent([a["frames"], b["frames"]],
                                                    [a["per_iteration_s"], b["per_iteration_s"]]),
                      "cholesky_factor_solve": fit_exponent([a["frames"], b["frames"]],
                                                            [a["cholesky_factor_solve_s"], b["cholesky_factor_solve_s"]])})
    return {"rows": rows, "exponents": fits, "local_exponents": local, "tangent_closed_vs_complex_step": chunk_rows}


# --------------------------------------------------------------------------- 2. gallery + warm start
def warm_trajectory(kind, base_model_fn, ticks, scene_name):
    """Cold and warm-started solves along ``ticks`` changes of 1 % each."""
    if kind == "load":   # dead load changed: one model per load level (built outside the timing)
        models = [base_model_fn(1.0 + 0.01 * k) for k in range(ticks + 1)]
        acts = [None] * (ticks + 1)
    else:                # actuation changed
        model = base_model_fn(1.0)
        models = [model] * (ticks + 1)
        a0 = active_actuation(model)
        acts = [a0 * (1.0 + 0.01 * k) for k in range(ticks + 1)]
    first = models[0].solve(acts[0])
    models[0].solve(acts[0], initial=first.state)          # warm-up of the warm path
    # two separate passes (each pays the per-tick set-up, e.g. the reference force of a new load)
    cold_t, cold_it, cold_conv, cold_pos, cold_c = [], [], [], [], []
    for k in range(1, ticks + 1):
        gc.disable()
        c0 = time.process_time()
        t0 = time.perf_counter()
        cold = models[k].solve(acts[k])
        cold_t.append(time.perf_counter() - t0)
        cold_c.append(time.process_time() - c0)
        gc.enable()
        cold_it.append(cold.iterations), cold_conv.append(cold.converged), cold_pos.append(cold.state.positions)
    warm_t, warm_it, warm_conv, warm_c = [], [], [], []
    prev, diff = first, 0.0
    for k in range(1, ticks + 1):
        gc.disable()
        c0 = time.process_time()
        t0 = time.perf_counter()
        warm = models[k].solve(acts[k], initial=prev.state)
        warm_t.append(time.perf_counter() - t0)
        warm_c.append(time.process_time() - c0)
        gc.enable()
        warm_it.append(warm.iterations), warm_conv.append(warm.converged)
        diff = max(diff, float(np.max(np.abs(warm.state.positions - cold_pos[k - 1]))))
        prev = warm
    return {"scene": scene_name, "change": kind, "ticks": ticks,
            "cold_median_s": float(np.median(cold_t)), "warm_median_s": float(np.median(warm_t)),
            "cold_cpu_median_s": float(np.median(cold_c)), "warm_cpu_median_s": float(np.median(warm_c)),
            "cold_iterations_median": float(np.median(cold_it)), "warm_iterations_median": float(np.median(warm_it)),
            "all_converged": bool(all(warm_conv) and all(cold_conv)),
            "max_position_difference_m": diff, "speedup": float(np.median(cold_t) / np.median(warm_t))}


def bench_gallery(quick):
    repeats = 20 if quick else 41
    rows, warm = [], []
    cases = []
    for name in RUNTIME_SCENES:
        cases.append((name, name, False))
        m = solver.build_model(gallery.load(name))
        if m.n_cables + m.n_chambers and not np.any(m.default_actuation):
            cases.append((name + " (3 N on every 4th tendon)", name, True))
    for label, name, active in cases:
        la = loadavg()
        scene = gallery.load(name)
        t0 = time.perf_counter()
        model = solver.build_model(scene)
        build_s = time.perf_counter() - t0
        own = []
        act = active_actuation(model) if active else None

        def run():
            r = model.solve(act)
            own.append(r.timings["solve_s"])
            return r
        result, t = timed(run, repeats)
        own = own[1:]   # drop the warm-up
        _, evals = count_evaluations(model, lambda: model.solve(act))
        rows.append({"scene": label, "frames": model.n_frames, "dof": model.n_dof, "kd": model.trunk.assembler.kd,
                     "cables": model.n_cables, "chambers": model.n_chambers,
                     "converged": bool(result.converged), "iterations": int(result.iterations),
                     "load_steps": int(result.load_steps), "factorization": result.factorization,
                     "residual": float(result.residual), "evaluations": evals, "build_s": build_s,
                     "wall": t, "solver_solve_s_median": float(np.median(own)), "loadavg": la})
        print(f"  {label:<44} {fmt_time(t['median_s']):>9} (own {fmt_time(float(np.median(own)))})  "
              f"it {result.iterations}  steps {result.load_steps}  {result.factorization}  load {la}", flush=True)
    ticks = 10 if quick else 20
    # the cantilever under a load growing 1 % per tick
    warm.append(warm_trajectory("load", lambda s: solver.build_model(cantilever(20, force_scale=s)), ticks,
                                "cantilever (20 links, PL²/EI = 1)"))
    for name in RUNTIME_SCENES:
        model = solver.build_model(gallery.load(name))
        if model.n_cables + model.n_chambers == 0:
            continue
        warm.append(warm_trajectory("actuation", lambda s, m=model: m, ticks, name))
    for w in warm:
        print(f"  warm {w['scene']:<36} cold {fmt_time(w['cold_median_s'])} ({w['cold_iterations_median']:.0f} it)  "
              f"warm {fmt_time(w['warm_median_s'])} ({w['warm_iterations_median']:.0f} it)", flush=True)

    # the 20-link cantilever specifically (acceptance: ≤ 1 ms median), solver-internal breakdown
    model = solver.build_model(gallery.load("cantilever"))
    result, t = timed(lambda: model.solve(), 61 if not quick else 21)
    own = [model.solve().timings["solve_s"] for _ in range(1001 if not quick else 101)]
    t["solver_solve_s_median"] = float(np.median(own))
    t["solver_solve_s_q10_q90"] = [float(np.percentile(own, 10)), float(np.percentile(own, 90))]
    state, act = result.state, model.default_actuation
    matrix, rhs, pieces = evaluation_pieces(model, state, act, 61)
    t_tan, t_grad = pieces["tangent"], pieces["gradient"]
    ab = matrix.symmetric_band()
    _, t_fs = timed(lambda: factor_cholesky(ab).solve(rhs), 201)
    _, t_step = timed(lambda: model.step(state, rhs * 0.0), 201)
    _, evals = count_evaluations(model, lambda: model.solve())
    c20 = {"wall": t, "iterations": int(result.iterations), "evaluations": evals,
           "tangent_eval_s": t_tan["cpu_median_s"], "gradient_eval_s": t_grad["cpu_median_s"],
           "cholesky_factor_solve_s": t_fs["cpu_median_s"], "retraction_s": t_step["cpu_median_s"],
           "target_s": 1e-3, "met": bool(t["solver_solve_s_median"] <= 1e-3), "loadavg": loadavg()}
    print(f"  cantilever 20 links: solver's own timing {fmt_time(t['solver_solve_s_median'])} median of "
          f"{len(own)}; wall {fmt_time(t['median_s'])} (min {fmt_time(t['min_s'])}), "
          f"{result.iterations} it, {evals['tangent']} tangent evals of {fmt_time(t_tan['median_s'])}, "
          f"factor+solve {fmt_time(t_fs['median_s'])}", flush=True)
    return {"rows": rows, "warm": warm, "cantilever_20": c20}


# --------------------------------------------------------------------------- 3. accuracy
def bench_accuracy(quick):
    loads = [1.0, 10.0] if quick else [0.5, 1.0, 5.0, 10.0]
    links_list = [5, 20, 100] if quick else [5, 10, 20, 40, 100]
    fine = 160 if quick else 320
    rows, orders = [], {}
    for k in loads:
        ref = analytic.elastica_tip(k, LENGTH)
        fine_tip = tip_xz(solver.build_model(cantilever(fine, k, tolerance=1e-12)).solve())
        floor = float(np.linalg.norm(fine_tip - ref) / LENGTH)
        for n in links_list:
            model = solver.build_model(cantilever(n, k, tolerance=1e-12))
            result, t = timed(lambda: model.solve(), 5 if quick else 11)
            tip = tip_xz(result)
            rows.append({"load_parameter": k, "links": n, "converged": bool(result.converged),
                         "iterations": int(result.iterations), "load_steps": int(result.load_steps),
                         "error_vs_elastica": float(np.linalg.norm(tip - ref) / LENGTH),
                         "error_vs_fine": float(np.linalg.norm(tip - fine_tip) / LENGTH),
                         "fine_links": fine, "fine_vs_elastica": floor, "time": t})
        sel = [r for r in rows if r["load_parameter"] == k and r["error_vs_fine"] > 1e-12]
        if len(sel) >= 2:
            orders[str(k)] = -fit_exponent([r["links"] for r in sel], [r["error_vs_fine"] for r in sel])
        print(f"  PL²/EI = {k:>4}: " + "  ".join(
            f"{r['links']}: {100 * r['error_vs_elastica']:.2e}% / {100 * r['error_vs_fine']:.1e}%"
            for r in rows if r["load_parameter"] == k) + f"   order {orders.get(str(k), float('nan')):.2f}"
            f"   floor({fine}) {100 * floor:.2e}%", flush=True)
    # the floor is physics: make the same rod (nearly) inextensible and shear-rigid and it drops
    floor_rows = []
    A = math.pi * RADIUS ** 2
    I = math.pi * RADIUS ** 4 / 4.0
    for k in ([1.0] if quick else [1.0, 10.0]):
        ref = analytic.elastica_tip(k, LENGTH)
        for n in (20, 320):
            for label, section in (("circle (extensible, shearable)", {"shape": "circle", "radius": RADIUS}),
                                   ("area × 1000, shear-rigid", {"area": 1e3 * A, "Ixx": I, "Iyy": I, "J": 2 * I})):
                seg = rod_segment(n)
                seg["section"] = section
                P = k * EI / LENGTH ** 2
                model = solver.build_model(solver.parse_scene({
                    "solver": {"tolerance": 1e-12, "max_iterations": 100}, "segment": [seg],
                    "load": [{"vertebra": -1, "force": [P, 0.0, 0.0]}]}))
                t0 = time.perf_counter()
                result = model.solve(raise_on_failure=False)
                dt = time.perf_counter() - t0
                floor_rows.append({"load_parameter": k, "links": n, "section": label,
                                   "converged": bool(result.converged), "iterations": int(result.iterations),
                                   "load_steps": int(result.load_steps),
                                   "error_vs_elastica": float(np.linalg.norm(tip_xz(result) - ref) / LENGTH),
                                   "time_s": dt})
                r = floor_rows[-1]
                print(f"  floor check PL²/EI = {k} {n} links {label}: {100 * r['error_vs_elastica']:.2e}% "
                      f"it {r['iterations']} steps {r['load_steps']} conv {r['converged']}", flush=True)
    return {"rows": rows, "orders": orders, "floor_check": floor_rows}


# --------------------------------------------------------------------------- 4. coil
def bench_coil(quick):
    rows = []
    for turns in ([1.0] if quick else [1.0, 1.25]):
        ref = analytic.arc_tip(2.0 * math.pi * turns, LENGTH)
        for n in ([20, 40] if quick else [10, 20, 40, 80]):
            model = solver.build_model(end_moment(n, turns))
            try:
                result, t = timed(lambda: model.solve(raise_on_failure=False), 3 if quick else 7,
                                  budget_s=8.0)
            except Exception as exc:  # noqa: BLE001  (a crash is a result here)
                rows.append({"turns": turns, "links": n, "error": repr(exc)})
                continue
            p = result.state.positions
            closure = float(np.linalg.norm(p[-1] - p[0]) / LENGTH)
            arc_err = float(np.linalg.norm(tip_xz(result) - ref) / LENGTH)
            # the tip frame must have turned by 2π·turns about +y
            qw, qy = result.state.quaternions[-1][[0, 2]]
            angle = 2.0 * math.atan2(qy, qw)
            ang_err = abs((angle - 2 * math.pi * turns + math.pi) % (2 * math.pi) - math.pi)
            rows.append({"turns": turns, "links": n, "converged": bool(result.converged),
                         "iterations": int(result.iterations), "load_steps": int(result.load_steps),
                         "factorization": result.factorization, "residual": float(result.residual),
                         "closure": closure, "arc_error": arc_err, "tip_angle_error_rad": float(ang_err),
                         "time": t, "loadavg": loadavg()})
            print(f"  {turns} turns {n:>3} links: conv {result.converged} it {result.iterations} "
                  f"steps {result.load_steps} ({result.factorization}) closure {closure:.1e} arc err {arc_err:.1e} "
                  f"{fmt_time(t['median_s'])}", flush=True)
    return {"rows": rows}


# --------------------------------------------------------------------------- 5. tolerance
def bench_tolerance(quick):
    tols = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12] if quick else [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12]
    k, n = 5.0, 20
    out = {}
    for tol in tols:
        model = solver.build_model(cantilever(n, k, tolerance=tol))
        result, t = timed(lambda: model.solve(), 11 if quick else 31)
        out[tol] = (result, t)
    tight = tip_xz(out[min(tols)][0])
    ref = analytic.elastica_tip(k, LENGTH)
    rows = []
    for tol in tols:
        result, t = out[tol]
        rows.append({"tolerance": tol, "converged": bool(result.converged), "iterations": int(result.iterations),
                     "residual": float(result.residual), "rounding_limited": bool(result.rounding_limited),
                     "error_vs_tightest": float(np.linalg.norm(tip_xz(result) - tight) / LENGTH),
                     "error_vs_elastica": float(np.linalg.norm(tip_xz(result) - ref) / LENGTH),
                     "time": t})
        print(f"  tol {tol:.0e}: it {result.iterations} res {result.residual:.1e} "
              f"err {rows[-1]['error_vs_tightest']:.1e} {fmt_time(t['median_s'])}", flush=True)
    return {"load_parameter": k, "links": n, "rows": rows, "loadavg": loadavg()}


# --------------------------------------------------------------------------- 6. one step
def linear_step(model, state, act_old, act_new, tangent_at):
    """One linearised step. ``tangent_at="previous"``: paper eqs. 10–12, tangent and residual at the
    previous actuation λ0 plus ``B (λ − λ0)`` (docs/solver-api.md); ``"new"``: a plain Newton step
    on the new problem (tangent at the new actuation). For dead-load changes (no actuation) both
    are the same step (a dead force has no tangent)."""
    if tangent_at == "previous" and act_old is not None:
        lin = model.linearise(state, act_old)
        rhs = lin.residual + lin.actuator_forces @ (np.asarray(act_new) - np.asarray(act_old))
    else:
        lin = model.linearise(state, act_new)
        rhs = lin.residual
    return model.step(state, lin.solve(rhs))


def one_step_case(label, model_a, model_b, act_a, act_b, L):
    """From A's converged state, the load/actuation changes to B: 1 and 2 linearised steps vs the
    converged solution of B; time of one step vs a converged warm-started re-solve."""
    a = model_a.solve(act_a, raise_on_failure=False)
    conv_b = model_b.solve(act_b, raise_on_failure=False)
    tip_b = conv_b.state.positions[-1]
    change = float(np.linalg.norm(a.state.positions[-1] - tip_b) / L)
    row = {"case": label, "tip_change_per_L": change}
    variants = ("previous", "new") if act_a is not None else ("previous",)
    for v in variants:
        s1 = linear_step(model_b, a.state, act_a, act_b, v)
        s2 = linear_step(model_b, s1, act_a, act_b, v)
        e1 = float(np.linalg.norm(s1.positions[-1] - tip_b) / L)
        e2 = float(np.linalg.norm(s2.positions[-1] - tip_b) / L)
        row[f"one_step_error_{v}"] = e1
        row[f"two_steps_error_{v}"] = e2
        row[f"one_step_relative_{v}"] = e1 / change if change else None
    _, t_step = timed(lambda: linear_step(model_b, a.state, act_a, act_b, "previous"), 41)
    _, t_warm = timed(lambda: model_b.solve(act_b, initial=a.state), 41)
    warm = model_b.solve(act_b, initial=a.state)
    row.update({"one_step_s": t_step["median_s"], "warm_converged_s": t_warm["median_s"],
                "one_step_cpu_s": t_step["cpu_median_s"], "warm_converged_cpu_s": t_warm["cpu_median_s"],
                "warm_iterations": int(warm.iterations)})
    return row


def tick_loop(label, models, acts, L):
    """A control loop taking exactly one linearised step per tick (tangent at the previous tick's
    actuation), never converging in between: tip error vs the converged solution at each tick."""
    state = models[0].solve(acts[0]).state
    errors = []
    for i in range(1, len(models)):
        state = linear_step(models[i], state, acts[i - 1], acts[i], "previous")
        exact = models[i].solve(acts[i], initial=state).state.positions[-1]
        errors.append(float(np.linalg.norm(state.positions[-1] - exact) / L))
    return {"case": label, "ticks": len(models) - 1, "max_error": max(errors), "last_error": errors[-1],
            "errors": errors}


def bench_one_step(quick):
    rows = []
    for k in (1.0, 5.0):
        rows.append(one_step_case(f"cantilever 20 links, PL²/EI = {k:g}, load +1 %",
                                  solver.build_model(cantilever(20, k)),
                                  solver.build_model(cantilever(20, k, force_scale=1.01)), None, None, LENGTH))
    for name in ("tendon_two_section", "paper_5v_16t"):
        m = solver.build_model(gallery.load(name))
        a0 = active_actuation(m)
        rows.append(one_step_case(f"{name}, tensions +1 % ({np.count_nonzero(a0)} active)", m, m, a0, a0 * 1.01,
                                  m.length_scale))
    for r in rows:
        extra = (f"  [tangent at new λ: 1 step {r['one_step_error_new']:.1e}, 2 steps {r['two_steps_error_new']:.1e}]"
                 if "one_step_error_new" in r else "")
        print(f"  {r['case']:<48} change {r['tip_change_per_L']:.1e}  1 step {r['one_step_error_previous']:.1e}  "
              f"2 steps {r['two_steps_error_previous']:.1e}  step {fmt_time(r['one_step_s'])}  "
              f"converged {fmt_time(r['warm_converged_s'])} ({r['warm_iterations']} it){extra}", flush=True)

    ticks = 10 if quick else 20
    loops = []
    k = 5.0
    models = [solver.build_model(cantilever(20, k, force_scale=1.0 + 0.01 * i)) for i in range(ticks + 1)]
    loops.append(tick_loop(f"cantilever 20 links, PL²/EI = {k:g}, +1 % load per tick", models,
                           [None] * (ticks + 1), LENGTH))
    m = solver.build_model(gallery.load("tendon_two_section"))
    a0 = active_actuation(m)
    loops.append(tick_loop("tendon_two_section, +1 % tensions per tick", [m] * (ticks + 1),
                           [a0 * (1.0 + 0.01 * i) for i in range(ticks + 1)], m.length_scale))
    for lp in loops:
        print(f"  one step per tick, {lp['case']}: max error {lp['max_error']:.1e} L", flush=True)
    return {"rows": rows, "tick_loops": loops, "loadavg": loadavg()}


def acceptance(res):
    acc = []
    ex = res["scaling"]["exponents"]
    if ex:
        acc.append({"criterion": f"growth exponent of time per Newton iteration, {ex['range_links'][0]}–"
                                 f"{ex['range_links'][1]} links", "target": "≤ 1.1",
                    "measured": f"{ex['per_iteration_s']:.3f}", "met": ex["per_iteration_s"] <= 1.1})
    c = res["gallery"]["cantilever_20"]
    acc.append({"criterion": "20-link cantilever, median solve (the solver's own timing)", "target": "≤ 1 ms",
                "measured": f"{fmt_time(c['wall']['solver_solve_s_median'])} (timed wall {fmt_time(c['wall']['median_s'])}, "
                            f"CPU {fmt_time(c['wall']['cpu_median_s'])})", "met": c["met"]})
    rows = res["accuracy"]["rows"]
    for n, target in ((20, 1e-3), (100, 1e-4)):
        sel = [r for r in rows if r["links"] == n]
        if sel:
            worst = max(r["error_vs_elastica"] for r in sel)
            loads = sorted({r["load_parameter"] for r in sel})
            acc.append({"criterion": f"{n} links, tip error vs elastica, PL²/EI ∈ {loads}",
                        "target": f"≤ {100 * target:g} % of L", "measured": sci_percent(worst), "met": worst <= target})
    coil = [r for r in res["coil"]["rows"] if r.get("turns") == 1.0 and "closure" in r]
    if coil:
        worst = max(r["closure"] for r in coil)
        acc.append({"criterion": f"full coil closure, {min(r['links'] for r in coil)}–{max(r['links'] for r in coil)} links",
                    "target": "≤ 1e-6 of L", "measured": f"{worst:.1e}",
                    "met": worst <= 1e-6 and all(r["converged"] for r in coil)})
    return acc



def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fast smoke run (small sizes, few repeats)")
    ap.add_argument("--out", type=Path, default=None, help="output directory (default benchmarks/results)")
    ap.add_argument("--only", nargs="*", default=None,
                    help="sections to run (scaling gallery accuracy coil tolerance one_step)")
    args = ap.parse_args(argv)
    if args.out:
        out_dir = args.out
    elif args.quick:
        out_dir = Path(tempfile.gettempdir()) / f"bench_solver_quick_{os.getuid()}"
    else:
        out_dir = RESULTS
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = "solver-quick" if args.quick else "solver"
    start = time.perf_counter()
    res = {"quick": args.quick, "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
           "loadavg_start": loadavg(),
           "environment": {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
                           "numpy": np.__version__, "scipy": scipy.__version__,
                           "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
                           "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
                           "git": git_info(), "solver_module": str(Path(solver.__file__).parent)}}
    sections = [("scaling", bench_scaling), ("gallery", bench_gallery), ("accuracy", bench_accuracy),
                ("coil", bench_coil), ("tolerance", bench_tolerance), ("one_step", bench_one_step)]
    for name, fn in sections:
        if args.only and name not in args.only:
            continue
        la = loadavg()
        print(f"== {name} (load {la})", flush=True)
        t0 = time.perf_counter()
        res[name] = fn(args.quick)
        res[name + "_section_s"] = time.perf_counter() - t0
        res[name + "_loadavg_before"] = la
    res["loadavg_end"] = loadavg()
    res["total_s"] = time.perf_counter() - start
    if not args.only:
        res["acceptance"] = acceptance(res)
        for a in res["acceptance"]:
            print(f"  [{'met' if a['met'] else 'NOT MET'}] {a['criterion']}: {a['measured']} (target {a['target']})")
    if args.only:
        from benchmarks.common import write_json
        write_json(res, out_dir / f"{stem}.json")
    else:
        render.write("solver", res, out_dir, stem=stem)
    print(f"wrote {out_dir / (stem + '.json')} in {res['total_s']:.0f} s")


if __name__ == "__main__":
    sys.exit(main())
