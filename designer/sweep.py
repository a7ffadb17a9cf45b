"""Design-space sweeps that fill the shared catalogue (docs/sweeps.md).

A sweep spec (TOML) names a geometry family, fixed parameters, mesh settings
and one sampler — ``[grid]``, ``[[list]]`` or ``[lhs]`` — that expands into
tasks. Running a sweep:

1. expand the spec into tasks (``expand``);
2. validate every task with ``designer.canonical_parameters`` and compute its
   content key with ``designer.entry_key`` — no meshing (``plan_sweep``);
   invalid tasks become failures, tasks whose key is already in the catalogue
   are skipped (resume), repeated keys run once;
3. run the rest on an executor (``designer.executors``): each worker designs
   its segment and writes it with ``store.catalogue.add_entry`` itself; the
   parent only tracks outcomes, shows a progress bar (tqdm, stderr) and appends
   failures to a JSON-lines log next to the catalogue (``run_sweep``).

The job is injectable (:class:`SweepBackend`): tests run the same machinery
with a cheap fake job; the default backend is the real designer and store.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import string
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from functools import partial
from pathlib import Path
from typing import Any, Callable

from vertebra.designer.executors import Crash, make_executor, pin_threads, worker_info
from vertebra.store.errors import SceneError, VertebraError

FAILURE_LOG_VERSION = 1
FAILURE_LOG_SUFFIX = ".failures.jsonl"

TOP_LEVEL_FIELDS = ("family", "parameters", "mesh_size", "order", "name", "description",
                    "linear_solver", "estimate_accuracy")
LHS_FIELDS = ("ranges", "samples", "seed", "log", "integer")
LHS_DIGITS = 6                        # significant digits kept of each Latin-hypercube value


# --------------------------------------------------------------------------- spec

@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep specification. ``sampler`` is a key of ``SAMPLERS``."""

    family: str
    parameters: dict
    sampler: str
    design: Any                       # the sampler's validated table
    mesh_size: float | None = None
    order: int = 2
    name: str | None = None           # str.format template over the parameters, index, family
    linear_solver: str = "auto"
    estimate_accuracy: bool = True
    description: str = ""
    source: str = "<dict>"

    def __post_init__(self):
        if self.sampler not in SAMPLERS:
            raise SceneError(f"unknown sampler {self.sampler!r}", file=self.source, field=self.sampler)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _parse_grid(table, source: str) -> dict:
    if not isinstance(table, dict) or not table:
        raise SceneError("expected a table of parameter = [values, ...]", file=source, field="grid")
    for parameter, values in table.items():
        if not isinstance(values, list) or not values:
            raise SceneError(f"expected a non-empty list of values, got {values!r}",
                             file=source, field=f"grid.{parameter}")
    return {parameter: list(values) for parameter, values in table.items()}


def _parse_list(table, source: str) -> list[dict]:
    # ``[[list]]`` (one table per parameter set) or ``[list] sets = [{...}, ...]``
    if isinstance(table, dict):
        unknown = sorted(set(table) - {"sets"})
        if unknown:
            raise SceneError("unknown field (use [[list]] tables or [list] sets = [...])",
                             file=source, field=f"list.{unknown[0]}")
        table = table.get("sets")
    if not isinstance(table, list) or not table:
        raise SceneError("expected a non-empty list of parameter tables", file=source, field="list")
    for i, item in enumerate(table):
        if not isinstance(item, dict) or not item:
            raise SceneError(f"expected a non-empty table of parameters, got {item!r}",
                             file=source, field=f"list[{i}]")
    return [dict(item) for item in table]


@dataclass(frozen=True)
class LatinHypercube:
    """``[lhs]``: ``samples`` points, one per stratum in every dimension (scipy.stats.qmc)."""

    ranges: dict                      # parameter -> (low, high)
    samples: int
    seed: int
    log: tuple = ()                   # parameters sampled uniformly in log space
    integer: tuple = ()               # parameters rounded to the nearest integer


