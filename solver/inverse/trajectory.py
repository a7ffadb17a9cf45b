"""Target trajectories for the inverse: the scene's targets, and CSV reading and writing.

CSV form: one row per step, columns ``<effector>.x``, ``<effector>.y``, ``<effector>.z`` and an
optional leading ``t``. Effectors without columns keep their scene target. Errors are
:class:`TrajectoryError` naming the file, the column or row, and the reason. Canonical target
paths (circles, reachable loops) are in ``solver.gallery.targets``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vertebra.core.errors import SceneError, TrajectoryError
from vertebra.core.inputs import read_text

__all__ = ["Trajectory", "scene_trajectory", "read_trajectory", "write_trajectory"]
MAX_TRAJECTORY_BYTES = 64 * 2**20       # a CSV of ~1 million steps of one effector


@dataclass(frozen=True)
class Trajectory:
    """Targets ``(n_steps, n_eff, 3)`` (m, world) and times ``(n_steps,)``: seconds when
    ``timed`` (a CSV with a ``t`` column, or times given in code), else the step index."""

    targets: np.ndarray
    times: np.ndarray
    timed: bool = True

    def __post_init__(self):
        t = np.asarray(self.targets, dtype=float)
        if t.ndim != 3 or t.shape[2] != 3 or t.shape[0] == 0:
            raise TrajectoryError(f"must have shape (n_steps ≥ 1, n_eff, 3), got {t.shape}", field="targets")
        times = np.asarray(self.times, dtype=float)
        if times.shape != (t.shape[0],):
            raise TrajectoryError(f"len(times) = {times.size}, but there are {t.shape[0]} steps", field="times")
        object.__setattr__(self, "targets", t)
        object.__setattr__(self, "times", times)


def scene_trajectory(model) -> Trajectory:
    """One step: the scene's effector targets (:class:`SceneError` when an effector has none)."""
    targets = np.asarray(model.effector_targets, dtype=float)
    for k, name in enumerate(model.effector_names):
        if not np.isfinite(targets[k]).all():
            raise SceneError(f"effector {name!r} has no target (give one, or a trajectory)",
                             file=model.scene.source, field=f"effector[{k}].target")
    return Trajectory(targets[None].copy(), np.zeros(1), timed=False)


def read_trajectory(path, effector_names, default_targets=None) -> Trajectory:
    """Read a trajectory CSV for a model with ``effector_names``.

    ``default_targets`` (n_eff, 3; NaN where none) fill effectors the file does not name.
    Rows are counted as lines of the file (the header is row 1).
    """
    path = str(path)
    names = list(effector_names)
    defaults = (np.full((len(names), 3), np.nan) if default_targets is None
                else np.asarray(default_targets, dtype=float).reshape(len(names), 3))
    text = read_text(path, TrajectoryError, limit=MAX_TRAJECTORY_BYTES)
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        rows = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    except csv.Error as error:
        raise TrajectoryError(f"cannot read CSV: {error}", file=path) from None
    if not rows:
        raise TrajectoryError("empty file: expected a header row and at least one step", file=path)
    header = [c.strip() for c in rows[0][1]]
    body = rows[1:]
    if not body:
        raise TrajectoryError("no steps after the header row", file=path)
    has_t = header[0] == "t"
    columns = {}
    for j, col in enumerate(header):
        if j == 0 and has_t:
            continue
        if col == "t":
            raise TrajectoryError("'t' may only be the first column", file=path, field=col)
        eff, _, axis = col.rpartition(".")
        if axis not in ("x", "y", "z") or not eff:
            raise TrajectoryError("column must be named <effector>.x, .y or .z", file=path, field=col)
        if eff not in names:
            raise TrajectoryError(f"unknown effector {eff!r}; the scene has {', '.join(names)}",
                                  file=path, field=col)
        if col in columns:
            raise TrajectoryError("duplicate column", file=path, field=col)
        columns[col] = j
    named = {c.rpartition(".")[0] for c in columns}
    for eff in sorted(named):
        missing = [f"{eff}.{a}" for a in "xyz" if f"{eff}.{a}" not in columns]
        if missing:
            raise TrajectoryError(f"effector {eff!r} needs all three columns; missing {', '.join(missing)}",
                                  file=path, field=missing[0])
    for k, eff in enumerate(names):
        if eff not in named and not np.isfinite(defaults[k]).all():
            raise TrajectoryError(f"effector {eff!r} has neither columns here nor a target in the scene",
                                  file=path, field=f"{eff}.x")
    n = len(body)
    targets = np.repeat(defaults[None], n, axis=0)
    times = np.arange(n, dtype=float)
    cells = ([("t", 0, None)] if has_t else []) + [
        (col, j, (names.index(col.rpartition(".")[0]), "xyz".index(col.rpartition(".")[2])))
        for col, j in columns.items()]
    for k, (line, row) in enumerate(body):
        if len(row) != len(header):
            raise TrajectoryError(f"has {len(row)} values, the header has {len(header)}", file=path,
                                  field=f"row {line}")
        for col, j, where in cells:
            try:
                value = float(row[j])
            except ValueError:
                raise TrajectoryError(f"{row[j].strip()!r} is not a number", file=path,
                                      field=f"row {line}, column {col}") from None
            if not math.isfinite(value):
                raise TrajectoryError(f"{row[j].strip()!r} is not finite", file=path, field=f"row {line}, column {col}")
            if where is None:
                times[k] = value
            else:
                targets[k, where[0], where[1]] = value
    return Trajectory(targets, times, timed=has_t)


def write_trajectory(path, trajectory: Trajectory, effector_names) -> None:
    """Write the CSV form read by :func:`read_trajectory` (with a ``t`` column)."""
    names = list(effector_names)
    with open(Path(path), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t"] + [f"{e}.{a}" for e in names for a in "xyz"])
        for t, row in zip(trajectory.times, trajectory.targets):
            w.writerow([repr(float(t))] + [repr(float(v)) for v in row.reshape(-1)])
