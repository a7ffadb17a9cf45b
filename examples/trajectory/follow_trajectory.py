"""Follow a trajectory file with the inverse model, one control tick per row.

Reads a trajectory CSV (``t,<effector>.x,<effector>.y,<effector>.z`` per row; by default the
circle that ``../inverse/track_circle.py`` wrote for the tip of ``paper_3v_4t``), runs the
inverse controller on every row and reports the tracking error. ``--mode tick`` takes one
linearise–QP step per row (a real-time controller); ``converged`` solves each row exactly.

    python follow_trajectory.py [--scene paper_3v_4t] [--trajectory FILE.csv]
                                [--mode tick|converged] [--steps N] [--plot track.png]

The command-line equivalent: ``vertebra invert gallery:paper_3v_4t --trajectory FILE.csv``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from vertebra import solver
from vertebra.solver.inverse.controller import InverseController, InverseSettings
from vertebra.solver.inverse.trajectory import read_trajectory

HERE = Path(__file__).resolve().parent
DEFAULT_TRAJECTORY = HERE.parent / "inverse" / "paper_3v_4t_tip_circle.csv"


def run(scene_name: str = "paper_3v_4t", trajectory=DEFAULT_TRAJECTORY, mode: str = "tick",
        steps: int | None = None, plot=None, quiet: bool = False) -> dict:
    model = solver.build_model(solver.load_scene(f"gallery:{scene_name}"))
    path = trajectory
    trajectory = read_trajectory(path, model.effector_names, model.effector_targets)
    targets = trajectory.targets[:steps]
    controller = InverseController(model, InverseSettings(mode=mode))
    errors, actuations = [], []
    for target in targets:
        step = controller.step(target)
        errors.append(step.errors)
        actuations.append(step.actuation)
    errors, actuations = np.array(errors), np.array(actuations)
    summary = {"scene": scene_name, "trajectory": str(path), "mode": mode, "steps": len(targets),
               "max_error_m": float(errors.max()), "final_error_m": float(errors[-1].max()),
               "max_tension_N": float(actuations.max())}
    if not quiet:
        print(f"{scene_name} following {Path(path).name} ({len(targets)} rows, {mode} mode)")
        print(f"  largest tracking error {1e3 * summary['max_error_m']:.4f} mm, "
              f"last row {1e3 * summary['final_error_m']:.4f} mm, largest tension {summary['max_tension_N']:.3f} N")
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
        for k, name in enumerate(model.actuator_names):
            top.plot(actuations[:, k], label=name)
        top.set_ylabel("tension [N]"), top.legend(fontsize=7, ncol=4)
        bottom.semilogy(np.maximum(errors, 1e-16))
        bottom.set_xlabel("row of the trajectory"), bottom.set_ylabel("tracking error [m]")
        fig.suptitle(f"{scene_name}: {mode} inverse along {Path(path).name}")
        fig.tight_layout()
        fig.savefig(plot, dpi=110)
        plt.close(fig)
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="paper_3v_4t", help="gallery scene whose effectors the file names")
    parser.add_argument("--trajectory", default=str(DEFAULT_TRAJECTORY), help="trajectory CSV")
    parser.add_argument("--mode", choices=("tick", "converged"), default="tick")
    parser.add_argument("--steps", type=int, default=None, help="only the first N rows")
    parser.add_argument("--plot", default=None, help="tensions and tracking error per row (.png)")
    args = parser.parse_args(argv)
    run(args.scene, args.trajectory, args.mode, args.steps, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
