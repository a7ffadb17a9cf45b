"""Shared test set-up: one BLAS/OpenMP thread per process (inherited by the processes tests
start), non-interactive plots."""

import os

from vertebra.designer.threads import pin_blas_threads

pin_blas_threads()
os.environ.setdefault("MPLBACKEND", "Agg")
