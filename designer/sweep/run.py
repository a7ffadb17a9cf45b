"""The run loop: hand a plan's tasks to an executor, collect outcomes, merge, report.

One loop for every batch of tasks: a sweep (:func:`run_sweep`) and the design segments of a
scene (``designer.prepare``) both come here through :func:`run_plan`.

Workers commit their own entries; the parent tracks outcomes, shows a progress bar
(tqdm, on stderr), appends each failure to the failure log as it happens, and merges the
committed entries every :data:`MERGE_EVERY` entries and at the end. Ctrl-C stops the
workers; what landed stays and a re-run resumes.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from functools import partial
from typing import Callable

from vertebra.designer.executors import Crash, make_executor
from vertebra.designer.sweep.plan import SweepPlan, plan_sweep
from vertebra.designer.sweep.report import SweepReport, TaskFailure, append_failures, failure_log_path
from vertebra.designer.sweep.spec import SweepSpec, load_spec
from vertebra.designer.sweep.store import CatalogueStore, SweepStore
from vertebra.designer.sweep.tasks import FiniteElementDesigner, SegmentDesigner, Task
from vertebra.designer.sweep.worker import TaskOutcome, execute_task

MERGE_EVERY = 25                      # entries between two merges of the committed entries


def _outcome_failure(task: Task, result: TaskOutcome | Crash) -> TaskFailure:
    if isinstance(result, Crash):
        return TaskFailure(task, "worker", result.error_type, result.message)
    return TaskFailure(replace(task, key=result.key or task.key, name=result.name or task.name),
                       result.stage or "design", result.error_type or "Error", result.message or "",
                       traceback=result.traceback, worker=result.worker)


def _merge(store: SweepStore, catalogue: str) -> None:
    """Merge what the workers committed; a failure leaves the entries committed (readers see
    them; ``vertebra catalogue consolidate`` merges them later) and is only logged."""
    try:
        store.consolidate()
    except Exception as error:   # noqa: BLE001 - entries are safe as committed whatever happened
        print(f"merging shards into {catalogue} failed ({type(error).__name__}: {error}); "
              "entries stay committed as shards", file=sys.stderr)


def run_sweep(spec: SweepSpec | str | os.PathLike, catalogue, *, executor: str = "local",
              workers: int | None = None, scheduler: str | None = None, start_method: str = "spawn",
              store: Callable[[str], SweepStore] = CatalogueStore,
              designer: SegmentDesigner = FiniteElementDesigner(), progress: bool = True,
              dry_run: bool = False) -> SweepReport:
    """Plan and run a sweep; failures are isolated, logged and counted, never raised.

    Raises SpecError for a bad spec, OptionError for bad executor settings (both before
    any work) and CatalogueError when the catalogue's directory does not exist.
    ``store`` builds the catalogue's store from its absolute path; ``designer`` designs
    the entries (both travel to the workers).
    """
    start = time.perf_counter()
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    plan = plan_sweep(spec, catalogue, store=store, designer=designer)
    return run_plan(plan, executor=executor, workers=workers, scheduler=scheduler, start_method=start_method,
                    progress=progress, dry_run=dry_run, started=start)


def run_plan(plan: SweepPlan, *, executor: str = "local", workers: int | None = None, scheduler: str | None = None,
             start_method: str = "spawn", progress: bool = True, dry_run: bool = False,
             started: float | None = None) -> SweepReport:
    """Design a plan's tasks to run on an executor; failures are isolated, logged and counted,
    never raised. OptionError for bad executor settings (before any work). ``started``: the
    ``time.perf_counter()`` the report's elapsed time counts from (default: now)."""
    start = time.perf_counter() if started is None else started
    batch, catalogue = plan.batch, plan.catalogue
    pool = make_executor(executor, workers=workers, scheduler=scheduler, start_method=start_method)
    failures, completed, interrupted = list(plan.invalid), [], False
    if dry_run:
        return SweepReport(batch, catalogue, pool.describe(), plan.tasks, (), plan.skipped, plan.duplicates,
                           tuple(failures), time.perf_counter() - start, dry_run=True, todo=plan.todo)
    log_path = failure_log_path(catalogue)
    append_failures(log_path, [f.record(batch, catalogue) for f in plan.invalid])
    if plan.todo:
        from tqdm import tqdm

        by_index = {task.index: task for task in plan.todo}
        bar = tqdm(total=len(plan.todo), file=sys.stderr, unit="entry", desc=batch.label,
                   disable=not progress, dynamic_ncols=True)
        try:
            with pool:
                for task, result in pool.map_unordered(partial(execute_task, plan.designer, plan.store), plan.todo):
                    task = by_index[task.index]
                    if isinstance(result, TaskOutcome) and result.ok:
                        completed.append(result)
                        if len(completed) % MERGE_EVERY == 0:
                            _merge(plan.store, catalogue)
                    else:
                        failures.append(_outcome_failure(task, result))
                        append_failures(log_path, [failures[-1].record(batch, catalogue)])
                        bar.set_postfix(failed=len(failures) - len(plan.invalid), refresh=False)
                    bar.update(1)
        except KeyboardInterrupt:
            # Ctrl-C: the executor has stopped its workers (a killed writer loses only
            # its own unfinished entry); what landed stays, a re-run resumes.
            interrupted = True
        finally:
            bar.close()
            if completed:
                _merge(plan.store, catalogue)
    return SweepReport(batch, catalogue, pool.describe(), plan.tasks, tuple(sorted(completed, key=lambda o: o.index)),
                       plan.skipped, plan.duplicates, tuple(sorted(failures, key=lambda f: f.index)),
                       time.perf_counter() - start, failure_log=str(log_path) if failures else None,
                       todo=plan.todo, interrupted=interrupted)
