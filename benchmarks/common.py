"""What the study scripts share: where results go, the machine's load, one timing helper, JSON
output and progress messages."""

from __future__ import annotations

import gc
import json
import os
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DOCS = ROOT / "docs"


def loadavg() -> list[float] | None:
    """The 1, 5 and 15 minute load averages, rounded (None where the system has none)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def machine() -> dict:
    """Host, Python, date, cores and load: the record a result file's rows were measured on."""
    import platform
    import socket

    return {"host": socket.gethostname(), "python": platform.python_version(), "date": now(),
            "cores": os.cpu_count(), "load": loadavg()}


def now() -> str:
    """The UTC date and time, ISO 8601 to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def log(message: str) -> None:
    """A progress line on stderr (stdout stays for tables)."""
    print(message, file=sys.stderr, flush=True)


def timed(fn, repeats: int, *, warmup: int = 1, budget_s: float | None = None, samples: bool = False):
    """``(last result, timing)`` of ``fn()`` called ``repeats`` times after ``warmup`` calls,
    with the garbage collector off while timed. With ``budget_s`` the repeat count shrinks
    (to no fewer than 3) so that the calls fit the budget, judged by the last warm-up call.

    The timing holds the median, minimum, maximum and quartiles of the wall time (``*_s``), the
    median CPU time of the process (``cpu_median_s``: worker threads included) and of the
    calling thread (``thread_median_s``: what a shared machine's other jobs inflate least),
    ``repeats`` and, with ``samples``, the wall times themselves (``times_s``)."""
    out, first = None, None
    for _ in range(warmup):
        start = time.perf_counter()
        out = fn()
        first = time.perf_counter() - start
    if budget_s is not None and first:
        repeats = int(max(3, min(repeats, budget_s / max(first, 1e-9))))
    wall, cpu, thread = [], [], []
    enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(repeats):
            c0, t0, w0 = time.process_time(), time.thread_time(), time.perf_counter()
            out = fn()
            wall.append(time.perf_counter() - w0)
            thread.append(time.thread_time() - t0)
            cpu.append(time.process_time() - c0)
    finally:
        if enabled:
            gc.enable()
    wall = np.array(wall)
    timing = {"median_s": float(np.median(wall)), "min_s": float(wall.min()), "max_s": float(wall.max()),
              "q25_s": float(np.percentile(wall, 25)), "q75_s": float(np.percentile(wall, 75)),
              "cpu_median_s": float(np.median(cpu)), "thread_median_s": float(np.median(thread)),
              "repeats": int(repeats)}
    if samples:
        timing["times_s"] = wall.tolist()
    return out, timing


def write_json(document, path: Path) -> Path:
    """``document`` as indented JSON at ``path`` (its folder made; numpy scalars as floats)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1, default=float) + "\n")
    return path
