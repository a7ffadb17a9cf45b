"""Worker processes that die with their owner and run BLAS single-threaded.

Both the designer's pools and the runtime's parallel calibration start worker processes; what
they share lives here (core: nothing of vertebra above it). A worker calls
:func:`exit_with_parent` first, so that a killed parent never leaves it running, and is started
with :func:`thread_environment` in its environment, so that its BLAS and OpenMP runtimes, read
when they load, take one thread each (threaded BLAS on top of processes only oversubscribes the
cores).
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: seconds between two looks of a worker's watchdog at its parent
PARENT_WATCH_S = 0.5


def thread_environment(threads: int = 1) -> dict[str, str]:
    """The environment that starts a process with ``threads`` BLAS/OpenMP threads."""
    return {name: str(threads) for name in THREAD_VARIABLES}


@contextmanager
def pinned_environment(threads: int = 1):
    """Within the block, processes started inherit ``threads`` BLAS/OpenMP threads (the
    environment is restored after)."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(thread_environment(threads))
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def gone(pid: int) -> bool:
    """Has process ``pid`` ended?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:                                           # exists, not ours to signal
        return False
    return False


def exit_with_parent(owner: int) -> None:
    """Make this process die with ``owner``, the process that started it: on Linux the kernel
    sends it SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``); everywhere a daemon
    thread looks every :data:`PARENT_WATCH_S` whether its parent is still the one that started it
    (an orphan is adopted by another process) and ``owner`` still exists, and ends the process at
    once if not. A worker of a killed command would otherwise go on working."""
    import threading

    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)         # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            pass                                               # the watchdog still acts

    def orphaned() -> bool:
        return os.getppid() != parent or gone(owner) or (parent == 1 and owner != 1)

    if orphaned():                                             # the owner died before we started
        os._exit(1)

    def watch():
        import time

        while True:
            time.sleep(PARENT_WATCH_S)
            if orphaned():
                os._exit(1)

    threading.Thread(target=watch, name="vertebra-parent-watchdog", daemon=True).start()
