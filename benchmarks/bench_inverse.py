"""Benchmark of the inverse step (paper §IV): linearise → project (W) → QP → step.

Rows:
1. each gallery robot: median time of one real-time inverse step split into
   ``linearise`` (the model's tangent + banded factor), ``W`` (``ConstraintSpace.project``: one
   multi-RHS banded solve for K⁻¹[r, B] and the products giving W_ea, W_aa, δe_free, δa_free),
   ``QP`` (DAQP through ``solve_constraint_problem``) and ``step`` (retraction), plus the whole tick;
   the paper reports ~5 ms (2 ms for W) on 3 vertebrae and ~13 ms (9 ms for W) on the
   5-vertebra 16-tendon robot (SOFA, 2.66 GHz i7);
2. growth with frames (links per segment) and with actuators (tendons) on the 16-tendon robot;
3. the speed/accuracy knob "one linearise–QP step per tick vs converged": per-step cost and
   effector error of the equilibrium under the commanded actuation along a reachable loop.

Run: ``.venv/bin/python -m benchmarks.bench_inverse [--quick]``; writes
``benchmarks/results/inverse.json`` and ``benchmarks/results/inverse.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time

import numpy as np

from benchmarks import render
from benchmarks.common import timed
from vertebra import solver
from vertebra.solver.gallery import load
from vertebra.solver.gallery.targets import reachable_loop
from vertebra.solver.inverse import ConstraintSpace, InverseController, InverseSettings
from vertebra.solver.inverse.qp import solve_constraint_problem

PAPER = {"paper_3v_4t": "~5 ms (W ~2 ms)", "paper_3v_8t": "~5 ms (W ~2 ms)",
         "paper_5v_16t": "~13 ms (W ~9 ms)"}


def median_time(fn, repeats):
    """(median CPU time of this thread, median wall time) of ``fn`` over ``repeats`` calls: on 2
    cores shared by several jobs, wall-clock medians measure the scheduler, not the code (wall
    medians were ~3× the CPU time at load 4.6); the wall medians are kept for the record."""
    _, t = timed(fn, repeats)
    return t["thread_median_s"], t["median_s"]


def breakdown(model, repeats, actuation=None):
    n_act = len(model.actuator_names)
    lam = np.full(n_act, 0.3) if actuation is None else actuation
    state = model.solve(lam).state
    targets = model.effector_positions(state) + 1e-3
    space = ConstraintSpace.of_model(model)
    lin = model.linearise(state, lam)
    projection = space.project(lin, targets, lam)
    sol = solve_constraint_problem(projection.problem)
    dq = projection.state_change(sol.actuation)
    t_lin, _ = median_time(lambda: model.linearise(state, lam), repeats)
    t_w, _ = median_time(lambda: space.project(lin, targets, lam), repeats)
    t_qp, _ = median_time(lambda: solve_constraint_problem(projection.problem), repeats)
    t_step, _ = median_time(lambda: model.step(state, dq), repeats)
    controller = InverseController(model, InverseSettings(mode="tick"), actuation=lam, state=state)
    parts = []

    def tick():
        controller.state, controller.actuation = state, lam
        parts.append(controller.step(targets).timings)

    t_tick, wall_tick = median_time(tick, repeats)
    inside = {key: float(np.median([p.get(key, 0.0) for p in parts]))
              for key in ("linearise_s", "W_s", "qp_s", "step_s", "total_s")}
    return dict(wall_tick_s=wall_tick, frames=int(model.n_frames), actuators=n_act, effectors=len(model.effector_names),
                linearise_s=t_lin, W_s=t_w, qp_s=t_qp, step_s=t_step, tick_s=t_tick,
                in_tick=inside, qp_iterations=int(sol.iterations))


def scaled_scene(name, elements=None, n_cables=None, vertebrae=None):
    scene = load(name)
    if vertebrae is not None:       # k× the vertebrae, every tendon running k× as far (same band)
        scene = dataclasses.replace(
            scene, segments=tuple(dataclasses.replace(s, count=s.count * vertebrae) for s in scene.segments),
            cables=tuple(dataclasses.replace(c, last=c.last * vertebrae) for c in scene.cables))
    if elements is not None:
        scene = dataclasses.replace(scene, segments=tuple(dataclasses.replace(s, elements=elements)
                                                          for s in scene.segments))
    if n_cables is not None:
        base = scene.cables
        cables = []
        for k in range(n_cables):
            c = base[k % len(base)]
            cables.append(dataclasses.replace(c, name=f"c{k}", angle=c.angle + 0.1 * (k // len(base))))
        scene = dataclasses.replace(scene, cables=tuple(cables))
    return scene


def modes_table(n_points):
    rows = []
    for label, keep in [("tip only", ("tip",)), ("mid + tip (posture)", ("mid", "tip"))]:
        scene = load("paper_5v_16t")
        scene = dataclasses.replace(scene, effectors=tuple(e for e in scene.effectors if e.name in keep))
        model = solver.build_model(scene)
        loop = reachable_loop(model, scene, n_points)
        for mode in ("tick", "converged"):
            controller = InverseController(model, InverseSettings(mode=mode))
            controller.step(loop[0])  # start on the loop (not timed)
            if mode == "tick":
                for _ in range(5):
                    controller.step(loop[0])
            times, errors, state = [], [], None
            for target in loop[1:]:
                t0 = time.thread_time()
                step = controller.step(target)
                times.append(time.thread_time() - t0)
                errors.append(float(np.max(controller.settled(step).errors)))
            rows.append(dict(effectors=label, mode=mode, median_step_s=float(np.median(times)),
                             max_step_s=float(np.max(times)), median_error_m=float(np.median(errors)),
                             max_error_m=float(np.max(errors)),
                             loop_step_m=float(np.median(np.linalg.norm(np.diff(loop, axis=0), axis=2)))))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    repeats = 30 if args.quick else 200

    # the gallery rows in interleaved rounds (median over rounds of each round's medians): load
    # bursts on the shared machine then hit every scene alike instead of one row
    names = ["paper_3v_4t", "paper_3v_8t", "paper_5v_16t", "tendon_two_section"]
    models = {name: solver.build_model(load(name)) for name in names}
    rounds = {name: [] for name in names}
    for _ in range(3):
        for name in names:
            rounds[name].append(breakdown(models[name], repeats))
    scenes = []
    for name in names:
        rows = rounds[name]
        row = {key: (float(np.median([r[key] for r in rows])) if isinstance(rows[0][key], float) else rows[0][key])
               for key in rows[0] if key != "in_tick"}
        row["in_tick"] = {k: float(np.median([r["in_tick"][k] for r in rows])) for k in rows[0]["in_tick"]}
        scenes.append(dict(scene=name, paper=PAPER.get(name, ""), rounds=len(rows), **row))
    frames = []
    for elements in ([2, 8, 32] if args.quick else [2, 4, 8, 16, 32, 64]):
        model = solver.build_model(scaled_scene("paper_5v_16t", elements=elements))
        frames.append(dict(elements_per_segment=elements, **breakdown(model, max(5, repeats // max(1, elements // 4)))))
    vertebrae = []
    for k in ([1, 4, 16] if args.quick else [1, 2, 4, 8, 16, 32]):
        model = solver.build_model(scaled_scene("paper_5v_16t", vertebrae=k))
        vertebrae.append(dict(factor=k, **breakdown(model, max(5, repeats // k))))
    fit = lambda rows, key: float(np.polyfit(np.log([r["frames"] for r in rows]),  # noqa: E731
                                             np.log([r[key] for r in rows]), 1)[0])
    exponents = {key: fit(vertebrae, key) for key in ("W_s", "linearise_s", "tick_s")}
    exponents["W_in_tick"] = float(np.polyfit(np.log([r["frames"] for r in vertebrae]),
                                              np.log([r["in_tick"]["W_s"] for r in vertebrae]), 1)[0])
    actuators = []
    for n_cables in ([4, 16, 64] if args.quick else [4, 8, 16, 32, 64]):
        model = solver.build_model(scaled_scene("paper_5v_16t", n_cables=n_cables))
        actuators.append(breakdown(model, repeats))
    modes = modes_table(13 if args.quick else 37)

    host = (f"host: {platform.node()} · {platform.processor() or platform.machine()} · python "
            f"{platform.python_version()} · OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')} · "
            f"load average {os.getloadavg()[0]:.1f} (2 cores shared)")
    document = {"scenes": scenes, "frames": frames, "vertebrae": vertebrae, "vertebrae_exponents": exponents,
                "actuators": actuators, "modes": modes, "quick": args.quick, "host": host}
    print(render.markdown("inverse", document))
    render.write("inverse", document)


if __name__ == "__main__":
    main()
