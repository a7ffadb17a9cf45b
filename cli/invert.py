"""``vertebra invert SCENE [--trajectory FILE.csv] [--json] [--plot FILE.png] [--mode converged|tick] [--budget S] [--prepare]``

Actuation that brings the scene's effectors to their targets (or along a trajectory). Each
step is reported at the equilibrium its actuation reaches (``InverseController.settled``).
Exit codes: 0 every target reached within tolerance; 1 solved but some target not reached
(or an equilibrium failed) — the JSON says which; 2 bad input.
"""

from __future__ import annotations

import argparse
import sys

from vertebra.cli.outputs import PICTURE_SUFFIXES, bound_warnings, output_file, range_warnings, refusal, write_json
from vertebra.cli.prepare import add_preparation, prepared_scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene file (TOML) or gallery:NAME")
    parser.add_argument("--trajectory", metavar="FILE.csv",
                        help="targets per step: columns <effector>.x,.y,.z (optional leading t)")
    parser.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    parser.add_argument("--plot", metavar="FILE.png", help="targets vs achieved paths and actuation")
    parser.add_argument("--vtk", metavar="FILE.pvd",
                        help="write the steps for ParaView: a .pvd time series of one .vtp per step "
                             "in a folder beside it (docs/paraview.md)")
    parser.add_argument("--mode", choices=("converged", "tick"), default="converged",
                        help="converged static inverse (default) or one linearise–QP step per tick")
    parser.add_argument("--backend", default=None,
                        help="QP backend: daqp (default), gauss-seidel, qpsolvers:<solver>")
    parser.add_argument("--tolerance", type=float, default=None,
                        help="effector error counted as reached, m (default 1e-6 converged, 1e-3 tick)")
    parser.add_argument("--effort", choices=("least", "penalty"), default=None,
                        help="how redundant actuation is chosen: least (default: the best reachable error, "
                             "then the least actuation energy keeping it) or penalty (one QP weighing the "
                             "error against the energy by --regularisation)")
    parser.add_argument("--regularisation", type=float, default=None,
                        help="with --effort penalty: the dimensionless actuation-energy weight ε (default 1e-8); "
                             "it trades effector error for effort")
    parser.add_argument("--max-iterations", type=int, default=None, metavar="N",
                        help="linearise–QP–solve iterations per target in converged mode (default 30)")
    parser.add_argument("--budget", type=float, default=None, metavar="S",
                        help="time budget per target in converged mode, s (default 2): then the closest "
                             "reach so far is reported (status \"budget\", exit 1)")
    parser.add_argument("--tangent-reuse", type=int, default=None, metavar="N",
                        help="tick mode: use a tick's tangent factor again for up to N following ticks while the "
                             "tensions stay near (chord steps; faster ticks, slightly larger tracking lag; default 0)")
    add_preparation(parser)


def _log(message: str) -> None:
    print(message, file=sys.stderr)


