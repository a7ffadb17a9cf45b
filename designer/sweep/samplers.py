"""The samplers of a sweep spec: ``[grid]``, ``[[list]]`` and ``[lhs]``.

Each sampler parses its own table (raising :class:`SpecError` that names the field),
expands it into parameter sets in a deterministic order (resuming a sweep relies on the
same spec giving the same tasks) and says which parameters it varies. A sampler
registers in :data:`SAMPLERS`; adding one touches this file only.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Callable

from vertebra.core.errors import SpecError

LHS_FIELDS = ("ranges", "samples", "seed", "log", "integer")
LHS_DIGITS = 6                        # significant digits kept of each Latin-hypercube value
MAX_LHS_DIMENSIONS = 64               # parameters one Latin hypercube varies (a family has at most ~15)
MAX_TASKS = 10_000                    # tasks of one sweep (planning keys them all before any meshing: ~3 s)


def is_number(value) -> bool:
    """A finite int or float (not a bool): what TOML numbers become."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _is_count(value, minimum: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= minimum


def check_value(value, source: str, where: str) -> None:
    """A parameter value a sweep may set: a string, a bool, a finite number, or a table or list
    of them (NaN and infinity are refused: they make no geometry and no JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise SpecError(f"expected a finite number, got {value!r}", file=source, field=where)
    if isinstance(value, dict):
        for key, item in value.items():
            check_value(item, source, f"{where}.{key}")
    elif isinstance(value, list):
        for i, item in enumerate(value):
            check_value(item, source, f"{where}[{i}]")


def check_task_count(count: int, source: str, where: str) -> None:
    if count > MAX_TASKS:
        raise SpecError(f"the sweep would have {count:,} tasks; at most {MAX_TASKS:,} (split it into several "
                        "sweeps into the same catalogue)", file=source, field=where)


# --------------------------------------------------------------------------- [grid]

def parse_grid(table, source: str) -> dict:
    if not isinstance(table, dict) or not table:
        raise SpecError("expected a table of parameter = [values, ...]", file=source, field="grid")
    for parameter, values in table.items():
        if not isinstance(values, list) or not values:
            raise SpecError(f"expected a non-empty list of values, got {values!r}"[:200],
                            file=source, field=f"grid.{parameter}")
        check_value(values, source, f"grid.{parameter}")
    check_task_count(math.prod(len(values) for values in table.values()), source, "grid")
    return {parameter: list(values) for parameter, values in table.items()}


def expand_grid(grid: dict) -> list[dict]:
    """The cartesian product; the last parameter varies fastest."""
    names = list(grid)
    return [dict(zip(names, values)) for values in itertools.product(*(grid[n] for n in names))]


# --------------------------------------------------------------------------- [[list]]

def parse_list(table, source: str) -> list[dict]:
    """``[[list]]`` (one table per parameter set) or ``[list] sets = [{...}, ...]``."""
    if isinstance(table, dict):
        unknown = sorted(set(table) - {"sets"})
        if unknown:
            raise SpecError("unknown field (use [[list]] tables or [list] sets = [...])",
                            file=source, field=f"list.{unknown[0]}")
        table = table.get("sets")
    if not isinstance(table, list) or not table:
        raise SpecError("expected a non-empty list of parameter tables", file=source, field="list")
    check_task_count(len(table), source, "list")
    for i, item in enumerate(table):
        if not isinstance(item, dict) or not item:
            raise SpecError(f"expected a non-empty table of parameters, got {item!r}"[:200],
                            file=source, field=f"list[{i}]")
        check_value(item, source, f"list[{i}]")
    return [dict(item) for item in table]


def expand_list(sets: list[dict]) -> list[dict]:
    return [dict(item) for item in sets]


# --------------------------------------------------------------------------- [lhs]

@dataclass(frozen=True)
class LatinHypercube:
    """``[lhs]``: ``samples`` points, one per stratum in every dimension (scipy.stats.qmc)."""

    ranges: dict                      # parameter -> (low, high)
    samples: int
    seed: int
    log: tuple = ()                   # parameters sampled uniformly in log space
    integer: tuple = ()               # parameters rounded to the nearest integer


def _parse_ranges(ranges, source: str) -> dict:
    if not isinstance(ranges, dict) or not ranges:
        raise SpecError("expected a table of parameter = [low, high]", file=source, field="lhs.ranges")
    parsed = {}
    for parameter, bounds in ranges.items():
        where = f"lhs.ranges.{parameter}"
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(is_number(b) for b in bounds)):
            raise SpecError(f"expected [low, high] numbers, got {bounds!r}", file=source, field=where)
        low, high = float(bounds[0]), float(bounds[1])
        if not low < high:
            raise SpecError(f"low {low} must be below high {high}", file=source, field=where)
        parsed[parameter] = (low, high)
    return parsed


def _parse_names(table: dict, option: str, ranges: dict, source: str) -> tuple:
    names = table.get(option, [])
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise SpecError("expected a list of parameter names", file=source, field=f"lhs.{option}")
    for name in names:
        if name not in ranges:
            raise SpecError(f"{name!r} has no range in lhs.ranges", file=source, field=f"lhs.{option}")
    return tuple(names)


def parse_lhs(table, source: str) -> LatinHypercube:
    if not isinstance(table, dict):
        raise SpecError("expected a table", file=source, field="lhs")
    for name in table:
        if name not in LHS_FIELDS:
            raise SpecError(f"unknown field (known: {', '.join(LHS_FIELDS)})", file=source, field=f"lhs.{name}")
    for required in ("ranges", "samples", "seed"):
        if required not in table:
            reason = ("required: the same seed gives the same tasks, which resuming relies on"
                      if required == "seed" else "required")
            raise SpecError(reason, file=source, field=f"lhs.{required}")
    ranges = _parse_ranges(table["ranges"], source)
    if len(ranges) > MAX_LHS_DIMENSIONS:
        raise SpecError(f"at most {MAX_LHS_DIMENSIONS} parameters; got {len(ranges)}", file=source,
                        field="lhs.ranges")
    samples, seed = table["samples"], table["seed"]
    if not _is_count(samples, 1):
        raise SpecError(f"expected a positive integer, got {samples!r}", file=source, field="lhs.samples")
    check_task_count(samples, source, "lhs.samples")
    if not _is_count(seed, 0):
        raise SpecError(f"expected a non-negative integer, got {seed!r}", file=source, field="lhs.seed")
    log = _parse_names(table, "log", ranges, source)
    integer = _parse_names(table, "integer", ranges, source)
    for name in log:
        if ranges[name][0] <= 0.0:
            raise SpecError(f"log sampling of {name!r} needs a positive range", file=source, field="lhs.log")
    return LatinHypercube(ranges, samples, seed, log, integer)


def latin_hypercube_unit(dimensions: int, samples: int, seed: int):
    """(samples, dimensions) points in [0, 1): exactly one per stratum [i/n, (i+1)/n) per dimension."""
    from scipy.stats import qmc

    return qmc.LatinHypercube(d=dimensions, rng=seed).random(samples)


def expand_lhs(lhs: LatinHypercube) -> list[dict]:
    import numpy as np

    names = list(lhs.ranges)
    unit = latin_hypercube_unit(len(names), lhs.samples, lhs.seed)
    tasks = []
    for row in unit:
        values = {}
        for name, u in zip(names, row):
            low, high = lhs.ranges[name]
            if name in lhs.log:
                value = float(np.exp(np.log(low) + u * (np.log(high) - np.log(low))))
            else:
                value = float(low + u * (high - low))
            # 6 significant digits: readable names and parameters, and keys that do not
            # hinge on the last bits of exp/log on one platform (resume across machines)
            values[name] = int(round(value)) if name in lhs.integer else float(f"{value:.{LHS_DIGITS}g}")
        tasks.append(values)
    return tasks


# --------------------------------------------------------------------------- registry

@dataclass(frozen=True)
class Sampler:
    parse: Callable[[Any, str], Any]  # (table, source) -> validated design; SpecError names the field
    expand: Callable[[Any], list[dict]]
    varied: Callable[[Any], set]      # the parameter names the sampler sets


SAMPLERS: dict[str, Sampler] = {
    "grid": Sampler(parse_grid, expand_grid, lambda grid: set(grid)),
    "list": Sampler(parse_list, expand_list, lambda sets: set().union(*(set(s) for s in sets))),
    "lhs": Sampler(parse_lhs, expand_lhs, lambda lhs: set(lhs.ranges)),
}
