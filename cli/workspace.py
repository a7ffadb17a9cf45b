"""``vertebra workspace SCENE [--samples N] [--json] [--plot FILE.png] [--points FILE.csv] [--prepare]``

Reachable effector positions over actuations sampled quasi-randomly within their bounds
(``vertebra.solver.workspace``). Progress goes to stderr; ``--json`` prints one summary
document on stdout (per effector: count, extents, centroid, convex hull; failures by
sample); ``--points`` writes every sample; the samples are solved in batches
(``model.solve_batch``), and ``--processes N`` spreads the batches over N processes
(``--executor dask`` or ``--scheduler ADDRESS``, the options that also say where ``--prepare``
designs entries, over a dask cluster; ``--workers`` is for designing entries with ``--prepare``). Exit codes: 0 when at
least one sample converged (failed samples are counted and listed), 1 when none did or a
design failed, 2 bad input.
"""

from __future__ import annotations

import sys

from vertebra.cli.outputs import PICTURE_SUFFIXES, output_file, write_json
from vertebra.cli.prepare import add_preparation, prepared_scene

POINT_SUFFIXES = (".csv", ".npz")
MAX_PROCESSES = 256       # --processes (and --workers: cli/sweep.py)


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="scene file (TOML) or gallery:NAME")
    parser.add_argument("--samples", type=int, default=1000, metavar="N", help="actuations to sample (default 1000)")
    parser.add_argument("--json", action="store_true", help="print one JSON summary on stdout")
    parser.add_argument("--plot", metavar="FILE.png", help="draw the clouds with their convex hulls and projections")
    parser.add_argument("--points", metavar="FILE.csv", help="write every sample (.csv or .npz)")
    parser.add_argument("--sampler", choices=("sobol", "halton"), default="sobol",
                        help="quasi-random sequence (scrambled; default sobol)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scrambling (default 0)")
    parser.add_argument("--ordering", choices=("levels", "tree", "chain", "sampled"), default="levels",
                        help="which solved sample each one starts from; samples are solved in batches, one "
                             "generation of this order at a time (default levels: two batches)")
    parser.add_argument("--tolerance", type=float, default=None,
                        help="Newton tolerance (scaled residual; default: the scene's)")
    parser.add_argument("--processes", type=int, default=1, metavar="N",
                        help="processes solving the batches (default 1; with --executor dask or --scheduler the "
                             "batches are solved on dask: a LocalCluster of N workers, or the scheduler's cluster)")
    parser.add_argument("--drop-outside", action="store_true",
                        help="leave out of the clouds the samples whose equilibrium breaks a bound of the scene "
                             "(stroke, volume growth, tendon tension) or leaves an entry's fitted range "
                             "(they are counted and flagged either way)")
    add_preparation(parser)


def _with_tip_effector(scene):
    """The scene with an effector ``tip`` at the last vertebra's origin when it has none."""
    import dataclasses

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.solver.scene import EffectorSpec

    if scene.effectors:
        return scene
    print("vertebra workspace: the scene has no [[effector]]; mapping the tip vertebra's origin as 'tip'",
          file=sys.stderr)
    return dataclasses.replace(scene, effectors=(EffectorSpec("tip", scene.n_vertebrae - 1),))


