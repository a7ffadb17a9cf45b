"""``vertebra simulate SCENE [--json] [--plot FILE.png] [--vtk FILE.vtp] [--frames FILE.csv] [--prepare]``:
forward statics."""

from __future__ import annotations

import sys

from vertebra.cli.outputs import (PICTURE_SUFFIXES, bound_warnings, output_file, range_warnings, refusal, shown,
                                  write_json)
from vertebra.cli.prepare import add_preparation, prepared_scene
from vertebra.core.errors import ConvergenceError

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
    add_preparation(parser)


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
        write_vtp(str(vtk), trunk_polydata(model, result.state, result.actuation))
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