def _parse_lhs(table, source: str) -> LatinHypercube:
    if not isinstance(table, dict):
        raise SceneError("expected a table", file=source, field="lhs")
    for name in table:
        if name not in LHS_FIELDS:
            raise SceneError(f"unknown field (known: {', '.join(LHS_FIELDS)})", file=source, field=f"lhs.{name}")
    for required in ("ranges", "samples", "seed"):
        if required not in table:
            reason = ("required: the same seed gives the same tasks, which resuming relies on"
                      if required == "seed" else "required")
            raise SceneError(reason, file=source, field=f"lhs.{required}")
    ranges = table["ranges"]
    if not isinstance(ranges, dict) or not ranges:
        raise SceneError("expected a table of parameter = [low, high]", file=source, field="lhs.ranges")
    parsed = {}
    for parameter, bounds in ranges.items():
        where = f"lhs.ranges.{parameter}"
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(_is_number(b) for b in bounds)):
            raise SceneError(f"expected [low, high] numbers, got {bounds!r}", file=source, field=where)
        low, high = float(bounds[0]), float(bounds[1])
        if not low < high:
            raise SceneError(f"low {low} must be below high {high}", file=source, field=where)
        parsed[parameter] = (low, high)
    samples, seed = table["samples"], table["seed"]
    if not (isinstance(samples, int) and not isinstance(samples, bool) and samples >= 1):
        raise SceneError(f"expected a positive integer, got {samples!r}", file=source, field="lhs.samples")
    if not (isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0):
        raise SceneError(f"expected a non-negative integer, got {seed!r}", file=source, field="lhs.seed")
    lists = {}
    for option in ("log", "integer"):
        names = table.get(option, [])
        if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
            raise SceneError("expected a list of parameter names", file=source, field=f"lhs.{option}")
        for name in names:
            if name not in parsed:
                raise SceneError(f"{name!r} has no range in lhs.ranges", file=source, field=f"lhs.{option}")
        lists[option] = tuple(names)
    for name in lists["log"]:
        if parsed[name][0] <= 0.0:
            raise SceneError(f"log sampling of {name!r} needs a positive range", file=source, field="lhs.log")
    return LatinHypercube(parsed, samples, seed, lists["log"], lists["integer"])


def _expand_grid(grid: dict) -> list[dict]:
    names = list(grid)
    return [dict(zip(names, values)) for values in itertools.product(*(grid[n] for n in names))]


def _expand_list(sets: list[dict]) -> list[dict]:
    return [dict(item) for item in sets]


def latin_hypercube_unit(dimensions: int, samples: int, seed: int):
    """(samples, dimensions) points in [0, 1): exactly one per stratum [i/n, (i+1)/n) per dimension."""
    from scipy.stats import qmc

    return qmc.LatinHypercube(d=dimensions, rng=seed).random(samples)


def _expand_lhs(lhs: LatinHypercube) -> list[dict]:
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


@dataclass(frozen=True)
class Sampler:
    parse: Callable[[Any, str], Any]
    expand: Callable[[Any], list[dict]]
    varied: Callable[[Any], set]      # the parameter names the sampler sets


SAMPLERS: dict[str, Sampler] = {
    "grid": Sampler(_parse_grid, _expand_grid, lambda grid: set(grid)),
    "list": Sampler(_parse_list, _expand_list, lambda sets: set().union(*(set(s) for s in sets))),
    "lhs": Sampler(_parse_lhs, _expand_lhs, lambda lhs: set(lhs.ranges)),
}


