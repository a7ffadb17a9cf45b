"""Speed benchmarks of vertebra, run by airspeed velocity (asv; ``asv.conf.json`` at the
repository root, docs/benchmarks.md).

Every module holds asv benchmark classes: ``time_*`` (wall time of one call, asv's statistics
over repeats), ``track_*`` (a number the run reports, e.g. Newton iterations, so that a change in
work is told apart from a change in speed) and ``peakmem_*``. They use only the public API of
``vertebra``, so that ``asv continuous BASE HEAD`` can run them on older commits.

One BLAS/OpenMP thread: the timings measure the code, not the thread pool.
"""

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
