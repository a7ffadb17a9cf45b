"""The paper's robots tracking a circle (paper §V-a, Fig. 6) with the inverse model.

* tip only: the tip of ``paper_3v_4t`` / ``paper_3v_8t`` / ``paper_5v_16t`` runs around a
  horizontal circle about the robot's axis;
* ``--posture`` (16-tendon robot): two effectors, vertebra 2 ("mid") and the tip, follow
  two circles at once — posture control, not only the tip.

Tendons around a stiff backbone can bend it but barely shorten it (~1 µm per N), so
the targets must lie on the reachable surface: the circles are the effector positions of
one forward solution with the chosen bending radius, rotated about the axis
(``solver.gallery.targets.bent_circle``; the robot is axisymmetric).

    .venv/bin/python examples/inverse/track_circle.py --scene paper_5v_16t --posture \
        --points 60 --mode converged --csv circle.csv --plot circle.png

The CSV it writes is a ``vertebra invert --trajectory`` file for the same effectors.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np


from vertebra import solver  # noqa: E402
from vertebra.solver.gallery import load  # noqa: E402
from vertebra.solver.gallery.targets import bent_circle  # noqa: E402
from vertebra.solver.inverse.controller import InverseController, InverseSettings  # noqa: E402
from vertebra.solver.inverse.trajectory import Trajectory, write_trajectory  # noqa: E402


def scene_for(name: str, posture: bool):
    scene = load(name)
    keep = ("mid", "tip") if posture else ("tip",)
    effectors = tuple(e for e in scene.effectors if e.name in keep)
    if len(effectors) != len(keep):
        raise SystemExit(f"{name} has no effectors named {keep}")
    return dataclasses.replace(scene, effectors=effectors)


def run(scene_name="paper_5v_16t", posture=False, radius=0.01, points=36, mode="converged",
        csv=None, plot=None, quiet=False):
    scene = scene_for(scene_name, posture)
    model = solver.build_model(scene)
    targets = bent_circle(model, scene, radius, points)
    if csv:
        write_trajectory(csv, Trajectory(targets, np.arange(points, dtype=float)), model.effector_names)
    controller = InverseController(model, InverseSettings(mode=mode))
    efforts, errors, times, achieved, steps = [], [], [], [], []
    for target in targets:
        t0 = time.thread_time()
        step = controller.step(target)
        times.append(time.thread_time() - t0)
        step = controller.settled(step)  # a tick: where the robot settles under its actuation
        steps.append(step)
        achieved.append(step.positions)
        errors.append(step.errors)
        efforts.append(step.actuation)
    efforts, errors, achieved = np.array(efforts), np.array(errors), np.array(achieved)
    moves = np.linalg.norm(np.diff(efforts, axis=0), axis=1)
    summary = dict(scene=scene_name, effectors=list(model.effector_names), mode=mode, points=points,
                   radius=radius, max_error_m=float(errors.max()), median_step_cpu_s=float(np.median(times)),
                   max_effort_jump_over_median=float(moves.max() / max(np.median(moves), 1e-300)),
                   max_tension=float(efforts.max()))
    if not quiet:
        for key, value in summary.items():
            print(f"{key}: {value}")
    if plot:
        from vertebra.solver.plots import plot_inverse

        plot_inverse(model, steps, path=plot, tolerance=controller.settings.tolerance,
                     title=f"{scene_name}: {mode} inverse along a {radius * 1e3:g} mm circle")
    return summary


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="paper_5v_16t", choices=["paper_3v_4t", "paper_3v_8t", "paper_5v_16t"])
    p.add_argument("--posture", action="store_true", help="mid + tip (16-tendon robot)")
    p.add_argument("--radius", type=float, default=0.01, help="tip circle radius, m")
    p.add_argument("--points", type=int, default=36)
    p.add_argument("--mode", choices=["converged", "tick"], default="converged")
    p.add_argument("--csv")
    p.add_argument("--plot")
    a = p.parse_args(argv)
    run(a.scene, a.posture, a.radius, a.points, a.mode, a.csv, a.plot)


if __name__ == "__main__":
    main()
