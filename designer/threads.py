"""Pin BLAS/OpenMP threads to one (FIELD-NOTES: AMG ran 5–25× slower otherwise on 2 cores).

Environment variables only act before numpy is imported, so for an already
running interpreter we also call the ``*openblas_set_num_threads*`` entry point
of every OpenBLAS that is loaded (what threadpoolctl does, which is not a
dependency here). Best effort: never raises.
"""

from __future__ import annotations

import ctypes
import os

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def pin_environment(threads: int = 1) -> None:
    """Set the variables for this process and the processes it starts (unless set)."""
    for name in THREAD_VARIABLES:
        os.environ.setdefault(name, str(threads))


def pin_blas_threads(threads: int = 1) -> int:
    """Limit every loaded OpenBLAS to ``threads``; returns how many libraries were pinned."""
    pin_environment(threads)
    pinned = 0
    try:
        with open("/proc/self/maps") as maps:
            fields = [line.split() for line in maps]
        paths = {f[-1] for f in fields if len(f) >= 6 and "openblas" in f[-1].lower() and ".so" in f[-1]}
    except OSError:
        return 0
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for symbol in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                       "openblas_set_num_threads64_", "openblas_set_num_threads"):
            function = getattr(lib, symbol, None)
            if function is not None:
                function(ctypes.c_int(threads))
                pinned += 1
                break
    return pinned
