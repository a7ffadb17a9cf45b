"""What a run reports: failed tasks, the failure log and the summary of a run.

Failures are appended, as they happen, to a JSON-lines log next to the catalogue
(``<catalogue>.failures.jsonl``, one object per failed task, under a file lock so several
sweeps may share a catalogue). :class:`SweepReport` is what ``run_sweep`` returns: counts,
one status row per task, a one-screen summary and the JSON document of ``--json``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from vertebra.designer.sweep.tasks import Batch, Task
from vertebra.store import locking

FAILURE_LOG_VERSION = 1
FAILURE_LOG_SUFFIX = ".failures.jsonl"


@dataclass(frozen=True)
class TaskFailure:
    """One failed task, as written to the failure log (one JSON object per line)."""

    task: Task                        # canonical parameters when validation passed, raw otherwise
    stage: str                        # "validate" | "key" | "design" | "store" | "worker"
    error_type: str
    message: str
    traceback: str | None = None
    worker: dict = field(default_factory=dict)

    @classmethod
    def of(cls, task: Task, stage: str, error: BaseException) -> "TaskFailure":
        return cls(task, stage, type(error).__name__, str(error) or repr(error))

    @property
    def index(self) -> int:
        return self.task.index

    def record(self, batch: Batch, catalogue: str) -> dict:
        """The failure log's line; ``batch.origin`` names its source field (``sweep``, ``scene``)."""
        task = self.task
        return {"version": FAILURE_LOG_VERSION,
                "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                batch.origin: batch.source, "catalogue": str(catalogue),
                "index": task.index, "key": task.key, "family": task.family, "name": task.name,
                "parameters": task.parameters, **task.key_options,
                "stage": self.stage, "error_type": self.error_type, "message": self.message,
                "traceback": self.traceback, "worker": self.worker}


#: seconds a sweep waits for another one appending to the same failure log
FAILURE_LOG_LOCK_TIMEOUT_S = 600.0


def failure_log_path(catalogue) -> Path:
    """``<catalogue>.failures.jsonl``, next to the catalogue."""
    catalogue = Path(catalogue)
    return catalogue.with_name(catalogue.name + FAILURE_LOG_SUFFIX)


def append_failures(path: Path, records: list[dict]) -> None:
    """Append JSON lines under a file lock (several sweeps may share a catalogue)."""
    if not records:
        return
    text = "".join(json.dumps(record, sort_keys=True, default=str) + "\n" for record in records)
    with locking.locked(Path(str(path) + ".lock"), FAILURE_LOG_LOCK_TIMEOUT_S):
        with open(path, "a", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())


@dataclass(frozen=True)
class SweepReport:
    """What a run of a batch (a sweep, a scene's designs) did. ``exit_code`` is 1 when any task
    failed, 0 otherwise."""

    batch: Batch
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
            **self.batch.describe,
            "catalogue": self.catalogue, "executor": self.executor, "dry_run": self.dry_run,
            "tasks": len(self.tasks), "completed": len(self.completed), "skipped": len(self.skipped),
            "duplicates": len(self.duplicates), "failed": len(self.failures),
            "planned": len(self.todo) if self.dry_run else None, "interrupted": self.interrupted,
            "entries": self.status(),
            "failures": [{"index": f.index, "key": f.task.key, "parameters": f.task.parameters, "stage": f.stage,
                          "error_type": f.error_type, "message": f.message} for f in self.failures],
            "failure_log": self.failure_log,
            "timing": {"total_s": self.elapsed_s, "entries_per_minute": self.entries_per_minute},
        }

    def summary(self) -> str:
        head = "dry run" if self.dry_run else self.batch.origin
        lines = [f"{head} {self.batch.source}: {len(self.tasks)} tasks, "
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
