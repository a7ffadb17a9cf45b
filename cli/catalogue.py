"""``vertebra catalogue ls|show|verify|merge|query|export|rm|consolidate``.

JSON goes to stdout only (``--json``); messages go to stderr. CatalogueError is turned
into exit code 2 by ``cli.main``. ``verify`` exits 0 only when every entry and the
schema check out, 2 otherwise; ``merge`` exits 1 when conflicts were left out.
"""

from __future__ import annotations

import json
import sys


def _print_json(data) -> None:
    json.dump(data, sys.stdout, allow_nan=False)
    sys.stdout.write("\n")


def _short(params: dict, width: int = 60) -> str:
    text = ", ".join(f"{k}={v}" for k, v in sorted(params.items()))
    return text if len(text) <= width else text[: width - 1] + "…"


def _ls(args) -> int:
    from vertebra.store import catalogue

    with catalogue.open_catalogue(args.file) as cat:
        rows = cat.list()
        pending = set(cat.pending)
    if args.json:
        _print_json([{k: r[k] for k in ("key", "name", "family", "parameters")} for r in rows])
        return 0
    print(f"{'key':20}  {'name':24}  {'family':10}  cav  parameters")
    for r in rows:
        mark = " (pending)" if r["key"] in pending else ""
        print(f"{r['key']:20}  {r['name'][:24]:24}  {r['family'][:10]:10}  {r['n_cavities']:3d}  "
              f"{_short(r['parameters'])}{mark}")
    print(f"{len(rows)} entries", file=sys.stderr)
    return 0


def _show(args) -> int:
    import numpy as np

    from vertebra.store import catalogue

    with catalogue.open_catalogue(args.file) as cat:
        entry = cat.load(args.key)
    data = catalogue.entry_to_dict(entry)
    if args.json:
        _print_json(data)
        return 0
    with np.printoptions(precision=4, linewidth=120):
        print(f"key        {entry.key}\nname       {entry.name}\nfamily     {entry.family}")
        print(f"parameters {json.dumps(entry.parameters, sort_keys=True)}")
        print(f"cavities   {entry.n_cavities}  rest volumes {entry.cavity_volumes} m^3")
        print(f"mass       {entry.mass} kg  centre of mass {entry.center_of_mass} m")
        print(f"rest pose  d0 {entry.rest_translation} m  R0 {entry.rest_quaternion}")
        print(f"compliance ({entry.compliance.shape[0]}×{entry.compliance.shape[1]})\n{entry.compliance}")
        for field in ("mesh", "accuracy", "timings", "provenance"):
            print(f"{field:10} {json.dumps(getattr(entry, field), sort_keys=True)}")
        print(f"checksum   {data['checksum']}")
    return 0


def _verify(args) -> int:
    from vertebra.store import catalogue

    from vertebra.store.errors import CatalogueError

    problems = catalogue.verify(args.file)
    try:
        with catalogue.open_catalogue(args.file) as cat:
            n = len(cat)
    except CatalogueError:               # e.g. a broken index: already among the problems
        n = None
    if args.json:
        _print_json({"ok": not problems, "entries": n, "problems": problems})
    else:
        for p in problems:
            print(p)
        print(f"{args.file}: {'?' if n is None else n} entries, " + ("OK" if not problems else f"{len(problems)} problem(s)"),
              file=sys.stderr)
    return 0 if not problems else 2


def _merge(args) -> int:
    from vertebra.store import catalogue

    report = catalogue.merge(args.out, args.inputs)
    if args.json:
        _print_json(report.as_dict())
    else:
        for c in report.conflicts:
            print(f"conflict: {c}", file=sys.stderr)
        for r in report.rejected:
            print(f"rejected: {r}", file=sys.stderr)
    print(f"{args.out}: added {len(report.added)}, skipped identical {len(report.skipped)}, "
          f"conflicts {len(report.conflicts)} (existing entries kept)", file=sys.stderr)
    return 1 if report.conflicts else 0


def _query(args) -> int:
    from vertebra.store import catalogue

    rows = catalogue.query(args.file, args.where or [])
    if args.json:
        _print_json([{k: r[k] for k in ("key", "name", "family", "parameters")} for r in rows])
    else:
        for r in rows:
            print(f"{r['key']:20}  {r['name'][:24]:24}  {r['family'][:10]:10}  {_short(r['parameters'])}")
        print(f"{len(rows)} matching entries", file=sys.stderr)
    return 0


def _export(args) -> int:
    from vertebra.store import catalogue

    if args.format == "json" and args.out is None:
        with catalogue.open_catalogue(args.file) as cat:
            entry = cat.load(args.key)
        _print_json(catalogue.entry_to_dict(entry))
        return 0
    out = catalogue.export(args.file, args.key, args.format, args.out)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _rm(args) -> int:
    from vertebra.store import catalogue

    key = catalogue.remove(args.file, args.key)
    print(f"{args.file}: removed {key}", file=sys.stderr)
    return 0


def _consolidate(args) -> int:
    from vertebra.store import catalogue

    report = catalogue.consolidate(args.file)
    if args.json:
        _print_json(report.as_dict())
    print(f"{args.file}: merged {len(report.added)} pending entries, skipped {len(report.skipped)}, "
          f"conflicts {len(report.conflicts)}, rejected {len(report.rejected)}", file=sys.stderr)
    return 1 if report.conflicts or report.rejected else 0


# name -> (handler, help, argument adder)
def _file(p):
    p.add_argument("file", metavar="FILE", help="catalogue file (.h5)")


def _json(p):
    p.add_argument("--json", action="store_true", help="print JSON on stdout")


ACTIONS = {
    "ls": (_ls, "list entries", lambda p: (_file(p), _json(p))),
    "show": (_show, "show one entry (key, unique key prefix or unique name)",
             lambda p: (_file(p), p.add_argument("key", metavar="KEY"), _json(p))),
    "verify": (_verify, "check schema, checksums and index; exit 0 only if all good",
               lambda p: (_file(p), _json(p))),
    "merge": (_merge, "merge catalogues into OUT (conflicts reported, nothing overwritten)",
              lambda p: (p.add_argument("out", metavar="OUT"),
                         p.add_argument("inputs", metavar="IN", nargs="+"), _json(p))),
    "query": (_query, "entries matching every --where condition",
              lambda p: (_file(p), p.add_argument("--where", action="append", metavar="COND",
                                                  help="e.g. 'radius>=0.01', 'family=rod' (= != < <= > >=)"),
                         _json(p))),
    "export": (_export, "export one entry as JSON or NPZ",
               lambda p: (_file(p), p.add_argument("key", metavar="KEY"),
                          p.add_argument("--format", choices=("json", "npz"), default="json"),
                          p.add_argument("--out", metavar="PATH", default=None,
                                         help="output file (default: JSON to stdout, NPZ to KEY.npz)"))),
    "rm": (_rm, "remove one entry", lambda p: (_file(p), p.add_argument("key", metavar="KEY"))),
    "consolidate": (_consolidate, "merge pending shards into the catalogue file now",
                    lambda p: (_file(p), _json(p))),
}


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, (handler, help_text, adder) in ACTIONS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        adder(p)
        p.set_defaults(_action=handler)


def run(args) -> int:
    try:
        return args._action(args)
    except BrokenPipeError:              # e.g. `vertebra catalogue ls FILE | head`: not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
