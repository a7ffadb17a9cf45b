"""Where the tasks of a design-space sweep run: a small Protocol and a registry.

An executor takes a picklable function and a sequence of items and yields
``(item, result)`` pairs as they complete, in any order. The function runs in
worker processes; it is expected to catch its own exceptions and return them as
data (``designer.sweep.execute_task`` does). What the function cannot report
itself — a worker process that died (segfault, out-of-memory kill), an argument
that cannot be pickled, a dask worker lost over and over — the executor yields as
a :class:`Crash` in place of the result, and the other items go on.

Registered executors (``EXECUTORS``):

``serial``
    Runs every item in the calling process, one after the other. For debugging
    and for tests with cheap fake jobs.
``local``
    ``concurrent.futures.ProcessPoolExecutor`` with ``workers`` processes started
    with ``spawn`` (default) or ``forkserver`` — never ``fork``: gmsh keeps global
    state and is not thread-safe, so every worker is a fresh interpreter with one
    gmsh of its own. BLAS/OpenMP threads are pinned to one per worker
    (``designer.threads``).
``dask``
    ``dask.distributed``: ``Client(scheduler)`` when a scheduler address is given
    (a cluster of any size, workers on other machines), otherwise a
    ``LocalCluster`` of ``workers`` single-threaded worker processes.

Adding an executor touches this file only: a class with the :class:`Executor`
attributes, decorated with ``@register_executor("name")``.
"""

from __future__ import annotations

import os
import socket
import sys
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Protocol, runtime_checkable

from vertebra.designer.threads import THREAD_VARIABLES, blas_threads, pin_blas_threads, thread_environment
from vertebra.core.errors import OptionError
from vertebra.core.processes import exit_with_parent

START_METHODS = ("spawn", "forkserver")


def worker_info() -> dict:
    """Who ran a task: host, process id, the thread pinning it saw and the BLAS threads in use."""
    return {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "blas_threads": blas_threads(),
    }


@dataclass(frozen=True)
class Crash:
    """An item the executor could not get a result for (the function never returned)."""

    error_type: str
    message: str

    @classmethod
    def from_exception(cls, error: BaseException, context: str = "") -> "Crash":
        message = str(error) or repr(error)
        return cls(type(error).__name__, f"{context}{message}" if context else message)


@runtime_checkable
class Executor(Protocol):
    """What a sweep needs from an executor."""

    name: str
    workers: int

    def __enter__(self) -> "Executor": ...

    def __exit__(self, *exc_info) -> None: ...

    def map_unordered(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        """Yield ``(item, function(item))`` or ``(item, Crash)`` as items complete."""
        ...

    def describe(self) -> dict:
        """JSON-able description (name, workers, start method or scheduler address)."""
        ...


EXECUTORS: dict[str, type] = {}


def register_executor(name: str):
    def decorate(cls):
        cls.name = name
        EXECUTORS[name] = cls
        return cls
    return decorate


MAX_WORKERS = 1024      # worker processes of one executor (a local pool starts them all)


def make_executor(name: str, *, workers: int | None = None, scheduler: str | None = None,
                  start_method: str = "spawn") -> Executor:
    """Build a registered executor; bad settings raise OptionError naming the option."""
    try:
        cls = EXECUTORS[name]
    except KeyError:
        raise OptionError(f"unknown executor {name!r} (known: {', '.join(sorted(EXECUTORS))})",
                          field="executor") from None
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
        raise OptionError(f"expected a positive integer, got {workers!r}", field="workers")
    if workers is not None and workers > MAX_WORKERS:
        raise OptionError(f"at most {MAX_WORKERS}; got {workers:,}", field="workers")
    return cls(workers=workers, scheduler=scheduler, start_method=start_method)


def _default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def _refuse_scheduler(scheduler: str | None) -> None:
    if scheduler:
        raise OptionError("a scheduler address needs the dask executor", field="scheduler")


@register_executor("serial")
class SerialExecutor:
    """Everything in the calling process, in order. Exceptions escaping the function become Crashes."""

    name = "serial"

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None, start_method: str = "spawn"):
        _refuse_scheduler(scheduler)
        self.workers = 1

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        return None

    def map_unordered(self, function, items):
        for item in items:
            try:
                result = function(item)
            except Exception as error:  # noqa: BLE001 - isolation is the point
                result = Crash.from_exception(error)
            yield item, result

    def describe(self) -> dict:
        return {"name": self.name, "workers": 1}


