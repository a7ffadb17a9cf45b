"""Target trajectories for the inverse: CSV reading/writing and canonical paths.

CSV contract (DESIGN.md §5): one row per step, columns ``<effector>.x``, ``<effector>.y``,
``<effector>.z`` and an optional leading ``t``. Effectors without columns keep their scene
target. Errors are :class:`SceneError` naming the file, the column/row and the reason.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vertebra.store.errors import SceneError

__all__ = ["Trajectory", "read_trajectory", "write_trajectory", "circle"]


@dataclass(frozen=True)
class Trajectory:
    """Targets ``(n_steps, n_eff, 3)`` (m, world) and times ``(n_steps,)`` (s, or step index)."""

    targets: np.ndarray
    times: np.ndarray

    def __post_init__(self):
        t = np.asarray(self.targets, dtype=float)
        if t.ndim != 3 or t.shape[2] != 3 or t.shape[0] == 0:
            raise ValueError(f"targets must have shape (n_steps ≥ 1, n_eff, 3), got {t.shape}")
        times = np.asarray(self.times, dtype=float)
        if times.shape != (t.shape[0],):
            raise ValueError(f"len(times) = {times.size}, but there are {t.shape[0]} steps")
        object.__setattr__(self, "targets", t)
        object.__setattr__(self, "times", times)


def read_trajectory(path, effector_names, default_targets=None) -> Trajectory:
    """Read a trajectory CSV for a model with ``effector_names``.

    ``default_targets`` (n_eff, 3; NaN where none) fill effectors the file does not name.
    """
    path = str(path)
    names = list(effector_names)
    defaults = (np.full((len(names), 3), np.nan) if default_targets is None
                else np.asarray(default_targets, dtype=float).reshape(len(names), 3))
    try:
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise SceneError(f"cannot read CSV: {error}", file=path) from None
    if not rows:
        raise SceneError("empty file: expected a header row and at least one step", file=path)
    header = [c.strip() for c in rows[0]]
    body = rows[1:]
    if not body:
        raise SceneError("no steps after the header row", file=path)
    has_t = header[0] == "t"
    columns = {}
    for j, col in enumerate(header):
        if j == 0 and has_t:
            continue
        if col == "t":
            raise SceneError("'t' may only be the first column", file=path, field=col)
        eff, _, axis = col.rpartition(".")
        if axis not in ("x", "y", "z") or not eff:
            raise SceneError("column must be named <effector>.x, .y or .z", file=path, field=col)
        if eff not in names:
            raise SceneError(f"unknown effector {eff!r}; the scene has {', '.join(names)}",
                             file=path, field=col)
        if col in columns:
            raise SceneError("duplicate column", file=path, field=col)
        columns[col] = j
    named = {c.rpartition(".")[0] for c in columns}
    for eff in sorted(named):
        missing = [f"{eff}.{a}" for a in "xyz" if f"{eff}.{a}" not in columns]
        if missing:
            raise SceneError(f"effector {eff!r} needs all three columns; missing {', '.join(missing)}",
                             file=path, field=missing[0])
    for k, eff in enumerate(names):
        if eff not in named and not np.isfinite(defaults[k]).all():
            raise SceneError(f"effector {eff!r} has neither columns here nor a target in the scene",
                             file=path, field=f"{eff}.x")
    n = len(body)
    targets = np.repeat(defaults[None], n, axis=0)
    times = np.arange(n, dtype=float)
    for i, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise SceneError(f"has {len(row)} values, the header has {len(header)}", file=path,
                             field=f"row {i}")
        try:
            if has_t:
                times[i - 2] = float(row[0])
            for col, j in columns.items():
                eff, _, axis = col.rpartition(".")
                targets[i - 2, names.index(eff), "xyz".index(axis)] = float(row[j])
        except ValueError:
            raise SceneError(f"non-numeric value in {row!r}", file=path, field=f"row {i}") from None
    if not np.isfinite(targets).all() or not np.isfinite(times).all():
        raise SceneError("values must be finite", file=path)
    return Trajectory(targets, times)


def write_trajectory(path, trajectory: Trajectory, effector_names) -> None:
    """Write the CSV form read by :func:`read_trajectory` (with a ``t`` column)."""
    names = list(effector_names)
    with open(Path(path), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t"] + [f"{e}.{a}" for e in names for a in "xyz"])
        for t, row in zip(trajectory.times, trajectory.targets):
            w.writerow([repr(float(t))] + [repr(float(v)) for v in row.reshape(-1)])


def circle(center, radius: float, n_steps: int, *, normal=(0.0, 0.0, 1.0), turns: float = 1.0) -> np.ndarray:
    """``n_steps`` points (n_steps, 3) on a circle around ``center`` in the plane ⟂ ``normal``,
    starting at angle 0 (along the first in-plane axis) and closing after ``turns``."""
    center = np.asarray(center, dtype=float)
    normal = np.asarray(normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - normal * (helper @ normal)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    theta = np.linspace(0.0, 2.0 * np.pi * turns, n_steps)
    return center + radius * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)
