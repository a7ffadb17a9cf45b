"""``vertebra sweep SWEEP.toml --catalogue FILE``: a design-space sweep into the catalogue.

Exit codes: 0 every task done (or already in the catalogue); 1 some task failed
(see the failure log next to the catalogue); 2 bad spec or options (cli.main).
"""

from __future__ import annotations

import sys

from vertebra.cli.documents import print_document


def add_executor_arguments(parser) -> None:
    """Where entries are designed: the options of every command that designs (sweep, prepare)."""
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes (default: the CPUs available; with --scheduler: the cluster's)")
    parser.add_argument("--executor", default="local", choices=("local", "dask", "serial"),
                        help="local process pool (default), dask.distributed, or serial in this process")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="dask scheduler address, e.g. tcp://10.0.0.5:8786 (implies --executor dask)")
    parser.add_argument("--start-method", default="spawn", choices=("spawn", "forkserver"),
                        help="how the local executor starts workers (default: spawn)")


def add_arguments(parser) -> None:
    parser.add_argument("spec", metavar="SWEEP.toml", help="sweep specification (docs/sweeps.md)")
    parser.add_argument("--catalogue", required=True, metavar="FILE", help="HDF5 catalogue to fill")
    add_executor_arguments(parser)
    parser.add_argument("--dry-run", action="store_true",
                        help="validate, compute keys and show what would run; design nothing")
    parser.add_argument("--json", action="store_true", help="print one JSON report on stdout")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.designer.sweep import run_sweep

    executor = "dask" if args.scheduler else args.executor
    report = run_sweep(args.spec, args.catalogue, executor=executor, workers=args.workers,
                       scheduler=args.scheduler, start_method=args.start_method,
                       progress=not args.no_progress, dry_run=args.dry_run)
    if args.json:
        print_document(report.to_json(), indent=1)
    else:
        print(report.summary())
        if args.dry_run:
            for row in report.status():
                print(f"  {row['index']:4d} {row.get('status', '?'):9s} {row['key'] or '-':20s} "
                      f"{row['name'] or ''}", file=sys.stdout)
    return report.exit_code