def parse_spec(data: dict, source: str = "<dict>") -> SweepSpec:
    """Validate a sweep spec dictionary; SceneError names the file and the field."""
    if not isinstance(data, dict):
        raise SceneError("a sweep spec is a table", file=source)
    known = set(TOP_LEVEL_FIELDS) | set(SAMPLERS)
    for name in data:
        if name not in known:
            raise SceneError(f"unknown field (known: {', '.join(sorted(known))})", file=source, field=name)
    family = data.get("family")
    if not isinstance(family, str) or not family:
        raise SceneError("required: the geometry family name, e.g. \"rod\"", file=source, field="family")
    parameters = data.get("parameters", {})
    if not isinstance(parameters, dict):
        raise SceneError("expected a table of fixed parameters", file=source, field="parameters")
    samplers = [name for name in SAMPLERS if name in data]
    if len(samplers) != 1:
        raise SceneError(f"exactly one of {', '.join('[' + s + ']' for s in SAMPLERS)} is needed, "
                         f"found {len(samplers)}" + (f" ({', '.join(samplers)})" if samplers else ""),
                         file=source, field=samplers[1] if len(samplers) > 1 else "grid")
    sampler = samplers[0]
    design = SAMPLERS[sampler].parse(data[sampler], source)
    clash = sorted(SAMPLERS[sampler].varied(design) & set(parameters))
    if clash:
        raise SceneError(f"{clash[0]!r} is both fixed in [parameters] and varied by [{sampler}]",
                         file=source, field=f"{sampler}.{clash[0]}")
    mesh_size = data.get("mesh_size")
    if mesh_size is not None and not (_is_number(mesh_size) and mesh_size > 0):
        raise SceneError(f"expected a positive length in metres, got {mesh_size!r}", file=source, field="mesh_size")
    order = data.get("order", 2)
    if order not in (1, 2) or isinstance(order, bool):
        raise SceneError(f"expected 1 or 2, got {order!r}", file=source, field="order")
    name = data.get("name")
    if name is not None:
        if not isinstance(name, str) or not name:
            raise SceneError("expected a non-empty string template", file=source, field="name")
        try:
            list(string.Formatter().parse(name))
        except ValueError as error:
            raise SceneError(f"bad template {name!r}: {error}", file=source, field="name") from None
    linear_solver = data.get("linear_solver", "auto")
    if not isinstance(linear_solver, str):
        raise SceneError(f"expected a string, got {linear_solver!r}", file=source, field="linear_solver")
    estimate_accuracy = data.get("estimate_accuracy", True)
    if not isinstance(estimate_accuracy, bool):
        raise SceneError(f"expected true or false, got {estimate_accuracy!r}", file=source, field="estimate_accuracy")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise SceneError("expected a string", file=source, field="description")
    return SweepSpec(family=family, parameters=dict(parameters), sampler=sampler, design=design,
                     mesh_size=None if mesh_size is None else float(mesh_size), order=int(order), name=name,
                     linear_solver=linear_solver, estimate_accuracy=estimate_accuracy,
                     description=description, source=source)


def load_spec(path) -> SweepSpec:
    """Read and validate a sweep spec TOML file."""
    import tomllib

    path = Path(path)
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise SceneError("file not found", file=str(path)) from None
    except tomllib.TOMLDecodeError as error:
        raise SceneError(f"not valid TOML: {error}", file=str(path)) from None
    return parse_spec(data, source=str(path))


# --------------------------------------------------------------------------- tasks

@dataclass(frozen=True)
class Task:
    """One segment to design. ``parameters`` are canonical once planned; ``key`` is its content key."""

    index: int
    family: str
    parameters: dict
    mesh_size: float | None
    order: int
    name: str | None = None
    key: str | None = None
    linear_solver: str = "auto"
    estimate_accuracy: bool = True


def expand(spec: SweepSpec) -> list[Task]:
    """The spec's tasks in a deterministic order (raw parameters: fixed + sampled)."""
    sampled = SAMPLERS[spec.sampler].expand(spec.design)
    return [Task(index=i, family=spec.family, parameters={**spec.parameters, **values},
                 mesh_size=spec.mesh_size, order=spec.order, linear_solver=spec.linear_solver,
                 estimate_accuracy=spec.estimate_accuracy)
            for i, values in enumerate(sampled)]


