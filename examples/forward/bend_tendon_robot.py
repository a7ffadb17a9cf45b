"""Forward statics: bend the paper's 16-tendon robot and read its pose and tip stiffness.

Two tendons pull: of the tendons ending at the tip, the one nearest the +x side with
``--tension``; of those ending at vertebra 3, the one nearest +x with half of it. The script solves the equilibrium, prints where the effectors
went, the tip's translational compliance there (how far it moves per newton pushed on it)
and writes a picture of the bent robot.

    python bend_tendon_robot.py [--tension 4] [--plot bend.png]

The same model from the command line: ``vertebra simulate gallery:paper_5v_16t --json``
(after setting tensions in a copy of the scene file).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.spatial.transform import Rotation

from vertebra import solver
from vertebra.solver.compliance import effector_compliance
from vertebra.solver.report import plot_static


def run(tension: float = 4.0, plot=None, quiet: bool = False) -> dict:
    scene = solver.load_scene("gallery:paper_5v_16t")
    model = solver.build_model(scene)
    actuation = np.zeros(len(model.actuator_names))
    for last, share in ((scene.n_vertebrae - 1, 1.0), (3, 0.5)):
        ending = [k for k, cable in enumerate(scene.cables) if cable.last == last]
        nearest_x = max(ending, key=lambda k: np.cos(scene.cables[k].angle))
        actuation[nearest_x] = share * tension
    result = model.solve(actuation)
    positions = model.effector_positions(result.state)
    compliance = effector_compliance(model, result.state, actuation)
    tip = model.effector_names.index("tip")
    # principal compliances: how far the tip gives per newton along its softest and stiffest directions
    values, directions = np.linalg.eigh(0.5 * (compliance.translational[tip] + compliance.translational[tip].T))
    summary = {"converged": result.converged, "iterations": result.iterations,
               "effectors": {name: positions[k].tolist() for k, name in enumerate(model.effector_names)},
               "tip_compliance_m_per_N": compliance.translational[tip].tolist(),
               "tip_axis": Rotation.from_quat(result.state.quaternions[model.vertebra_frames[-1]],
                                              scalar_first=True).apply([0.0, 0.0, 1.0]).tolist(),
               "tip_principal_compliances_m_per_N": values.tolist(),
               "tip_stiffest_direction": directions[:, 0].tolist()}
    if not quiet:
        print(f"{scene.name}: converged {result.converged} in {result.iterations} Newton iterations")
        for name, position in summary["effectors"].items():
            print(f"  {name:4s} at {np.round(position, 5).tolist()} m")
        print("  tip compliance [mm/N]:")
        for row in 1e3 * compliance.translational[tip]:
            print("   " + " ".join(f"{v:+9.4f}" for v in row))
        print(f"  softest direction {np.round(directions[:, -1], 3).tolist()}: {1e3 * values[-1]:.3f} mm/N; "
              f"stiffest {np.round(directions[:, 0], 3).tolist()} (along the backbone): {1e3 * values[0]:.4f} mm/N")
    if plot:
        plot_static(model, result, str(plot), title=f"{scene.name}: {tension:g} N on a tip tendon, half on a vertebra-3 tendon")
        if not quiet:
            print(f"wrote {plot}")
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tension", type=float, default=4.0, help="tension of the tip tendon nearest +x, N")
    parser.add_argument("--plot", default=None, help="picture of the bent robot (.png)")
    args = parser.parse_args(argv)
    return 0 if run(args.tension, args.plot)["converged"] else 1


if __name__ == "__main__":
    sys.exit(main())