def terminate_pool(pool) -> None:
    """Stop a ``concurrent.futures.ProcessPoolExecutor`` now: its worker processes are
    terminated (there is no public "terminate": they are in ``_processes``, CPython 3.8-3.13)
    and pending work is cancelled."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def start_worker(owner: int) -> None:
    """Initializer of a local pool's worker processes: they die with ``owner`` (the pid of the
    process that made the pool) and run BLAS single-threaded."""
    exit_with_parent(owner)
    pin_blas_threads()


@register_executor("local")
class LocalExecutor:
    """A process pool on this machine (``concurrent.futures.ProcessPoolExecutor``).

    At most ``2 * workers`` items are in flight. A dead worker (segfault,
    out-of-memory kill) breaks the whole pool and fails every item in flight;
    those items are then re-run one at a time in a fresh pool, so only the item
    that kills its worker alone is reported as ``Crash("WorkerCrashed", ...)``
    and the others complete normally.
    """

    name = "local"

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None, start_method: str = "spawn"):
        _refuse_scheduler(scheduler)
        if start_method not in START_METHODS:
            raise OptionError(f"expected one of {START_METHODS}, got {start_method!r} "
                              "(fork is unsafe with gmsh's global state)", field="start_method")
        self.workers = workers or _default_workers()
        self.start_method = start_method
        self._saved_environment: dict[str, str | None] = {}
        self._pool = None

    def __enter__(self):
        # Spawned workers inherit the parent's environment at start and import numpy
        # while they unpickle their initializer: set it for the executor's lifetime so
        # BLAS loads single-threaded in them. The parent's own BLAS is left alone.
        self._saved_environment = {v: os.environ.get(v) for v in THREAD_VARIABLES}
        os.environ.update(thread_environment())
        return self

    def __exit__(self, exc_type, *exc_info):
        # On an error (Ctrl-C) stop the workers at once instead of waiting for
        # their tasks: the store guarantees a killed writer loses only its own entry.
        self._shutdown(terminate=exc_type is not None)
        for variable, value in self._saved_environment.items():
            if value is None:
                os.environ.pop(variable, None)
            else:
                os.environ[variable] = value
        return None

    def _new_pool(self):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                         mp_context=multiprocessing.get_context(self.start_method),
                                         initializer=start_worker, initargs=(os.getpid(),))
        return self._pool

    def _shutdown(self, terminate: bool = False):
        if self._pool is None:
            return
        if terminate:
            terminate_pool(self._pool)
        else:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None

    def map_unordered(self, function, items):
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        pending = deque(items)
        suspects: deque = deque()        # in flight when a worker died: re-run one at a time
        in_flight: dict = {}             # future -> (item, ran alone)
        limit = 2 * self.workers
        pool = self._pool or self._new_pool()
        while pending or suspects or in_flight:
            broken = False
            try:
                if suspects:
                    if not in_flight:
                        future = pool.submit(function, suspects[0])
                        in_flight[future] = (suspects.popleft(), True)
                else:
                    while pending and len(in_flight) < limit:
                        future = pool.submit(function, pending[0])
                        in_flight[future] = (pending.popleft(), False)
            except BrokenProcessPool:      # the pool broke before we saw its futures fail
                broken = True
            done, _ = wait(list(in_flight), return_when=FIRST_COMPLETED) if in_flight else (set(), set())
            for future in done:
                item, alone = in_flight.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    broken = True
                    if not alone:
                        suspects.append(item)
                        continue
                    result = Crash("WorkerCrashed", self._crash_message())
                except Exception as error:  # noqa: BLE001 - e.g. an unpicklable argument or result
                    result = Crash.from_exception(error)
                yield item, result
            if broken:
                # a broken pool fails every future it holds: all of them become suspects
                for future, (item, alone) in list(in_flight.items()):
                    in_flight.pop(future)
                    if alone:
                        yield item, Crash("WorkerCrashed", self._crash_message())
                    else:
                        suspects.append(item)
                self._pool.shutdown(wait=False, cancel_futures=True)
                pool = self._new_pool()

    def _crash_message(self) -> str:
        """Why a worker that ran a task alone may have died. Worker processes started by
        ``spawn``/``forkserver`` import the main script again: a script that designs at import
        time (no ``if __name__ == "__main__":``) makes every worker fail while it starts."""
        message = ("the worker process died while running this task alone (segmentation fault, "
                   "out-of-memory kill or exit in native code")
        main = sys.modules.get("__main__")
        if self.start_method != "fork" and getattr(main, "__file__", None) and getattr(main, "__spec__", None) is None:
            message += (f"; or, since workers are started with {self.start_method!r}, the script "
                        f"{main.__file__} runs this at import time: put its work under "
                        "`if __name__ == \"__main__\":`")
        return message + ")"

    def describe(self) -> dict:
        return {"name": self.name, "workers": self.workers, "start_method": self.start_method}


@register_executor("dask")
class DaskExecutor:
    """``dask.distributed``: a running cluster (``scheduler`` address) or a LocalCluster.

    The LocalCluster has ``workers`` worker processes with one thread each (gmsh
    is not thread-safe; one gmsh per process). dask's nannies already start
    workers with ``OMP_NUM_THREADS=MKL_NUM_THREADS=OPENBLAS_NUM_THREADS=1``
    (config ``distributed.nanny.pre-spawn-environ``); workers you start
    yourself for a remote cluster should be started the same way
    (``dask worker ADDRESS --nworkers N --nthreads 1``). A task whose worker
    dies is retried on another worker by dask; after
    ``distributed.scheduler.allowed-failures`` deaths it is reported as a Crash.
    """

    name = "dask"

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None, start_method: str = "spawn"):
        self.scheduler = scheduler
        self.workers = workers or (None if scheduler else _default_workers())
        self._client = None
        self._cluster = None

    def __enter__(self):
        import logging

        from dask.distributed import Client, LocalCluster

        if self.scheduler:
            try:
                self._client = Client(self.scheduler, timeout="20s")
            except (OSError, TimeoutError) as error:
                raise OptionError(f"cannot reach dask scheduler {self.scheduler!r}: {error}",
                                  field="scheduler") from None
            # one task at a time per worker *process* (designer.sweep serialises the
            # job inside a process): processes, not threads, are the parallelism
            self.workers = len(self._client.nthreads()) or self.workers
        else:
            self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                         dashboard_address=None, silence_logs=logging.ERROR,
                                         env=thread_environment())
            self._client = Client(self._cluster)
        return self

    def __exit__(self, *exc_info):
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
        return None

    def map_unordered(self, function, items):
        from dask.distributed import as_completed

        items = list(items)
        if not items:
            return
        futures = {}
        for item in items:
            futures[self._client.submit(function, item, pure=False)] = item
        for future in as_completed(list(futures)):
            item = futures.pop(future)
            try:
                result = future.result()
            except Exception as error:  # noqa: BLE001 - KilledWorker, deserialisation errors, ...
                result = Crash.from_exception(error)
            future.release()
            yield item, result

    def describe(self) -> dict:
        description = {"name": self.name, "workers": self.workers}
        if self.scheduler:
            description["scheduler"] = self.scheduler
        return description