def format_name(spec: SweepSpec, task: Task) -> str | None:
    """The task's entry name from the spec's template (``{index}``, ``{family}``, any parameter)."""
    if spec.name is None:
        return None
    try:
        return spec.name.format(index=task.index, family=task.family, **task.parameters)
    except (KeyError, IndexError, ValueError, AttributeError, TypeError) as error:
        raise SceneError(f"template {spec.name!r} cannot be filled for task {task.index}: "
                         f"{type(error).__name__}: {error}", file=spec.source, field="name") from None


# --------------------------------------------------------------------------- backend

def design_job(task: Task):
    """The real job: mesh, solve and condense one segment (``designer.design_segment``)."""
    from vertebra import designer

    return designer.design_segment(task.family, dict(task.parameters), mesh_size=task.mesh_size,
                                   order=task.order, name=task.name, linear_solver=task.linear_solver,
                                   estimate_accuracy=task.estimate_accuracy, progress=None)


def _catalogue_add(path: str, entry) -> str:
    """Commit the entry as a shard (durable and visible to readers at once); the parent
    merges shards into the catalogue file in batches (one rewrite per batch, not per entry:
    a merge rewrites the whole file, so per-entry merges cost O(N²) over a large sweep)."""
    from vertebra.store import catalogue

    return catalogue.add_entry(path, entry, consolidate=False)


def _catalogue_consolidate(path: str) -> None:
    from vertebra.store import catalogue

    catalogue.consolidate(path)


def _catalogue_has(path: str, key: str) -> bool:
    from vertebra.store import catalogue

    return catalogue.has_entry(path, key)


def _catalogue_keys(path: str) -> set | None:
    """Every key of an existing catalogue (file and committed shards) in one read; None: ask per key."""
    from vertebra.store import catalogue
    from vertebra.store.errors import CatalogueError

    if not os.path.exists(path):
        return None                   # only shards, or nothing: has_entry knows how to look
    try:
        with catalogue.open_catalogue(path) as cat:
            return {row["key"] for row in cat.list()}
    except (CatalogueError, OSError):
        return None


def _designer_canonical(family: str, parameters: dict) -> dict:
    from vertebra import designer

    return designer.canonical_parameters(family, parameters)


def _designer_key(task: Task) -> str:
    from vertebra import designer

    return designer.entry_key(task.family, task.parameters, mesh_size=task.mesh_size, order=task.order)


def _designer_families():
    from vertebra import designer

    return list(designer.FAMILIES)


@dataclass(frozen=True)
class SweepBackend:
    """The operations a sweep needs; module-level functions so they pickle to any worker.

    ``job(task) -> SegmentEntry`` and ``store(path, entry) -> key`` run in the
    workers; ``canonical``, ``key`` and ``contains`` run in the parent before
    any work; ``families()`` lists known families (``None``: do not check);
    ``catalogue_keys(path)`` optionally returns every key at once (a set) so
    planning a large sweep does not open the catalogue once per task (``None``
    or a ``None`` result: ``contains`` is asked per key).
    """

    job: Callable = design_job
    store: Callable = _catalogue_add
    contains: Callable = _catalogue_has
    canonical: Callable = _designer_canonical
    key: Callable = _designer_key
    families: Callable | None = _designer_families
    catalogue_keys: Callable | None = _catalogue_keys
    flush: Callable | None = None          # parent: merge committed shards (every FLUSH_EVERY and at the end)


DEFAULT_BACKEND = SweepBackend(flush=_catalogue_consolidate)
FLUSH_EVERY = 25


# --------------------------------------------------------------------------- worker side

