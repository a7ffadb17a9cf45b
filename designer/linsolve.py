"""Linear solvers for the interior stiffness ``K_ii`` (SPD: both end faces are
eliminated, so the usual rigid-body modes are the near-null space). A registry
of small solver objects with one method, ``solve(A, B, modes) -> (X, info)``.

* ``direct``: SuperLU with a symmetric fill-reducing ordering (small meshes).
* ``amg``: pyamg smoothed aggregation (3×3 blocks, rigid-body near-null space,
  ``coarse_solver='splu'`` — the default ``'pinv'`` cost ~30 s at 34k DoFs,
  FIELD-NOTES — and Chebyshev smoothing) as preconditioner of conjugate
  gradients, one right-hand side at a time.
* ``auto``: ``direct`` below ``AUTO_THRESHOLD`` unknowns, ``amg`` above, and ``direct``
  again when AMG-PCG stalls (more than 150 iterations: thin-walled geometry).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vertebra.store.errors import ConvergenceError, VertebraError

AUTO_THRESHOLD = 12_000     # interior unknowns; measured crossover ~14k (P2 rod), direct 7.8 s at 20k (pneumatic): benchmarks/results/designer.md
AMG_RTOL = 1e-8             # relative residual of each PCG solve (compliance error ~1e-9, far below discretisation)
#: polynomial smoothing: ~2.4× faster than pyamg's default block Gauss–Seidel on a 45k-DoF P2
#: rod here (same iteration count), and symmetric, as PCG requires
AMG_SMOOTHER = ("chebyshev", {"degree": 3})
#: strength threshold: 0.1 (pyamg's default 0) coarsens less aggressively — 3 levels instead of 2,
#: 30 instead of 46 PCG iterations and ~40 % less time on a 45k-unknown P2 pneumatic, ν = 0.45
AMG_STRENGTH = ("symmetric", {"theta": 0.1})


class LinearSolver(Protocol):
    name: str

    def solve(self, A, B: np.ndarray, modes: np.ndarray | None) -> tuple[np.ndarray, dict]: ...


LINEAR_SOLVERS: dict[str, LinearSolver] = {}


def register_solver(cls):
    LINEAR_SOLVERS[cls.name] = cls()
    return cls


@register_solver
@dataclass
class Direct:
    name: str = "direct"

    def solve(self, A, B, modes=None):
        from scipy.sparse.linalg import splu
        lu = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
        X = lu.solve(np.asarray(B, dtype=float))
        return X, {"solver": "direct", "method": "SuperLU (MMD_AT_PLUS_A)", "fill": int(lu.L.nnz + lu.U.nnz)}


@register_solver
@dataclass
class AMG:
    name: str = "amg"
    rtol: float = AMG_RTOL
    maxiter: int = 2000

    def solve(self, A, B, modes=None):
        import pyamg
        from scipy.sparse.linalg import cg
        A = A.tocsr()
        if A.shape[0] % 3:
            raise VertebraError(f"AMG needs 3×3 nodal blocks, got {A.shape[0]} unknowns")
        ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(3, 3)), B=modes, coarse_solver="splu",
                                               max_coarse=500, presmoother=AMG_SMOOTHER,
                                               postsmoother=AMG_SMOOTHER, strength=AMG_STRENGTH)
        M = ml.aspreconditioner()
        B = np.asarray(B, dtype=float)
        X = np.zeros_like(B)
        iterations = []
        for j in range(B.shape[1]):
            count = [0]

            def callback(_x, count=count):
                count[0] += 1

            x, status = cg(A, B[:, j], rtol=self.rtol, atol=0.0, M=M, maxiter=self.maxiter, callback=callback)
            if status != 0:
                raise ConvergenceError(f"AMG-PCG did not reach rtol {self.rtol} in {self.maxiter} iterations "
                                       f"(right-hand side {j})")
            X[:, j] = x
            iterations.append(count[0])
        return X, {"solver": "amg", "method": "pyamg smoothed aggregation + PCG", "rtol": self.rtol,
                   "iterations": iterations, "levels": len(ml.levels)}


@dataclass
class Auto:
    """``direct`` below ``threshold`` unknowns; above it AMG, falling back to ``direct`` when
    AMG-PCG stalls (thin walls — a bellows — made smoothed aggregation need 600–900
    iterations where SuperLU took seconds)."""

    threshold: int = AUTO_THRESHOLD
    amg_maxiter: int = 150
    name: str = "auto"

    def solve(self, A, B, modes=None):
        if A.shape[0] < self.threshold:
            return LINEAR_SOLVERS["direct"].solve(A, B, modes)
        try:
            return AMG(maxiter=self.amg_maxiter).solve(A, B, modes)
        except ConvergenceError as error:
            X, info = LINEAR_SOLVERS["direct"].solve(A, B, modes)
            return X, dict(info, amg_fallback=str(error))


def get_solver(name: str, n_unknowns: int, threshold: int | None = None) -> LinearSolver:
    """The solver registered as ``name``; ``"auto"`` picks by size (see :class:`Auto`)."""
    if name == "auto":
        return Auto(threshold=AUTO_THRESHOLD if threshold is None else threshold)
    if name not in LINEAR_SOLVERS:
        raise VertebraError(f"unknown linear_solver {name!r} (known: auto, {', '.join(LINEAR_SOLVERS)})")
    return LINEAR_SOLVERS[name]
