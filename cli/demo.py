"""``vertebra demo [--out DIR]``: the whole pipeline on embedded defaults, end to end.

1. forward statics of the gallery's two-section tendon robot (picture, ParaView .vtp, frames CSV);
2. prepare: a CBHA-like pneumatic trunk (two tapered three-chamber sections) written as a
   scene of design segments (``gallery:cbha_design``); ``vertebra prepare`` meshes its 16
   slices with gmsh and condenses them with scikit-fem into an HDF5 catalogue, which is
   verified; ``simulate --prepare`` then reuses every entry and solves the trunk forward under
   chamber pressures (picture);
3. inverse: the paper's 16-tendon robot tracking a circle with its tip (picture, JSON, ParaView
   .pvd time series), and the pneumatic trunk reaching a target with its chamber pressures
   (pictures, JSON).

Every stage runs the same code as the corresponding ``vertebra`` subcommand.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from vertebra.cli.main import main


def add_arguments(parser):
    parser.add_argument("--out", default="demo-output", help="directory for pictures, catalogue and JSON")
    parser.add_argument("--points", type=int, default=24, help="trajectory points of the circle")


def _banner(text: str):
    print(f"\n== {text}", flush=True)


def _command(argv, stdout_path: Path | None = None) -> int:
    """Run one ``vertebra`` subcommand; its stdout goes to ``stdout_path`` when given."""
    print("$ vertebra " + " ".join(argv), flush=True)
    if stdout_path is None:
        return main(argv)
    saved = sys.stdout
    with open(stdout_path, "w") as handle:
        sys.stdout = handle
        try:
            return main(argv)
        finally:
            sys.stdout = saved


def run(args) -> int:
    import numpy as np

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.solver.gallery.targets import circle, pose_circle
    from vertebra.solver.inverse.trajectory import Trajectory, write_trajectory
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    summary = {}

    _banner("1/3 forward statics: two-section tendon robot (gallery:tendon_two_section)")
    code = _command(["simulate", "gallery:tendon_two_section", "--plot", str(out / "tendon_forward.png"),
                     "--vtk", str(out / "tendon_forward.vtp"), "--frames", str(out / "tendon_forward_frames.csv")])
    summary["tendon_forward"] = code

    _banner("2/3 prepare → catalogue → forward: CBHA-like pneumatic trunk of design segments (gallery:cbha_design)")
    # the gallery scene names its 16 slices by design; prepare designs the missing entries into
    # the scene's catalogue (gmsh + scikit-fem, condensed), simulate --prepare then reuses them all
    import tomllib

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.solver import gallery
    from vertebra.solver.scene import scene_toml
    catalogue_path = out / "cbha.h5"
    scene = tomllib.loads(gallery.path("cbha_design").read_text())
    scene["catalogue"] = {"path": catalogue_path.name}
    pressures = {0: 1.2e5, 4: 0.6e5}   # section 1 chamber 0 and section 2 chamber 1, Pa
    scene["chamber"] = [dict(chamber, pressure=pressures.get(k, 0.0)) for k, chamber in enumerate(scene["chamber"])]
    scene_path = out / "cbha.toml"
    scene_path.write_text(scene_toml(scene, "CBHA-like trunk of design segments (gallery:cbha_design) with pressures"))
    t0 = time.perf_counter()
    summary["cbha_prepare"] = _command(["prepare", str(scene_path), "--json"], stdout_path=out / "cbha_prepare.json")
    prepared = json.loads((out / "cbha_prepare.json").read_text())
    print(f"catalogue {catalogue_path}: {len(prepared['designed'])} entries designed, {len(prepared['reused'])} "
          f"reused in {time.perf_counter() - t0:.1f} s")
    summary["catalogue_verify"] = _command(["catalogue", "verify", str(catalogue_path)])
    summary["cbha_forward"] = _command(["simulate", str(scene_path), "--prepare", "--json", "--plot",
                                        str(out / "cbha_forward.png")], stdout_path=out / "cbha_forward.json")
    forward = json.loads((out / "cbha_forward.json").read_text())
    print(f"  tip at {np.round(forward['effectors']['tip']['position'], 4).tolist()} m after "
          f"{forward['iterations']} Newton iterations ({1e3 * forward['timing']['solve_s']:.2f} ms)")

    _banner("3/3 inverse: 16-tendon robot tracks a circle; pneumatic trunk reaches a target")
    # a tip circle the axisymmetric robot can reach: the tip under one pulled tendon (4 N on the
    # last one, terminated at the tip) rotated about the axis
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver
    tendon_robot = solver.build_model(solver.load_scene("gallery:paper_5v_16t"))
    pulled = np.zeros(len(tendon_robot.actuator_names))
    pulled[-1] = 4.0
    tip = tendon_robot.effector_names.index("tip")
    targets = pose_circle(tendon_robot, pulled, args.points)[:, [tip]]
    trajectory_path = out / "circle.csv"
    write_trajectory(trajectory_path, Trajectory(targets, np.arange(args.points, dtype=float)), ["tip"])
    tip_only = out / "paper_5v_16t_tip.toml"
    data = tomllib.loads(gallery.path("paper_5v_16t").read_text())
    data["effector"] = [e for e in data["effector"] if e["name"] == "tip"]
    tip_only.write_text(scene_toml(data))
    summary["tendon_inverse"] = _command(["invert", str(tip_only), "--trajectory", str(trajectory_path),
                                          "--json", "--plot", str(out / "tendon_inverse.png"),
                                          "--vtk", str(out / "tendon_inverse.pvd")],
                                         stdout_path=out / "tendon_inverse.json")
    inverse = json.loads((out / "tendon_inverse.json").read_text())
    errors = [step["effectors"]["tip"]["error"] for step in inverse["steps"]]
    print(f"  {len(errors)} targets, converged static inverse at each: tip error max {max(errors):.2e} m, "
          f"median time per target {1e3 * inverse['timing']['median_step_s']:.2f} ms")
    # a target the trunk can reach: where the forward solve above put the tip; the inverse
    # starts from zero pressure and must find pressures that bring the tip there
    target = forward["effectors"]["tip"]["position"]
    scene["effector"] = [dict(effector, target=target) for effector in scene["effector"]]
    scene["chamber"] = [dict(chamber, pressure=0.0) for chamber in scene["chamber"]]
    target_scene = out / "cbha_target.toml"
    target_scene.write_text(scene_toml(scene))
    print(f"  target {np.round(target, 4).tolist()} m (the forward result above)")
    summary["cbha_inverse"] = _command(["invert", str(target_scene), "--prepare", "--json", "--plot",
                                        str(out / "cbha_inverse.png")], stdout_path=out / "cbha_inverse.json")
    reach = json.loads((out / "cbha_inverse.json").read_text())["steps"][-1]
    pressures = ", ".join("%s %.3f bar" % (k, v["pressure"] / 1e5) for k, v in reach["chambers"].items())
    print(f"  chamber pressures {pressures}; "
          f"tip error {reach['effectors']['tip']['error']:.2e} m")
    # and a tip trajectory: a horizontal circle of 3 cm radius 5 mm above the rest tip (the
    # chambers only extend the trunk, pressures ≥ 0: below that height the circle is out of reach)
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.designer import prepare
    trunk = solver.build_model(prepare(solver.load_scene(target_scene), progress=False)[0])     # every entry is there: reused
    rest_tip = trunk.effector_positions(trunk.rest_state)[0]
    tip_circle = circle([0.0, 0.0, rest_tip[2] + 0.005], 0.03, 13)
    write_trajectory(out / "cbha_circle.csv", Trajectory(tip_circle[:, None, :], np.arange(13, dtype=float)), ["tip"])
    summary["cbha_trajectory"] = _command(["invert", str(target_scene), "--prepare", "--trajectory",
                                           str(out / "cbha_circle.csv"), "--json", "--plot", str(out / "cbha_circle.png")],
                                          stdout_path=out / "cbha_circle.json")
    track = json.loads((out / "cbha_circle.json").read_text())
    peak = max(v["pressure"] for step in track["steps"] for v in step["chambers"].values())
    print(f"  circle of 13 targets: tip error max {max(s['effectors']['tip']['error'] for s in track['steps']):.2e} m, "
          f"pressures within 0–{peak / 1e5:.2f} bar (bounds 0–1.5 bar)")

    summary["total_s"] = time.perf_counter() - started
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"\nDemo finished in {summary['total_s']:.0f} s; pictures and data in {out}/")
    failed = {k: v for k, v in summary.items() if k != "total_s" and v != 0}
    if failed:
        print(f"stages with a non-zero exit code: {failed}", file=sys.stderr)
        return 1
    return 0