@dataclass(frozen=True)
class TaskOutcome:
    """What a worker reports back for one task (plain data, pickles cheaply)."""

    index: int
    key: str | None
    ok: bool
    name: str | None = None
    compliance: list | None = None     # the entry's full compliance, nested lists
    seconds: float = 0.0               # wall time in the worker, design + store
    cpu_seconds: float = 0.0           # CPU time of the worker process meanwhile (contention = seconds - cpu)
    stage: str | None = None           # where it failed: "design" | "store"
    error_type: str | None = None
    message: str | None = None
    traceback: str | None = None
    worker: dict = field(default_factory=dict)


def _short_traceback(limit: int = 4000) -> str:
    text = traceback.format_exc()
    return text if len(text) <= limit else "...\n" + text[-limit:]


# gmsh keeps global state and is not thread-safe: if a worker process runs
# several tasks in threads (a dask worker started with --nthreads > 1), they
# take turns here instead of corrupting each other's model.
_ONE_JOB_PER_PROCESS = threading.Lock()


def execute_task(job: Callable, store: Callable, catalogue: str, task: Task) -> TaskOutcome:
    """Run in a worker: ``entry = job(task)``, then ``store(catalogue, entry)``. Never raises.

    Only ``job`` and ``store`` travel to the workers (pickled), not the whole backend.
    """
    pin_threads()
    start, cpu_start = time.perf_counter(), time.process_time()
    common = {"index": task.index, "worker": worker_info()}
    try:
        with _ONE_JOB_PER_PROCESS:
            entry = job(task)
    except Exception as error:  # noqa: BLE001 - one task's failure must not stop the sweep
        return TaskOutcome(key=task.key, ok=False, seconds=time.perf_counter() - start, stage="design",
                           error_type=type(error).__name__, message=str(error) or repr(error),
                           traceback=_short_traceback(), **common)
    try:
        key = store(catalogue, entry)
    except Exception as error:  # noqa: BLE001
        return TaskOutcome(key=task.key, ok=False, name=getattr(entry, "name", None),
                           seconds=time.perf_counter() - start, stage="store", error_type=type(error).__name__,
                           message=str(error) or repr(error), traceback=_short_traceback(), **common)
    compliance = entry.compliance.tolist()
    seconds = time.perf_counter() - start
    common["cpu_seconds"] = time.process_time() - cpu_start
    if task.key is not None and key != task.key:
        # The entry landed, but under another key than entry_key predicted:
        # resuming could never skip it. That is a bug worth an exit code 1.
        return TaskOutcome(key=key, ok=False, name=entry.name, compliance=compliance, seconds=seconds,
                           stage="store", error_type="KeyMismatch",
                           message=f"entry stored under key {key} but entry_key predicted {task.key}; "
                                   "resuming will not recognise it", **common)
    return TaskOutcome(key=key, ok=True, name=entry.name, compliance=compliance, seconds=seconds, **common)


# --------------------------------------------------------------------------- planning

@dataclass(frozen=True)
class TaskFailure:
    """One failed task, as written to the failure log (one JSON object per line)."""

    index: int
    key: str | None
    family: str
    parameters: dict
    mesh_size: float | None
    order: int
    stage: str                        # "validate" | "key" | "design" | "store" | "worker"
    error_type: str
    message: str
    name: str | None = None
    traceback: str | None = None
    worker: dict = field(default_factory=dict)

    def record(self, spec: SweepSpec, catalogue: str) -> dict:
        return {"version": FAILURE_LOG_VERSION,
                "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "sweep": spec.source, "catalogue": str(catalogue),
                "index": self.index, "key": self.key, "family": self.family, "name": self.name,
                "parameters": self.parameters, "mesh_size": self.mesh_size, "order": self.order,
                "stage": self.stage, "error_type": self.error_type, "message": self.message,
                "traceback": self.traceback, "worker": self.worker}


def _failure(task: Task, stage: str, error_type: str, message: str, **extra) -> TaskFailure:
    return TaskFailure(index=task.index, key=task.key, family=task.family, parameters=task.parameters,
                       mesh_size=task.mesh_size, order=task.order, stage=stage, error_type=error_type,
                       message=message, name=task.name, **extra)


