"""Benchmark of the constraint-space QP backends (solver/inverse/qp.py).

Which library solves the inverse QP (paper eq. 13) fastest at equal accuracy, and what
the regularisation ε costs in bias and buys in smoothness. Synthetic problems built like
the real ones (SPD K, cables with B = −Jaᵀ, W_ea = Je K⁻¹ B, W_aa = Ja K⁻¹ B), seeded.

Rows:
* backend × (actuators, effector rows, reachable/unreachable, stroke limits): median solve
  time through ``solve_constraint_problem`` (validation + scaling + solve + diagnostics)
  and the effort/objective error against DAQP at its tightest (active set: exact);
* ε: reachable-target bias (predicted effector error / free gap) and smoothness of
  16-tendon efforts along a circle (max step / median step).

Run: ``.venv/bin/python -m benchmarks.bench_qp [--quick]``; writes
``benchmarks/results/qp.json`` and ``benchmarks/results/qp.md``.
"""

from __future__ import annotations

import argparse
import os
import platform

import numpy as np

from benchmarks import render
from benchmarks.common import timed
from vertebra.solver.gallery.targets import circle
from vertebra.solver.inverse import (ConstraintProblem, ConstraintSpace, available_backends,
                                     solve_constraint_problem)
from vertebra.solver.inverse.problems import synthetic_problem

def problem_for(case, seed, eps=None):
    W_ea, de, W_aa, _ = synthetic_problem(seed, case["n_act"], case["n_rows"], reach=case["reach"])
    kw = {}
    if case["stroke"]:
        kw["displacement_lower"] = -0.6 * np.abs(W_aa).sum(axis=1)
    if eps is not None:
        kw["regularisation"] = eps
    space = ConstraintSpace(case["n_act"], case["n_rows"], lambda_lower=0.0, lambda_upper=20.0, **kw)
    return ConstraintProblem(space, W_ea, de, W_aa, np.zeros(case["n_act"]))


def time_backend(problem, backend, repeats):
    """The solution and the median wall time of ``repeats`` solves (after one: lazy imports)."""
    sol, t = timed(lambda: solve_constraint_problem(problem, backend), repeats)
    return sol, t["median_s"]


def backend_table(quick):
    cases = []
    for n_act, n_rows in [(4, 3), (8, 3), (16, 3), (16, 6), (32, 6)]:
        for reach, stroke in [(0.5, False), (3.0, False), (3.0, True)]:
            cases.append(dict(n_act=n_act, n_rows=n_rows, reach=reach, stroke=stroke))
    if quick:
        cases = cases[::3]
    backends = available_backends()
    rows = []
    repeats = 20 if quick else 100
    for case in cases:
        for seed in range(2 if quick else 3):
            problem = problem_for(case, seed)
            ref, _ = time_backend(problem, "daqp", 1)
            free_objective = 0.5 * float(problem.delta_e_free @ problem.delta_e_free)
            scale = max(np.abs(ref.actuation).max(), 1e-300)
            for backend in backends:
                reps = max(3, repeats // 20) if backend in ("gauss-seidel", "qpsolvers:proxqp") else repeats
                sol, t = time_backend(problem, backend, reps)
                rows.append(dict(
                    backend=backend, seed=seed, **case, time_s=t, status=sol.status, converged=sol.converged,
                    effort_error=float(np.abs(sol.actuation - ref.actuation).max() / scale),
                    # excess over DAQP's optimum relative to the objective at λ = 0 (½‖δe_free‖²)
                    objective_rel=float((sol.diagnostics().objective - ref.diagnostics().objective)
                                        / free_objective),
                    effector_error=sol.effector_error,
                    bound_violation=float(max(np.max(problem.lambda_lower - sol.actuation),
                                              np.max(sol.actuation - problem.lambda_upper),
                                              np.max(problem.space.displacement_lower - sol.delta_a)
                                              - np.max(sol.displacement_relaxation, initial=0.0), 0.0)),
                ))
    return rows


def epsilon_table(quick):
    rows = []
    n_steps = 61 if quick else 181
    for eps in [1e-4, 1e-6, 1e-8, 1e-10]:
        biases = []
        for seed in range(3):
            problem = problem_for(dict(n_act=16, n_rows=3, reach=0.5, stroke=False), seed, eps)
            sol = solve_constraint_problem(problem, "daqp")
            biases.append(sol.effector_error / np.linalg.norm(problem.delta_e_free) if sol.converged else np.nan)
        W_ea, de0, W_aa, _ = synthetic_problem(2, 16, 3)
        space = ConstraintSpace(16, 3, lambda_lower=0.0, lambda_upper=20.0, regularisation=eps)
        gaps = circle(de0, 0.3 * np.linalg.norm(de0), n_steps, normal=np.random.default_rng(0).normal(size=3))
        lam, path, ok = None, [], True
        for de in gaps:
            sol = solve_constraint_problem(ConstraintProblem(space, W_ea, de, W_aa, np.zeros(16), lam), "daqp")
            ok &= sol.converged
            lam = sol.actuation
            path.append(lam)
        steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
        rows.append(dict(epsilon=eps, bias_max=float(np.nanmax(biases)), all_converged=bool(ok),
                         smoothness=float(steps.max() / np.median(steps)),
                         mean_tension=float(np.mean(np.sum(path, axis=1)))))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    rows = backend_table(args.quick)
    eps_rows = epsilon_table(args.quick)

    document = {"rows": rows, "epsilon": eps_rows, "quick": args.quick, "host": platform.node(),
                "python": platform.python_version(), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS")}
    print(render.markdown("qp", document))
    render.write("qp", document)


if __name__ == "__main__":
    main()
