"""Planning a batch of tasks (a sweep's, a scene's): every task validated and keyed before any meshing.

Each task's parameters go through the designer's ``canonical`` (invalid ones become
failures at stage ``validate``), get their entry name and their content key (stage
``key``). Tasks whose key the store already holds are skipped (this is what makes a
sweep resumable); a key repeated within the sweep runs once.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from typing import Callable

from vertebra.designer.sweep.report import TaskFailure
from vertebra.designer.sweep.spec import SweepSpec
from vertebra.designer.sweep.store import CatalogueStore, SweepStore
from vertebra.designer.sweep.tasks import Batch, FiniteElementDesigner, SegmentDesigner, Task, sweep_batch
from vertebra.core import plausibility
from vertebra.core.errors import CatalogueError, SpecError, VertebraError

#: what a designer may raise for one task's parameters; the task fails, the sweep goes on
TASK_ERRORS = (VertebraError, ValueError, TypeError, KeyError)


@dataclass(frozen=True)
class SweepPlan:
    """A batch's tasks sorted out before any meshing."""

    batch: Batch
    catalogue: str                    # as given (logs and reports)
    store: SweepStore                 # the catalogue at its absolute path (workers)
    designer: SegmentDesigner         # designs the tasks to run (workers)
    tasks: tuple                      # every task, planned (canonical parameters, key, name)
    todo: tuple                       # tasks to run
    skipped: tuple                    # tasks whose key is already in the catalogue
    duplicates: tuple                 # (task, index of the task with the same key that runs)
    invalid: tuple                    # TaskFailure at stage "validate" or "key"


def _json_ready(parameters: dict) -> dict:
    """Parameters as they will appear in logs: must be JSON (they come from TOML, so they are)."""
    return json.loads(json.dumps(parameters, default=str))


def check_family(spec: SweepSpec, designer: SegmentDesigner) -> None:
    families = designer.families()
    if families is not None and spec.family not in families:
        raise SpecError(f"unknown family {spec.family!r}; known: {', '.join(sorted(families))}",
                        file=spec.source, field="family")


def _plan_task(batch: Batch, designer: SegmentDesigner, raw: Task) -> Task | TaskFailure:
    """The task with canonical parameters, name and key, or the failure that stopped it."""
    task = replace(raw, parameters=_json_ready(raw.parameters))
    try:
        task = replace(task, parameters=dict(designer.canonical(task.family, task.parameters)))
    except TASK_ERRORS as error:
        return TaskFailure.of(task, "validate", error)
    if batch.origin == "sweep":          # a scene's designs were checked when it was read
        plausibility.design(task.parameters, task.options.get("mesh_size"), batch.source,
                            parameters_field=f"task {task.index}: parameters", mesh_field="mesh_size")
    if batch.names is not None:
        task = replace(task, name=batch.names(task))
    try:
        return replace(task, key=designer.key(task))
    except TASK_ERRORS as error:
        return TaskFailure.of(task, "key", error)


def plan_batch(batch: Batch, catalogue, *, store: Callable[[str], SweepStore] = CatalogueStore,
               designer: SegmentDesigner = FiniteElementDesigner()) -> SweepPlan:
    """Validate every task, compute its key, and sort tasks into todo/skipped/duplicate/invalid.

    ``store`` builds the catalogue's :class:`SweepStore` from its absolute path. Raises
    CatalogueError when the catalogue's directory does not exist.
    """
    catalogue = str(catalogue)
    directory = os.path.dirname(os.path.abspath(catalogue))
    if not os.path.isdir(directory):
        raise CatalogueError(f"{catalogue}: directory {directory} does not exist")
    held = store(os.path.abspath(catalogue))
    known = held.keys()
    tasks, todo, skipped, duplicates, invalid = [], [], [], [], []
    first_with_key: dict[str, int] = {}
    for raw in batch.tasks:
        task = _plan_task(batch, designer, raw)
        if isinstance(task, TaskFailure):
            tasks.append(task.task)
            invalid.append(task)
            continue
        tasks.append(task)
        if task.key in first_with_key:
            duplicates.append((task, first_with_key[task.key]))
            continue
        first_with_key[task.key] = task.index
        in_catalogue = task.key in known if known is not None else held.has(task.key)
        (skipped if in_catalogue else todo).append(task)
    return SweepPlan(batch, catalogue, held, designer, tuple(tasks), tuple(todo), tuple(skipped), tuple(duplicates),
                     tuple(invalid))


def plan_sweep(spec: SweepSpec, catalogue, *, store: Callable[[str], SweepStore] = CatalogueStore,
               designer: SegmentDesigner = FiniteElementDesigner()) -> SweepPlan:
    """Plan a sweep spec's tasks (:func:`plan_batch`); an unknown family is a SpecError."""
    check_family(spec, designer)
    return plan_batch(sweep_batch(spec), catalogue, store=store, designer=designer)