def run(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra import __version__, solver
    from vertebra.solver.workspace import MAX_SAMPLES, sample_workspace, write_points
    from vertebra.core.errors import OptionError

    plot = output_file(args.plot, "--plot", PICTURE_SUFFIXES)
    points = output_file(args.points, "--points", POINT_SUFFIXES)
    if not 1 <= args.samples <= MAX_SAMPLES:
        raise OptionError(f"must be from 1 to {MAX_SAMPLES:,} (at most {MAX_SAMPLES:,}); got {args.samples:,}",
                          field="--samples")
    if not 0 <= args.seed < 2**63:
        raise OptionError(f"must be a whole number from 0 to 2**63 - 1, got {args.seed}", field="--seed")
    if not 1 <= args.processes <= MAX_PROCESSES:
        raise OptionError(f"must be from 1 to {MAX_PROCESSES} (at most {MAX_PROCESSES}); got {args.processes}",
                          field="--processes")
    if args.tolerance is not None and not 0 < args.tolerance < float("inf"):
        raise OptionError(f"must be a positive number, got {args.tolerance}", field="--tolerance")
    scene, code = prepared_scene(args)
    if code:
        return code
    scene = _with_tip_effector(scene)
    model = solver.build_model(scene)

    from tqdm import tqdm

    with tqdm(total=args.samples, unit="solve", file=sys.stderr, disable=None, desc="workspace") as bar:
        workspace = sample_workspace(model, args.samples, method=args.sampler, seed=args.seed,
                                     ordering=args.ordering, tolerance=args.tolerance, workers=args.processes,
                                     executor="dask" if args.scheduler or args.executor == "dask" else "local",
                                     scheduler=args.scheduler,
                                     progress=bar.update, drop_outside=args.drop_outside)
    if points is not None:
        write_points(workspace, points)
        print(f"wrote {points}", file=sys.stderr)
    if plot is not None:
        # lazy: the parser imports every subcommand module; the libraries load for the command that runs
        from vertebra.solver.workspace_plot import plot_workspace

        plot_workspace(workspace, plot, rest=model.effector_positions(model.rest_state),
                       title=f"{scene.name or args.scene}: reachable workspace, {workspace.n_samples} samples")
        print(f"wrote {plot}", file=sys.stderr)
    summary = workspace.summary()
    if args.json:
        document = {"vertebra_version": __version__, "scene": scene.name or args.scene, **summary,
                    "points_file": None if points is None else str(points)}
        write_json(document)
    else:
        _print_summary(scene.name or args.scene, summary)
    return 0 if summary["converged"] else 1


def _print_summary(name: str, summary: dict) -> None:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.solver.workspace import area_text, volume_text

    timing = summary["timing"]
    print(f"{name}: {summary['converged']} of {summary['samples']} samples converged "
          f"({summary['failed']} failed), {summary['iterations']['mean'] or 0:.2f} Newton iterations per solve, "
          f"{timing['wall_s']:.2f} s wall, {timing['cpu_s']:.2f} s CPU")
    for effector, entry in summary["effectors"].items():
        if entry["count"] == 0:
            print(f"  effector {effector}: no converged sample")
            continue
        lower, upper = entry["lower"], entry["upper"]
        extent = " ".join(f"{axis} {lo:+.4f}..{hi:+.4f}" for axis, lo, hi in zip("xyz", lower, upper))
        hull = entry.get("hull")
        if hull is None:
            shape = "directions"
        elif hull["dimension"] == 3:
            shape = f"hull volume {volume_text(hull['volume'])}"
        elif hull["dimension"] == 2:
            shape = f"planar, hull area {area_text(hull['area'])}"
        else:
            shape = f"spans {hull['dimension']} dimension(s)"
        print(f"  effector {effector}: {extent} m, {shape}")
    outside = summary["beyond_bounds"] + summary["out_of_range"]
    if outside:
        named = ", ".join(f"{key} ({count})" for key, count in list(summary["violations"].items())[:5])
        print(f"  warning: {summary['beyond_bounds']} converged samples break a bound of the scene and "
              f"{summary['out_of_range']} leave an entry's fitted range ({named}); "
              + (f"{summary['dropped']} dropped from the clouds" if summary["dropped"]
                 else "kept in the clouds and flagged (--drop-outside leaves them out)"))
    for failure in summary["failures"][:5]:
        print(f"  sample {failure['sample']} failed: {failure['error']}: {failure['message']}")
    if len(summary["failures"]) > 5:
        print(f"  … and {len(summary['failures']) - 5} more failures (--json lists them all)")
