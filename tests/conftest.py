"""Shared test set-up: one BLAS/OpenMP thread per process (inherited by the processes tests
start), non-interactive plots, and the same import path under ``pytest`` and ``python -m pytest``.

``python -m pytest`` puts the working directory first on ``sys.path``; from the repository root
that makes its folders importable as bare top-level packages (``solver``, ``store``, … — a second
copy of vertebra's modules, which the installed package never has). Plain ``pytest`` does not:
the root is taken off ``sys.path`` here so that both run the same tests on the same modules
(``tests/`` itself stays on it, where pytest puts it, for the helpers and ``reference/``).
"""

import os
import sys
from pathlib import Path

from vertebra.designer.threads import pin_blas_threads

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [entry for entry in sys.path if Path(entry or os.curdir).resolve() != ROOT]

pin_blas_threads()
os.environ.setdefault("MPLBACKEND", "Agg")
