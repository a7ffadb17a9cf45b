"""``vertebra simulate SCENE [--json] [--plot FILE.png] [--vtk FILE.vtp] [--frames FILE.csv] [--prepare]
[--sequence NAME=V1,V2,… …]``: forward statics; with ``--sequence`` a series of commands solved in
order, each from the state (and the cables' friction state) the one before left."""

from __future__ import annotations

import sys

from vertebra.cli.outputs import (PICTURE_SUFFIXES, bound_warnings, output_file, range_warnings, refusal, shown,
                                  write_json)
from vertebra.cli.prepare import add_preparation, prepared_scene
from vertebra.core.errors import ConvergenceError, OptionError

VTK_SUFFIXES = (".vtp",)
FRAME_SUFFIXES = (".csv",)


def add_arguments(parser):
    parser.add_argument("scene", help="scene file (TOML; docs/scenes.md) or gallery:NAME")
    parser.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    parser.add_argument("--plot", metavar="FILE.png", help="write a picture of the equilibrium")
    parser.add_argument("--vtk", metavar="FILE.vtp",
                        help="write the trunk for ParaView: VTK PolyData with frames, cables, tensions, "
                             "effectors and targets (docs/paraview.md)")
    parser.add_argument("--frames", metavar="FILE.csv",
                        help="write every frame's pose as a row-major 4x4 transform (n x 16, a header row)")
    parser.add_argument("--sequence", metavar="NAME=V1,V2,...", action="append",
                        help="solve a sequence of commands in order, each from the last one's state: the values "
                             "of actuator NAME, one per step (repeat for several actuators, the same count each; "
                             "the others keep the scene's value). With cable friction a pull then a release "
                             "traces the hysteresis loop (docs/friction.md). --json prints "
                             '{"sequence": [one simulate document per step]}; pictures and files show the last step')
    add_preparation(parser)


def _sequence(model, items) -> list:
    """The commands of ``--sequence`` items (``NAME=V1,V2,…``) as actuation arrays."""
    columns = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not values.strip():
            raise OptionError(f"{item!r}: expected NAME=V1,V2,... (an actuator's values, one per step)",
                              field="--sequence")
        if name not in model.actuator_names:
            raise OptionError(f"{item!r}: unknown actuator {name!r} (the scene has "
                              f"{', '.join(model.actuator_names) or 'no actuators'})", field="--sequence")
        if name in columns:
            raise OptionError(f"{item!r}: actuator {name!r} given twice", field="--sequence")
        try:
            columns[name] = [float(v) for v in values.split(",")]
        except ValueError:
            raise OptionError(f"{item!r}: the values must be numbers separated by commas", field="--sequence") from None
    counts = {len(v) for v in columns.values()}
    if len(counts) != 1:
        raise OptionError(f"every actuator needs the same number of values (got {sorted(counts)})", field="--sequence")
    return [model.actuation({name: values[step] for name, values in columns.items()}) for step in range(counts.pop())]


