"""``vertebra simulate SCENE [--json] [--plot FILE.png] [--vtk FILE.vtp] [--frames FILE.csv] [--prepare]``:
forward statics."""

from __future__ import annotations

import json
import sys

from vertebra.cli.prepare import add_preparation, prepared_scene
from vertebra.store.errors import OptionError


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


def check_suffix(value: str | None, option: str, suffix: str) -> None:
    """An output file named on the command line must end in ``suffix`` (checked before solving)."""
    if value is not None and not value.lower().endswith(suffix):
        raise OptionError(f"{value}: {option} writes a {suffix} file", field=option)


def run(args) -> int:
    from vertebra import solver
    from vertebra.solver.paraview import trunk_polydata, write_vtp
    from vertebra.solver.report import plot_static, static_report, write_frames
    from vertebra.store.errors import ConvergenceError

    check_suffix(args.vtk, "--vtk", ".vtp")
    check_suffix(args.frames, "--frames", ".csv")
    scene, code = prepared_scene(args)
    if code:
        return code
    model = solver.build_model(scene)
    try:
        result = model.solve()
    except ConvergenceError as error:
        result = error.result
        print(f"vertebra simulate: {error}", file=sys.stderr)
    report = static_report(model, result)
    if args.plot:
        plot_static(model, result, args.plot)
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.vtk:
        write_vtp(args.vtk, trunk_polydata(model, result.state, result.actuation))
        print(f"wrote {args.vtk}", file=sys.stderr)
    if args.frames:
        write_frames(args.frames, result.state)
        print(f"wrote {args.frames}", file=sys.stderr)
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        status = "converged" if result.converged else "NOT converged"
        print(f"{scene.name or args.scene}: {status} in {result.iterations} iterations "
              f"({report['diagnostics']['load_stages']} load stages), residual {result.residual:.3g}, "
              f"{1e3 * result.timings['solve_s']:.3f} ms")
        for name, value in report["effectors"].items():
            print(f"  effector {name}: {' '.join(f'{v:+.6f}' for v in value['position'])} m")
        for name, value in report["cables"].items():
            print(f"  cable {name}: tension {value['tension']:g} N, stroke {value['stroke']:+.6g} m")
        for name, value in report["chambers"].items():
            print(f"  chamber {name}: pressure {value['pressure']:g} Pa, volume growth {value['volume_growth']:+.6g} m³")
    return 0 if result.converged else 1
