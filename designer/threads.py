"""One BLAS/OpenMP thread per process: the single place vertebra pins numerical threads.

Parallel work in vertebra is processes (sweep workers, concurrent designs), each solving
small banded systems or one sparse FE problem; threaded BLAS on top of that only
oversubscribes the cores (docs/designer.md: algebraic multigrid ran 5–25× slower on two
cores with threaded BLAS). The command line, the test suite, the designer and every sweep
worker call :func:`pin_blas_threads`.

Two mechanisms, because each acts on different libraries:

* the environment variables of :data:`THREAD_VARIABLES` are read by OpenBLAS, MKL and the
  OpenMP runtime when they are loaded, and are inherited by every process started later;
* threadpoolctl, the maintained library that knows every BLAS and OpenMP runtime numpy and
  scipy may have loaded (OpenBLAS, MKL, BLIS, libgomp, …), limits the ones already loaded.
"""

from __future__ import annotations

import os

from vertebra.core.processes import THREAD_VARIABLES, thread_environment


_limited: int | None = None           # the limit threadpoolctl applied in this process


def pin_blas_threads(threads: int = 1) -> None:
    """Pin this process and the processes it starts to ``threads`` BLAS/OpenMP threads.

    Sets :data:`THREAD_VARIABLES` (overriding any earlier value) and limits every runtime
    already loaded. Calling it again is cheap (no threadpoolctl scan) while the
    environment still holds the same limit: libraries loaded since then read it.
    """
    global _limited
    environment = thread_environment(threads)
    if _limited == threads and all(os.environ.get(name) == value for name, value in environment.items()):
        return
    from threadpoolctl import threadpool_limits

    os.environ.update(environment)
    threadpool_limits(limits=threads)
    _limited = threads


def blas_threads() -> int | None:
    """Threads the loaded BLAS libraries will use (the largest), ``None`` when none is loaded."""
    from threadpoolctl import threadpool_info

    counts = [pool["num_threads"] for pool in threadpool_info() if pool.get("user_api") == "blas"]
    return max(counts) if counts else None