@dataclass(frozen=True)
class SweepPlan:
    """The spec's tasks sorted out before any meshing."""

    spec: SweepSpec
    catalogue: str
    tasks: tuple                      # every task, planned (canonical parameters, key, name)
    todo: tuple                       # tasks to run
    skipped: tuple                    # tasks whose key is already in the catalogue
    duplicates: tuple                 # (task, index of the task with the same key that runs)
    invalid: tuple                    # TaskFailure at stage "validate" or "key"


def _json_ready(parameters: dict) -> dict:
    """Parameters as they will appear in logs: must be JSON (they come from TOML, so they are)."""
    return json.loads(json.dumps(parameters, default=str))


def plan_sweep(spec: SweepSpec, catalogue, *, backend: SweepBackend = DEFAULT_BACKEND) -> SweepPlan:
    """Validate every task, compute its key, and sort tasks into todo/skipped/duplicate/invalid."""
    catalogue = str(catalogue)
    if backend.families is not None:
        families = backend.families()
        if spec.family not in families:
            raise SceneError(f"unknown family {spec.family!r}; known: {', '.join(sorted(families))}",
                             file=spec.source, field="family")
    tasks, todo, skipped, duplicates, invalid = [], [], [], [], []
    first_with_key: dict[str, int] = {}
    known = backend.catalogue_keys(catalogue) if backend.catalogue_keys is not None else None

    def in_catalogue(key: str) -> bool:
        return key in known if known is not None else backend.contains(catalogue, key)

    for raw in expand(spec):
        task = replace(raw, parameters=_json_ready(raw.parameters))
        try:
            task = replace(task, parameters=dict(backend.canonical(task.family, task.parameters)))
        except (VertebraError, ValueError, TypeError, KeyError) as error:
            tasks.append(task)
            invalid.append(_failure(task, "validate", type(error).__name__, str(error) or repr(error)))
            continue
        task = replace(task, name=format_name(spec, task))
        try:
            task = replace(task, key=backend.key(task))
        except (VertebraError, ValueError, TypeError, KeyError) as error:
            tasks.append(task)
            invalid.append(_failure(task, "key", type(error).__name__, str(error) or repr(error)))
            continue
        tasks.append(task)
        if task.key in first_with_key:
            duplicates.append((task, first_with_key[task.key]))
        elif in_catalogue(task.key):   # the store also sees committed, unmerged shards
            first_with_key[task.key] = task.index
            skipped.append(task)
        else:
            first_with_key[task.key] = task.index
            todo.append(task)
    return SweepPlan(spec, catalogue, tuple(tasks), tuple(todo), tuple(skipped), tuple(duplicates), tuple(invalid))


# --------------------------------------------------------------------------- running

def failure_log_path(catalogue) -> Path:
    """``<catalogue>.failures.jsonl``, next to the catalogue."""
    catalogue = Path(catalogue)
    return catalogue.with_name(catalogue.name + FAILURE_LOG_SUFFIX)


def append_failures(path: Path, records: list[dict]) -> None:
    """Append JSON lines under a file lock (several sweeps may share a catalogue)."""
    if not records:
        return
    from filelock import FileLock

    text = "".join(json.dumps(record, sort_keys=True, default=str) + "\n" for record in records)
    with FileLock(str(path) + ".lock"):
        with open(path, "a", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())