def run(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver
    from vertebra.solver.inverse import InverseSettings
    from vertebra.solver.inverse.trajectory import read_trajectory, scene_trajectory
    from vertebra.core.errors import ConvergenceError, OptionError

    plot = output_file(args.plot, "--plot", PICTURE_SUFFIXES)
    vtk = output_file(args.vtk, "--vtk", (".pvd",))
    if args.regularisation is not None and args.effort != "penalty":
        raise OptionError("weighs effort against effector error in the penalty QP: give --effort penalty with it "
                          "(the default least-effort QP does not trade accuracy for effort)", field="--regularisation")
    options = {key: value for key, value in (("backend", args.backend), ("tolerance", args.tolerance),
                                             ("regularisation", args.regularisation), ("time_budget", args.budget),
                                             ("effort", args.effort), ("max_iterations", args.max_iterations),
                                             ("tangent_reuse", args.tangent_reuse))
               if value is not None}
    settings = InverseSettings(mode=args.mode, **options)
    scene, code = prepared_scene(args)
    if code:
        return code
    model = solver.build_model(scene)
    trajectory = (read_trajectory(args.trajectory, model.effector_names, model.effector_targets)
                  if args.trajectory else scene_trajectory(model))
    try:
        return _invert(args, model, scene, settings, trajectory, plot, vtk)
    except ConvergenceError as error:
        if not args.json:
            raise
        _log(f"vertebra invert: {error}")
        write_json(refusal(error, scene=scene.name or args.scene, mode=args.mode, reached=False))
        return 1


def _invert(args, model, scene, settings, trajectory, plot, vtk) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.solver.bounds import BoundViolation
    from vertebra.solver.inverse import InverseController
    from vertebra.solver.plausible import trajectory_warnings
    from vertebra.solver.report import inverse_report, plot_inverse

    # the same start as the library's: no actuation (clipped into the bounds), at its equilibrium
    controller = InverseController(model, settings)
    if args.trajectory:
        trajectory_warnings(model, trajectory.targets, args.trajectory)     # a trajectory in mm

    def progress(i, step):
        if step.equilibrium_failure:
            _log(f"step {i}: no equilibrium under the commanded actuation: {step.equilibrium_failure}")
        for line in range_warnings(step.out_of_range, f"step {i}: "):
            _log(line)
        if not args.json:
            _log(f"step {i}: error {step.errors.max():.3e} m ({step.status}, {step.iterations} iteration(s), "
                 f"{step.timings['total_s'] * 1e3:.2f} ms)")

    steps = controller.track(trajectory.targets, settle=True, on_step=progress)
    document = inverse_report(model, steps, trajectory.times, scene=scene.name or args.scene, mode=args.mode,
                              backend=settings.backend, tolerance=settings.tolerance)
    broken = [(i, step["bound_violations"]) for i, step in enumerate(document["steps"]) if step["bound_violations"]]
    for i, violations in broken[:3]:
        shown = [BoundViolation(**{k: v for k, v in violation.items() if k != "unit"}) for violation in violations]
        for line in bound_warnings(shown, f"step {i}: "):
            _log(line)
    if len(broken) > 3:
        _log(f"warning: {len(broken) - 3} more steps beyond the scene's bounds (see bound_violations in the JSON)")
    if plot is not None:
        plot_inverse(model, steps, trajectory.times if trajectory.timed else None, path=str(plot),
                     tolerance=settings.tolerance)
    if vtk is not None:
        # lazy: the parser imports every subcommand module; the libraries load for the command that runs
        from vertebra.solver.paraview import trunk_polydata, write_pvd

        series = [(t, trunk_polydata(model, step.state, step.actuation, step.targets, time=t, friction=step.friction))
                  for t, step in zip(trajectory.times if trajectory.timed else range(len(steps)), steps)]
        files = write_pvd(str(vtk), series)
        _log(f"wrote {args.vtk} ({len(files)} steps in {files[0].parent}/)")
    if args.json:
        write_json(document)
    else:
        last = document["steps"][-1]
        for name, effector in last["effectors"].items():
            where = effector.get("position", effector.get("direction"))
            print(f"{name}: target {effector['target']} position {[round(v, 6) for v in where]} "
                  f"error {effector['error']:.3e} m")
        for name, cable in last["cables"].items():
            print(f"cable {name}: tension {cable['tension']:.6g} N, stroke {cable['stroke']:.6g} m")
        for name, chamber in last["chambers"].items():
            print(f"chamber {name}: pressure {chamber['pressure']:.6g} Pa, "
                  f"volume growth {chamber['volume_growth']:.6g} m^3")
        print(outcome(document, settings.tolerance, timed=trajectory.timed))
        print(f"median step {document['timing']['median_step_s'] * 1e3:.3f} ms")
    return 0 if document["reached"] else 1


SHOWN_STEPS = 5      # unreached steps named one by one in the text output; the rest are counted


def _when(step: dict, index: int, timed: bool) -> str:
    return f"step {index} (t = {step['t']:g} s)" if timed else f"step {index}"


def outcome(document: dict, tolerance: float, *, timed: bool) -> str:
    """One line saying whether every step reached its targets; if not, which steps (index and,
    for a timed trajectory, time), which effectors and how far, and which found no equilibrium."""
    steps, n = document["steps"], len(document["steps"])
    if document["reached"]:
        return f"reached within {tolerance:g} m at {'every one of ' if n > 1 else ''}{n} step{'s' * (n > 1)}"
    misses: dict[int, list[str]] = {}
    for miss in document["unreached"]:
        misses.setdefault(miss["step"], []).append(f"{miss['effector']} {miss['error']:.3e} m")
    failed = [i for i, step in enumerate(steps) if not step["equilibrium"]]
    parts = []
    if misses:
        named = [f"{_when(steps[i], i, timed)}: {', '.join(what)}" for i, what in list(misses.items())[:SHOWN_STEPS]]
        more = len(misses) - SHOWN_STEPS
        parts.append(f"NOT reached within {tolerance:g} m at {len(misses)} of {n} step{'s' * (n > 1)}: "
                     + "; ".join(named) + (f"; and {more} more" if more > 0 else ""))
    if failed:
        named = ", ".join(_when(steps[i], i, timed) for i in failed[:SHOWN_STEPS])
        more = len(failed) - SHOWN_STEPS
        parts.append(("" if misses else "NOT reached: ") + f"no equilibrium at {named}"
                     + (f" and {more} more" if more > 0 else ""))
    return "; ".join(parts)
