"""Output files named on the command line, checked before any work is done.

A subcommand that writes a file calls :func:`output_file` for its option while parsing its
input, so that a misspelt extension or a missing directory is an :class:`OptionError`
(exit 2, naming the option) instead of a failure after a long solve.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

from vertebra import __version__
from vertebra.core.errors import OptionError

PICTURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def output_file(value: str | None, option: str, suffixes: tuple[str, ...] | None) -> Path | None:
    """``value`` as a path that can be written: one of ``suffixes`` (case-insensitive; None:
    any), in an existing, writable directory, not a directory itself. ``None`` passes through."""
    if value is None:
        return None
    if "\x00" in value:
        raise OptionError(f"{value!r}: a file name cannot contain a NUL byte", field=option)
    path = Path(value)
    if suffixes is not None and path.suffix.lower() not in suffixes:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise OptionError(f"{value}: {got}; {option} writes {' or '.join(suffixes)}", field=option)
    if path.is_dir():
        raise OptionError(f"{value}: is a directory, not a file name", field=option)
    parent = path.parent
    if not parent.is_dir():
        raise OptionError(f"{value}: directory {str(parent)!r} does not exist", field=option)
    if not os.access(parent, os.W_OK):
        raise OptionError(f"{value}: directory {str(parent)!r} is not writable", field=option)
    return path


def range_warnings(excesses, where: str = "", limit: int = 3) -> list[str]:
    """One-line warnings for the states outside the range a link energy was fitted on
    (:class:`~vertebra.solver.kinds.RangeExcess`): the largest ``limit`` excesses, and how many
    more there are."""
    if not excesses:
        return []
    worst = sorted(excesses, key=lambda excess: -excess.excess)
    lines = [f"warning: {where}{len(excesses)} quantit{'y' if len(excesses) == 1 else 'ies'} of "
             f"{len({e.link for e in excesses})} link(s) outside the range their fitted energy was sampled on "
             "(beyond it the fitted correction keeps its boundary force and the linear stiffness carries the "
             "rest; widen the entry's sampled range with `vertebra design … --sampling bending=… --sampling "
             "strain=…`, or let `vertebra prepare` size it from the scene; diagnostics.out_of_range in the JSON):"]
    lines += [f"  {excess}" for excess in worst[:limit]]
    if len(worst) > limit:
        lines.append(f"  … and {len(worst) - limit} more")
    return lines


def bound_warnings(violations, where: str = "", limit: int = 5) -> list[str]:
    """One-line warnings for the actuator quantities beyond the scene's bounds
    (:class:`~vertebra.solver.bounds.BoundViolation`): the first ``limit``, and how many more."""
    if not violations:
        return []
    lines = [f"warning: {where}{len(violations)} actuator quantit{'y' if len(violations) == 1 else 'ies'} beyond "
             "the scene's bounds (bound_violations in the JSON):"]
    lines += [f"  {violation}" for violation in violations[:limit]]
    if len(violations) > limit:
        lines.append(f"  … and {len(violations) - limit} more")
    return lines


def finite_json(value):
    """``value`` (a JSON-ready document) with every float that is not finite (±inf, NaN) as
    ``None``: the document then holds only standard JSON (``null`` where a number is unbounded or
    unknown)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(item) for item in value]
    return value


def write_json(document, stream=None) -> None:
    """Write ``document`` as one line of standard JSON (non-finite numbers as ``null``:
    :func:`finite_json`) to ``stream`` (stdout)."""
    stream = sys.stdout if stream is None else stream
    json.dump(finite_json(document), stream, allow_nan=False)
    stream.write("\n")


def refusal(error, **fields) -> dict:
    """The JSON document of a command that refused to solve (exit 1): ``converged`` false and
    the ``error`` (its type and message), beside ``fields``."""
    return {"vertebra_version": __version__, **fields, "converged": False,
            "error": {"type": type(error).__name__, "message": str(error)}}


def shown(values, scale: float, relative: float):
    """``values`` with entries below ``relative`` × ``scale`` set to 0, for printing: a tension
    of 3.7e-31 N beside tensions of newtons is rounding of a zero, and prints as 0."""
    import numpy as np

    values = np.asarray(values, dtype=float)
    return np.where(np.abs(values) <= relative * abs(scale), 0.0, values)