@dataclass(frozen=True)
class SweepReport:
    """What a sweep did. ``exit_code`` is 1 when any task failed, 0 otherwise."""

    spec: SweepSpec
    catalogue: str
    executor: dict
    tasks: tuple
    completed: tuple                  # TaskOutcome with ok=True
    skipped: tuple                    # Task already in the catalogue
    duplicates: tuple                 # (Task, index of the task that ran for its key)
    failures: tuple                   # TaskFailure
    elapsed_s: float
    dry_run: bool = False
    failure_log: str | None = None
    todo: tuple = ()                  # the tasks that were (or, for a dry run, would be) run
    interrupted: bool = False         # stopped by Ctrl-C before every task had run

    @property
    def exit_code(self) -> int:
        """0 all done; 1 some task failed; 130 interrupted (like a shell's Ctrl-C)."""
        if self.interrupted:
            return 130
        return 1 if self.failures else 0

    @property
    def entries_per_minute(self) -> float | None:
        if self.dry_run or not self.completed or self.elapsed_s <= 0:
            return None
        return 60.0 * len(self.completed) / self.elapsed_s

    def status(self) -> list[dict]:
        """One row per task: index, key, name, status, parameters (and seconds when run)."""
        outcome = {o.index: o for o in self.completed}
        failed = {f.index: f for f in self.failures}
        skipped = {t.index for t in self.skipped}
        duplicate_of = {t.index: i for t, i in self.duplicates}
        todo = {t.index for t in self.todo}
        rows = []
        for task in self.tasks:
            row = {"index": task.index, "key": task.key, "name": task.name, "parameters": task.parameters}
            if task.index in failed:
                row["status"] = "failed"
            elif task.index in skipped:
                row["status"] = "skipped"
            elif task.index in duplicate_of:
                row.update(status="duplicate", duplicate_of=duplicate_of[task.index])
            elif task.index in outcome:
                row.update(status="done", key=outcome[task.index].key, name=outcome[task.index].name,
                           seconds=outcome[task.index].seconds)
            elif task.index in todo:
                row["status"] = "planned" if self.dry_run else "not run"
            rows.append(row)
        return rows

    def to_json(self) -> dict:
        return {
            "spec": self.spec.source, "family": self.spec.family, "sampler": self.spec.sampler,
            "catalogue": self.catalogue, "executor": self.executor, "dry_run": self.dry_run,
            "tasks": len(self.tasks), "completed": len(self.completed), "skipped": len(self.skipped),
            "duplicates": len(self.duplicates), "failed": len(self.failures),
            "planned": len(self.todo) if self.dry_run else None, "interrupted": self.interrupted,
            "entries": self.status(),
            "failures": [{"index": f.index, "key": f.key, "parameters": f.parameters, "stage": f.stage,
                          "error_type": f.error_type, "message": f.message} for f in self.failures],
            "failure_log": self.failure_log,
            "timing": {"total_s": self.elapsed_s, "entries_per_minute": self.entries_per_minute},
        }

    def summary(self) -> str:
        head = "dry run" if self.dry_run else "sweep"
        lines = [f"{head} {self.spec.source}: {len(self.tasks)} tasks, "
                 + (f"{len(self.todo)} to run, " if self.dry_run else f"{len(self.completed)} done, ")
                 + f"{len(self.skipped)} already in {self.catalogue}, {len(self.duplicates)} duplicates, "
                 f"{len(self.failures)} failed"]
        if self.interrupted:
            not_run = sum(1 for row in self.status() if row.get("status") == "not run")
            lines.append(f"  interrupted: {not_run} tasks not run; run the same command again to resume")
        if self.entries_per_minute is not None:
            lines.append(f"  {self.elapsed_s:.1f} s, {self.entries_per_minute:.2f} entries/min "
                         f"({self.executor.get('name')}, {self.executor.get('workers')} workers)")
        for f in self.failures:
            lines.append(f"  failed task {f.index} [{f.stage}] {f.error_type}: {f.message}")
        if self.failures and self.failure_log:
            lines.append(f"  failures logged to {self.failure_log}")
        return "\n".join(lines)


