"""Preparing a scene of design segments: what a first run, a second run and a range estimate cost.

On ``gallery:cbha_design`` (16 coarse P2 ``tapered_pneumatic`` slices, no accuracy estimate):

1. **First run** into a fresh catalogue, serial and with the local pool of 2 workers: wall time
   from the call to the report, entries designed, entries per minute.
2. **Second run** on the filled catalogue: planning only (validate, key, look up; nothing is
   designed), the time until the resolved scene is returned.
3. **Range estimate** for nonlinear entries (``designer.scene_range.estimate_ranges``): the 64
   pressure corners of the six chambers and the forward actuation, solved with the linear
   entries; time per solve.

The machine is shared (2 cores, other work running): the load average is recorded next to the
numbers. Results: benchmarks/results/prepare.json and .md.

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.bench_prepare
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from pathlib import Path

from benchmarks import render
from benchmarks.common import loadavg, now
from vertebra import solver
from vertebra.designer import prepare
from vertebra.designer.scene_range import estimate_ranges

SCENE = "gallery:cbha_design"


def first_and_second_run(executor: str, workers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        catalogue = Path(tmp) / "cbha.h5"
        load = loadavg()[0]
        start = time.perf_counter()
        _, report = prepare(solver.load_scene(SCENE), catalogue, executor=executor, workers=workers,
                            estimate_accuracy=False, progress=False)
        first = time.perf_counter() - start
        assert report.exit_code == 0 and len(report.designed) == 16, report.summary()
        start = time.perf_counter()
        resolved, again = prepare(solver.load_scene(SCENE), catalogue, executor=executor, workers=workers,
                                  progress=False)
        second = time.perf_counter() - start
        assert again.designed == [] and len(again.reused) == 16
        start = time.perf_counter()
        estimate = estimate_ranges(solver.build_model(resolved))
        ranges = time.perf_counter() - start
    return {"date": now(), "host": platform.node(), "cpus": os.cpu_count(), "executor": executor, "workers": workers, "loadavg": load, "first_s": first,
            "entries_per_minute": 60.0 * 16 / first, "second_s": second, "ranges_s": ranges,
            "range_solves": len(estimate.actuations), "range_failed": len(estimate.failed)}


def main() -> int:
    rows = [first_and_second_run("serial", 1), first_and_second_run("local", 2)]
    print(render.markdown("prepare", rows))
    render.write("prepare", rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
