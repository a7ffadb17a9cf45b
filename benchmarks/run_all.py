"""Run every study script (``benchmarks/bench_*.py``) in turn; each prints its tables and
saves them under ``benchmarks/results/``. Usage: ``make bench`` or
``python -m benchmarks.run_all [NAME ...]`` (e.g. ``solver inverse``) from the repository root."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from vertebra.designer.threads import pin_blas_threads

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    scripts = sorted(HERE.glob("bench_*.py"))
    if argv:
        scripts = [s for s in scripts if s.stem.removeprefix("bench_") in argv]
    pin_blas_threads()                      # one BLAS/OpenMP thread: every benchmark inherits it
    env = dict(os.environ, MPLBACKEND="Agg")
    failed = []
    for script in scripts:
        print(f"\n### {script.name}", flush=True)
        start = time.perf_counter()
        code = subprocess.call([sys.executable, "-m", f"benchmarks.{script.stem}"], env=env, cwd=HERE.parent)
        print(f"### {script.name}: exit {code} after {time.perf_counter() - start:.0f} s", flush=True)
        if code:
            failed.append(script.name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
