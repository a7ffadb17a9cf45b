"""Map the reachable workspace of a tendon robot and measure how stiff it is across it.

Samples tendon tensions quasi-randomly within their bounds, solves every sample (each
warm-started from a nearby solved one), and reports the tip's point cloud: extents,
convex-hull volume, and the spread of the tip's sideways compliance over the cloud.

    python map_workspace.py [--scene paper_5v_16t] [--samples 2000] [--plot workspace.png]

The command-line equivalent: ``vertebra workspace gallery:paper_5v_16t --samples 2000
--plot workspace.png --json``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from vertebra import solver
from vertebra.solver.compliance import effector_compliance
from vertebra.solver.workspace import sample_workspace


def run(scene_name: str = "paper_5v_16t", samples: int = 2000, plot=None, stiffness_samples: int = 20,
        quiet: bool = False) -> dict:
    model = solver.build_model(solver.load_scene(f"gallery:{scene_name}"))
    workspace = sample_workspace(model, samples, seed=1)
    tip = workspace.cloud("tip")
    hull = tip.hull()
    # compliance at a few of the sampled equilibria (re-solved from rest: the map keeps positions only)
    k = model.effector_names.index("tip")
    lateral = []
    for i in np.flatnonzero(workspace.converged)[:stiffness_samples]:
        result = model.solve(workspace.actuations[i])
        lateral.append(effector_compliance(model, result.state, result.actuation).translational[k][0, 0])
    summary = {"scene": scene_name, "samples": samples, "converged": int(workspace.converged.sum()),
               "hull_volume_m3": hull.volume, "lower_m": tip.lower.tolist(), "upper_m": tip.upper.tolist(),
               "newton_iterations_per_sample": float(workspace.iterations.mean()),
               "tip_x_compliance_m_per_N": [float(min(lateral)), float(max(lateral))]}
    if not quiet:
        print(f"{scene_name}: {summary['converged']} of {samples} samples converged, "
              f"{summary['newton_iterations_per_sample']:.2f} Newton iterations each, "
              f"{workspace.timings['cpu_s']:.2f} s CPU")
        print(f"  tip reaches x {tip.lower[0]:+.4f}..{tip.upper[0]:+.4f}, y {tip.lower[1]:+.4f}..{tip.upper[1]:+.4f}, "
              f"z {tip.lower[2]:+.4f}..{tip.upper[2]:+.4f} m; hull volume {1e6 * hull.volume:.1f} cm³")
        print(f"  tip x-compliance over {len(lateral)} sampled poses: "
              f"{1e3 * min(lateral):.3f}..{1e3 * max(lateral):.3f} mm/N")
    if plot:
        from vertebra.solver.workspace_plot import plot_workspace

        plot_workspace(workspace, plot, rest=model.effector_positions(model.rest_state))
        if not quiet:
            print(f"wrote {plot}")
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="paper_5v_16t", help="gallery scene with a 'tip' effector")
    parser.add_argument("--samples", type=int, default=2000, help="sampled actuations")
    parser.add_argument("--plot", default=None, help="picture of the clouds (.png)")
    args = parser.parse_args(argv)
    run(args.scene, args.samples, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
