"""What runs in a worker process: design one task, commit its entry, report back.

:func:`execute_task` never raises: a task's failure comes back as a
:class:`TaskOutcome` naming the stage (``design`` or ``store``), so one bad task cannot
stop a sweep. Only the designer and the store travel to the workers (pickled).
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass, field

from vertebra.designer.executors import worker_info
from vertebra.designer.sweep.store import SweepStore
from vertebra.designer.sweep.tasks import SegmentDesigner, Task
from vertebra.designer.threads import pin_blas_threads

TRACEBACK_CHARACTERS = 4000           # the end of a worker traceback kept in the failure log


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


def _short_traceback(limit: int = TRACEBACK_CHARACTERS) -> str:
    text = traceback.format_exc()
    return text if len(text) <= limit else "...\n" + text[-limit:]


# gmsh keeps global state and is not thread-safe: if a worker process runs
# several tasks in threads (a dask worker started with --nthreads > 1), they
# take turns here instead of corrupting each other's model.
_ONE_JOB_PER_PROCESS = threading.Lock()


def execute_task(designer: SegmentDesigner, store: SweepStore, task: Task) -> TaskOutcome:
    """Run in a worker: ``entry = designer.design(task)``, then ``store.add(entry)``. Never raises."""
    pin_blas_threads()
    start, cpu_start = time.perf_counter(), time.process_time()
    common = {"index": task.index, "worker": worker_info()}

    def failed(stage: str, error: Exception, name: str | None = None) -> TaskOutcome:
        return TaskOutcome(key=task.key, ok=False, name=name, seconds=time.perf_counter() - start, stage=stage,
                           error_type=type(error).__name__, message=str(error) or repr(error),
                           traceback=_short_traceback(), **common)

    try:
        with _ONE_JOB_PER_PROCESS:
            entry = designer.design(task)
    except Exception as error:  # noqa: BLE001 - one task's failure must not stop the sweep
        return failed("design", error)
    try:
        key = store.add(entry)
    except Exception as error:  # noqa: BLE001
        return failed("store", error, getattr(entry, "name", None))
    compliance = entry.compliance.tolist()
    seconds = time.perf_counter() - start
    common["cpu_seconds"] = time.process_time() - cpu_start
    if task.key is not None and key != task.key:
        # The entry landed, but under another key than the designer predicted:
        # resuming could never skip it. That is a bug worth an exit code 1.
        return TaskOutcome(key=key, ok=False, name=entry.name, compliance=compliance, seconds=seconds,
                           stage="store", error_type="KeyMismatch",
                           message=f"entry stored under key {key} but entry_key predicted {task.key}; "
                                   "resuming will not recognise it", **common)
    return TaskOutcome(key=key, ok=True, name=entry.name, compliance=compliance, seconds=seconds, **common)
