"""``vertebra catalogue ls|show|verify|merge|query|export|rm|consolidate``.

JSON goes to stdout only (``--json``); messages go to stderr. CatalogueError is turned
into exit code 2 by ``cli.main``. ``verify`` exits 0 only when every entry and the
schema check out, 2 otherwise; ``merge`` exits 1 when conflicts were left out.
"""

from __future__ import annotations

import json

import numpy as np
import sys

from vertebra.cli.documents import print_document
from vertebra.cli.nonlinear_mesh import nonlinear_mesh_lines
from vertebra.core.errors import CatalogueError, OptionError
from vertebra.core.inputs import MAX_DEPTH


def _print_json(data) -> None:
    print_document(data)


def _text(params: dict) -> str:
    return ", ".join(f"{k}={json.dumps(v, sort_keys=True)}" for k, v in sorted(params.items()))


def _varied(rows: list[dict]) -> dict[str, dict]:
    """Per family of two or more ``rows``: the parameters every entry of it shares (name → value)."""
    by_family: dict[str, list[dict]] = {}
    for r in rows:
        by_family.setdefault(r["family"], []).append(r["parameters"])
    common = {}
    for family, params in by_family.items():
        if len(params) > 1:
            first = params[0]
            common[family] = {k: v for k, v in first.items() if all(k in p and p[k] == v for p in params[1:])}
    return common


def material(entry) -> str:
    """``linear``, or the material model of a nonlinear entry's fitted energy."""
    if entry.energy is None:
        return "linear"
    model = entry.energy.material.get("model") if isinstance(entry.energy.material, dict) else None
    return str(model or "nonlinear")


def fitted_range(entry) -> str:
    """One line: where a nonlinear entry's energy was fitted (strain extents by group, pressures)."""
    if entry.energy is None:
        return "-"
    r = entry.energy.range
    length = float(np.linalg.norm(entry.rest_translation)) or 1.0
    text = (f"lateral ≤ {r.pose_upper[0] / length:.3g} L, axial {r.pose_lower[1] / length:.3g}…"
            f"{r.pose_upper[1] / length:.3g} L, bending ≤ {r.pose_upper[2]:.3g} rad, "
            f"twist {r.pose_lower[3]:.3g}…{r.pose_upper[3]:.3g} rad")
    if r.pressure_upper.size:
        text += f", pressure ≤ {float(r.pressure_upper.max()):.4g} Pa"
    return text


def _table(rows: list[dict], wide: bool, pending=frozenset(), materials: dict | None = None) -> None:
    """Entries as aligned columns, nothing cut. The parameters column lists, per family of two or
    more entries, only the parameters that vary; the shared ones follow on one line per family
    (``wide``: every parameter on every row). ``materials``: key → material column."""
    common = {} if wide else _varied(rows)
    materials = materials or {}
    cells = [(r["key"], r["name"], r["family"], str(r["n_cavities"]), materials.get(r["key"], ""),
              _text({k: v for k, v in r["parameters"].items() if k not in common.get(r["family"], {})})
              + (" (pending)" if r["key"] in pending else "")) for r in rows]
    head = ("key", "name", "family", "cav", "material" if materials else "",
            "parameters" if wide else "parameters (varied)")
    widths = [max(len(c[j]) for c in cells + [head]) for j in range(5)]
    for c in [head] + cells:
        print("  ".join(value.ljust(width) for value, width in zip(c[:5], widths) if width) + "  " + c[5])
    for family, shared in common.items():
        if shared:
            print(f"every {family} entry: {_text(shared)}")


def _ls(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.store import catalogue

    with catalogue.open_catalogue(args.file) as cat:
        rows = cat.list()
        pending = set(cat.pending)
        if args.json:
            _print_json([{k: r[k] for k in ("key", "name", "family", "parameters")} for r in rows])
            return 0
        materials, ranges = {}, {}
        for r in rows:
            try:
                entry = cat.load(r["key"])
            except CatalogueError:
                materials[r["key"]] = "unreadable (catalogue verify)"
                continue
            materials[r["key"]] = material(entry)
            if entry.energy is not None:
                ranges[r["key"]] = fitted_range(entry)
    _table(rows, args.wide, pending, materials)
    for key, text in ranges.items():
        print(f"{key} fitted on: {text}")
    print(f"{len(rows)} entries", file=sys.stderr)
    return 0


def _show(args) -> int:
    import numpy as np

    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
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
        print(f"material   {material(entry)}")
        if entry.energy is not None:
            fit = entry.energy
            held = fit.fit_error.get("held_out", {}) if isinstance(fit.fit_error, dict) else {}
            print(f"energy     degree {fit.degree}, {fit.exponents.shape[0]} terms; held-out load error "
                  f"{held.get('load_max', float('nan')):.3g} (linear entry {held.get('linear_load_max', float('nan')):.3g})")
            for line in nonlinear_mesh_lines(fit):
                print(f"multi-fidelity  {line}")
            print(f"fitted on  {fitted_range(entry)}")
        for field in ("mesh", "accuracy", "timings", "provenance"):
            print(f"{field:10} {json.dumps(getattr(entry, field), sort_keys=True)}")
        print(f"checksum   {data['checksum']}")
    return 0


def _verify(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.store import catalogue

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
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
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


MAX_CONDITION = 1000      # characters of one --where condition


def _check_condition(condition: str) -> None:
    """Refuse a ``--where`` condition longer than :data:`MAX_CONDITION` characters or whose
    value nests lists or objects more than ``MAX_DEPTH`` deep (the JSON reader's recursion)."""
    if len(condition) > MAX_CONDITION:
        raise OptionError(f"at most {MAX_CONDITION} characters; got {len(condition):,}", field="--where")
    depth = deepest = 0
    for character in condition:
        depth += (character in "[{") - (character in "]}")
        deepest = max(deepest, depth)
    if deepest > MAX_DEPTH:
        raise OptionError(f"{condition[:40]!r}…: a value nested at most {MAX_DEPTH} deep; got {deepest}",
                          field="--where")


def _query(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.store import catalogue

    for condition in args.where or []:
        _check_condition(condition)
    rows = catalogue.query(args.file, args.where or [])
    if args.json:
        _print_json([{k: r[k] for k in ("key", "name", "family", "parameters")} for r in rows])
    else:
        _table(rows, args.wide)
        print(f"{len(rows)} matching entries", file=sys.stderr)
    return 0


def _export(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
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
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
    from vertebra.store import catalogue

    key = catalogue.remove(args.file, args.key)
    print(f"{args.file}: removed {key}", file=sys.stderr)
    return 0


def _consolidate(args) -> int:
    # lazy: the parser imports every subcommand module; the libraries load for the command that runs
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


def _wide(p):
    p.add_argument("--wide", action="store_true",
                   help="every parameter on every row (default: the varied ones; shared ones once per family)")


ACTIONS = {
    "ls": (_ls, "list entries", lambda p: (_file(p), _json(p), _wide(p))),
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
                         _json(p), _wide(p))),
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
