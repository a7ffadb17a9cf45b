"""Pin BLAS/OpenMP threads to one (FIELD-NOTES: AMG ran 5–25× slower otherwise on 2 cores).

Environment variables act only before numpy is imported, so for an interpreter that already
runs, the limits are set through threadpoolctl, the maintained library that knows every BLAS
and OpenMP runtime numpy/scipy may have loaded (OpenBLAS, MKL, BLIS, libgomp, …).
"""

from __future__ import annotations

import os

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def pin_environment(threads: int = 1) -> None:
    """Set the variables for this process and the processes it starts (unless set)."""
    for name in THREAD_VARIABLES:
        os.environ.setdefault(name, str(threads))


def pin_blas_threads(threads: int = 1) -> int:
    """Limit every loaded BLAS/OpenMP runtime to ``threads``; returns how many were limited."""
    from threadpoolctl import threadpool_info, threadpool_limits
    pin_environment(threads)
    threadpool_limits(limits=threads)
    return len(threadpool_info())


def blas_threads() -> int | None:
    """Threads the loaded BLAS libraries will use (the largest), ``None`` when none is loaded."""
    from threadpoolctl import threadpool_info
    counts = [pool["num_threads"] for pool in threadpool_info() if pool.get("user_api") == "blas"]
    return max(counts) if counts else None