def _outcome_failure(task: Task, result) -> TaskFailure:
    if isinstance(result, Crash):
        return _failure(task, "worker", result.error_type, result.message)
    return _failure(replace(task, key=result.key or task.key, name=result.name or task.name),
                    result.stage or "design", result.error_type or "Error", result.message or "",
                    traceback=result.traceback, worker=result.worker)


def _flush(backend: SweepBackend, catalogue) -> None:
    """Merge the shards the workers committed; a failure leaves them committed (readers see
    shards; ``vertebra catalogue consolidate`` merges them later) and is only logged."""
    if backend.flush is None:
        return
    try:
        backend.flush(os.path.abspath(catalogue))
    except Exception as error:   # noqa: BLE001 — entries are safe as shards whatever happened
        print(f"sweep: merging shards into {catalogue} failed ({type(error).__name__}: {error}); "
              "entries stay committed as shards", file=sys.stderr)


def run_sweep(spec: SweepSpec | str | os.PathLike, catalogue, *, executor: str = "local",
              workers: int | None = None, scheduler: str | None = None, start_method: str = "spawn",
              backend: SweepBackend = DEFAULT_BACKEND, progress: bool = True,
              dry_run: bool = False) -> SweepReport:
    """Plan and run a sweep; failures are isolated, logged and counted, never raised.

    Raises SceneError for a bad spec or executor settings (before any work) and
    CatalogueError when the catalogue's directory does not exist.
    """
    from vertebra.store.errors import CatalogueError

    start = time.perf_counter()
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    catalogue = str(catalogue)
    directory = os.path.dirname(os.path.abspath(catalogue))
    if not os.path.isdir(directory):
        raise CatalogueError(f"{catalogue}: directory {directory} does not exist")
    plan = plan_sweep(spec, catalogue, backend=backend)
    log_path = failure_log_path(catalogue)
    failures = list(plan.invalid)
    completed = []
    interrupted = False
    pool = make_executor(executor, workers=workers, scheduler=scheduler, start_method=start_method)
    if dry_run:
        return SweepReport(spec, catalogue, pool.describe(), plan.tasks, (), plan.skipped, plan.duplicates,
                           tuple(failures), time.perf_counter() - start, dry_run=True, todo=plan.todo)
    append_failures(log_path, [f.record(spec, catalogue) for f in plan.invalid])
    if plan.todo:
        from tqdm import tqdm

        by_index = {task.index: task for task in plan.todo}
        bar = tqdm(total=len(plan.todo), file=sys.stderr, unit="entry", desc=f"sweep {spec.family}",
                   disable=not progress, dynamic_ncols=True)
        try:
            with pool:
                # absolute: dask workers may run in another directory (or on another
                # machine that mounts the same shared filesystem at the same path)
                function = partial(execute_task, backend.job, backend.store, os.path.abspath(catalogue))
                for task, result in pool.map_unordered(function, plan.todo):
                    task = by_index[task.index]
                    if isinstance(result, TaskOutcome) and result.ok:
                        completed.append(result)
                        if len(completed) % FLUSH_EVERY == 0:
                            _flush(backend, catalogue)
                    else:
                        failure = _outcome_failure(task, result)
                        failures.append(failure)
                        append_failures(log_path, [failure.record(spec, catalogue)])
                        bar.set_postfix(failed=len(failures) - len(plan.invalid), refresh=False)
                    bar.update(1)
        except KeyboardInterrupt:
            # Ctrl-C: the executor has stopped its workers (a killed writer loses only
            # its own unfinished entry); what landed stays, a re-run resumes.
            interrupted = True
        finally:
            bar.close()
            if completed:
                _flush(backend, catalogue)
    description = pool.describe()
    return SweepReport(spec, catalogue, description, plan.tasks, tuple(sorted(completed, key=lambda o: o.index)),
                       plan.skipped, plan.duplicates, tuple(sorted(failures, key=lambda f: f.index)),
                       time.perf_counter() - start, failure_log=str(log_path) if failures else None,
                       todo=plan.todo, interrupted=interrupted)
