"""``vertebra prepare SCENE [--catalogue FILE] [--workers N] [--executor local|dask|serial] [--dry-run]``

Design the entries a scene's ``type = "design"`` segments need and its catalogue lacks (by
content key), reuse the rest, and report which were reused and which designed. ``simulate``,
``invert`` (and every command that reads a scene with :func:`add_preparation`) take
``--prepare`` to do this first. Exit codes: 0 every design segment has its entry; 1 a design
failed (see the failure log next to the catalogue) or a nonlinear entry was refused (its energy
fit misses its held-out samples by more than ``--max-fit-error`` where the scene goes); 2 bad
scene or options; 130 interrupted.
"""

from __future__ import annotations

import json
import sys

from vertebra.cli.sweep import add_executor_arguments


def add_preparation(parser, *, command: bool = False) -> None:
    """The options that design a scene's missing entries: ``vertebra prepare``'s own
    (``command``), or ``--prepare`` and the same options on a command that reads a scene."""
    group = parser if command else parser.add_argument_group(
        "design segments", "designing the entries of the scene's type = \"design\" segments (vertebra prepare)")
    if not command:
        group.add_argument("--prepare", action="store_true",
                           help="first design the entries the scene's design segments miss (as vertebra prepare)")
    group.add_argument("--catalogue", metavar="FILE", default=None,
                       help="catalogue of the scene's entries (default: the scene's [catalogue] path)")
    add_executor_arguments(group)
    group.add_argument("--no-accuracy", action="store_true",
                       help="designed entries skip the refined-mesh accuracy estimate")
    group.add_argument("--max-fit-error", metavar="FRACTION", type=_fit_error, default=None,
                       help="refuse a nonlinear entry whose fit misses its held-out samples by more than this "
                            "fraction of its load range where the scene goes (default 0.05; inf accepts any fit)")


def _fit_error(text: str) -> float:
    import argparse

    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number (inf: accept any fit), got {text!r}")
    return value


def _max_fit_error(args) -> dict:
    return {} if args.max_fit_error is None else {"max_fit_error": args.max_fit_error}


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="scene file (TOML) or gallery:NAME")
    add_preparation(parser, command=True)
    parser.add_argument("--dry-run", action="store_true",
                        help="list the entries that would be reused and designed; design nothing")
    parser.add_argument("--json", action="store_true", help="print one JSON report on stdout")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _prepare(args, *, dry_run: bool = False, progress: bool = True):
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver
    from vertebra.designer import prepare

    return prepare(solver.load_scene(args.scene), args.catalogue, build_model=solver.build_model,
                   executor="dask" if args.scheduler else args.executor,
                   workers=args.workers, scheduler=args.scheduler,
                   start_method=args.start_method, estimate_accuracy=not args.no_accuracy,
                   progress=progress, dry_run=dry_run, **_max_fit_error(args))


def prepared_scene(args):
    """The scene a command reads: with ``--prepare``, its missing entries designed first (the
    summary on stderr); without, its design segments resolved to the entries the catalogue
    already holds (an earlier ``vertebra prepare``); with ``--catalogue``, reading its entries
    from that file. Returns
    ``(scene, exit code)``: a non-zero code means a design failed (or an entry was refused: its fit
    cannot serve the scene, ``--max-fit-error``) and the command must stop."""
    import dataclasses

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import solver

    if args.prepare:
        scene, report = _prepare(args)
        print(report.summary(rows=False), file=sys.stderr)
        return scene, report.exit_code
    scene = solver.load_scene(args.scene)
    if args.catalogue is not None:
        scene = dataclasses.replace(scene, catalogue=args.catalogue)
    if scene.design_segments:           # the entries an earlier `vertebra prepare` designed
        # lazy: the designer (gmsh, scikit-fem) loads only for a scene of design segments
        from vertebra.designer.preparation import resolve_prepared

        scene = resolve_prepared(scene, build_model=solver.build_model, **_max_fit_error(args))
    return scene, 0


def run(args) -> int:
    _, report = _prepare(args, dry_run=args.dry_run, progress=not args.no_progress)
    if args.json:
        print(json.dumps(report.to_json(), indent=1))
    else:
        print(report.summary())
    return report.exit_code