def run(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver
    from vertebra.solver.paraview import trunk_polydata, write_vtp
    from vertebra.solver.report import plot_static, static_report, write_frames

    plot = output_file(args.plot, "--plot", PICTURE_SUFFIXES)
    vtk = output_file(args.vtk, "--vtk", VTK_SUFFIXES)
    frames = output_file(args.frames, "--frames", FRAME_SUFFIXES)
    scene, code = prepared_scene(args)
    if code:
        return code
    model = solver.build_model(scene)
    if args.sequence:
        return _run_sequence(args, model, _sequence(model, args.sequence), plot, vtk, frames)
    try:
        result = model.solve()
    except ConvergenceError as error:
        if error.result is None:          # no state to report (e.g. a chamber beyond its limit point)
            if not args.json:
                raise
            print(f"vertebra simulate: {error}", file=sys.stderr)
            write_json(refusal(error, scene=scene.name or args.scene))
            return 1
        result = error.result
        print(f"vertebra simulate: {error}", file=sys.stderr)
    for line in range_warnings(result.out_of_range) + bound_warnings(result.bound_violations):
        print(f"vertebra simulate: {line}", file=sys.stderr)
    report = static_report(model, result)
    if plot is not None:
        plot_static(model, result, str(plot))
        print(f"wrote {plot}", file=sys.stderr)
    if vtk is not None:
        write_vtp(str(vtk), trunk_polydata(model, result.state, result.actuation, friction=result.friction,
                                                  contacts=result.contacts))
        print(f"wrote {vtk}", file=sys.stderr)
    if frames is not None:
        write_frames(str(frames), result.state)
        print(f"wrote {frames}", file=sys.stderr)
    if args.json:
        write_json(report)
    else:
        status = "converged" if result.converged else "NOT converged"
        print(f"{scene.name or args.scene}: {status} in {result.iterations} iterations "
              f"({report['diagnostics']['load_stages']} load stages), residual {result.residual:.3g}, "
              f"{1e3 * result.timings['solve_s']:.3f} ms")
        for name, value in report["effectors"].items():
            where = (f"position {' '.join(f'{v:+.6f}' for v in value['position'])} m" if "position" in value
                     else f"direction {' '.join(f'{v:+.6f}' for v in value['direction'])}")
            print(f"  effector {name}: {where}")
        _print_actuators(model, report, scene.solver.tolerance)
    return 0 if result.converged else 1


def _largest(*groups) -> float:
    """The largest finite magnitude among the values of ``groups`` (0 when there is none)."""
    import numpy as np

    values = np.abs(np.concatenate([np.ravel(np.asarray(g, dtype=float)) for g in groups]))
    return float(values[np.isfinite(values)].max(initial=0.0))


def _print_actuators(model, report: dict, tolerance: float) -> None:
    """Tensions, strokes, pressures and volume growths; a value below the solver tolerance's
    share of the largest of its kind (values and bounds) is rounding and prints as 0."""
    upper, n = model.actuator_bounds[1], model.n_cables
    cables, chambers = list(report["cables"].items()), list(report["chambers"].items())
    tensions = [c["tension"] for _, c in cables]
    strokes = [c["stroke"] for _, c in cables]
    for (name, _), tension, stroke in zip(cables, shown(tensions, _largest(tensions, upper[:n]), tolerance),
                                          shown(strokes, model.length_scale, tolerance)):
        print(f"  cable {name}: tension {tension:g} N, stroke {stroke:+.6g} m")
    pressures = [c["pressure"] for _, c in chambers]
    volumes = [c["volume_growth"] for _, c in chambers]
    rest = [c["rest_volume"] for _, c in chambers]
    for (name, _), pressure, volume in zip(chambers, shown(pressures, _largest(pressures, upper[n:]), tolerance),
                                           shown(volumes, _largest(volumes, rest), tolerance)):
        print(f"  chamber {name}: pressure {pressure:g} Pa, volume growth {volume:+.6g} m³")


def _run_sequence(args, model, commands: list, plot, vtk, frames) -> int:
    """``--sequence``: solve ``commands`` in order; stop at the first that fails."""
    # lazy: the libraries load for the command that runs (as in run)
    from vertebra.solver.paraview import trunk_polydata, write_vtp
    from vertebra.solver.report import plot_static, static_report, write_frames

    name = model.scene.name or args.scene
    reports, history, initial, failed = [], None, None, False
    for step, command in enumerate(commands):
        try:
            result = model.solve(command, initial, history=history)
        except ConvergenceError as error:
            print(f"vertebra simulate: step {step}: {error}", file=sys.stderr)
            if error.result is None:
                failed = True
                break
            result, failed = error.result, True
        for line in range_warnings(result.out_of_range) + bound_warnings(result.bound_violations):
            print(f"vertebra simulate: step {step}: {line}", file=sys.stderr)
        report = static_report(model, result)
        reports.append(report)
        if not args.json:
            status = "converged" if result.converged else "NOT converged"
            values = " ".join(f"{n}={v:g}" for n, v in zip(model.actuator_names, command))
            where = "; ".join(f"{e} " + " ".join(f"{v:+.6f}" for v in (row.get("position") or row["direction"]))
                              for e, row in report["effectors"].items())
            print(f"{name} step {step}: {values}: {status}, {where}")
        if failed:
            break
        history, initial = result.friction, result.state
    if reports:
        if plot is not None:
            plot_static(model, result, str(plot))
            print(f"wrote {plot}", file=sys.stderr)
        if vtk is not None:
            write_vtp(str(vtk), trunk_polydata(model, result.state, result.actuation, friction=result.friction,
                                                  contacts=result.contacts))
            print(f"wrote {vtk}", file=sys.stderr)
        if frames is not None:
            write_frames(str(frames), result.state)
            print(f"wrote {frames}", file=sys.stderr)
    if args.json:
        write_json({"vertebra_version": reports[0]["vertebra_version"] if reports else None, "sequence": reports})
    return 1 if failed else 0
