"""Solves with a sequence of nearby symmetric matrices (Newton tangents of one segment),
reusing one factorization as long as it stays a good preconditioner.

A factorization (SuperLU, or a pyamg hierarchy for large meshes, :mod:`vertebra.designer.linsolve`)
costs as much as tens of solves with it, and consecutive Newton tangents — within a
load step, and between neighbouring poses of a continuation — differ little. So each
solve runs conjugate gradients preconditioned with the last factor, all right-hand
sides advancing together (one factor application per iteration for the block); when
that does not converge within its budget, or meets negative curvature, the current
matrix is factored afresh. The budget is the time of the last factorization: the
iterations allowed are those whose factor applications (timed as they run) cost
less than refactoring would. A solve that the last one's convergence rate says cannot
reach its tolerance within the budget refactors at once instead of trying (the
condensed-tangent solves — ten right-hand sides, so a budget of a few iterations —
otherwise spend it and refactor anyway). With a fresh direct factor the solve is exact
up to iterative refinement, also for indefinite matrices.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.designer.linsolve import AMG, Direct
from vertebra.core.errors import ConvergenceError, VertebraError

#: interior unknowns above which "auto" uses AMG: a reused SuperLU factor beat AMG-CG per pose by 1.6× at
#: 10k DoFs and 2.5× at 20k (P2 rod, benchmarks/results/nonlinear_fe.md) and 3.9× at 47k (CPU 8.5 s
#: against 33 s for a 0.2 rad bend, factor 20 s, 2.3 GB resident); at 97k the factor takes 120 s and
#: 6.4 GB per process, a pose 27 s. Higher than the linear designer's threshold because one factor
#: serves many tangents here; the bound is the factor's memory (one per worker), not its speed
AUTO_THRESHOLD = 60_000
#: fewest and most preconditioned-CG iterations before refactoring (within them, the timed budget)
MIN_ITERATIONS, MAX_ITERATIONS = 3, 60
#: SuperLU diagonal pivot threshold: small, so symmetric matrices keep perm_r == perm_c (inertia known)
PIVOT_THRESHOLD = 1e-3


def _direct():
    return Direct(diag_pivot_thresh=PIVOT_THRESHOLD)


@dataclass
class ReusedFactorSolver:
    """``solve(A, B, rtol)`` for successive symmetric matrices ``A`` (see the module docstring).

    ``method``: "direct", "amg" or "auto" (direct below ``threshold`` unknowns)."""

    method: str = "auto"
    threshold: int = AUTO_THRESHOLD
    modes: np.ndarray | None = None
    factor: object = None
    kind: str = ""                          # "direct" or "amg": the kind of the current factor
    fresh: bool = False                     # the factor is of the matrix of the last solve
    stats: dict = field(default_factory=lambda: {"factorizations": 0, "krylov_iterations": 0, "solves": 0})
    last_info: dict = field(default_factory=dict)
    factor_time: float = 0.0                # seconds of the last factorization
    apply_time: float = 0.0                 # seconds per right-hand side of one factor application
    rate: float = 0.0                       # residual reduction per iteration of the last preconditioned CG

    def __post_init__(self):
        if self.method not in ("auto", "direct", "amg"):
            raise VertebraError(f"unknown linear_solver {self.method!r} (known: auto, direct, amg)")

    def _kind(self, n: int) -> str:
        if self.method == "auto":
            return "direct" if n < self.threshold else "amg"
        return self.method

    def refactor(self, A) -> dict:
        kind = self._kind(A.shape[0])
        solver = _direct() if kind == "direct" else AMG()
        start = time.perf_counter()
        self.factor = solver.factor(A, self.modes)
        self.factor_time = time.perf_counter() - start
        self.kind = kind
        self.fresh = True
        self.rate = 0.0
        self.stats["factorizations"] += 1
        return self.factor.info

    def solve(self, A, B: np.ndarray, rtol: float = 1e-10) -> tuple[np.ndarray, dict]:
        """``X`` with ``‖A X − B‖ ≤ rtol ‖B‖`` per column; info: iterations, refactored, negative_pivots."""
        B = np.asarray(B, dtype=float)
        single = B.ndim == 1
        B2 = B.reshape(B.shape[0], -1)
        self.stats["solves"] += 1
        refactored = False
        if self.factor is None:
            self.refactor(A)
            refactored = True
        else:
            self.fresh = False
        per_iteration = self.apply_time * B2.shape[1]
        maxit = MAX_ITERATIONS if per_iteration <= 0 else int(self.factor_time / per_iteration)
        maxit = min(max(maxit, MIN_ITERATIONS), MAX_ITERATIONS)
        if (not refactored and self.kind == "direct" and 0.0 < self.rate < 1.0
                and math.log(rtol) / math.log(self.rate) > maxit):
            self.refactor(A)                # the stale factor would not make it: do not try (a fresh one is exact)
            refactored = True
        X, iterations, ok = self._iterate(A, B2, rtol, maxit)
        if not ok and not refactored:
            self.refactor(A)
            refactored = True
            X, more, ok = self._iterate(A, B2, rtol, maxit)
            iterations += more
        if not ok:
            if self.kind == "amg":          # AMG stalled on a fresh hierarchy (thin walls, indefinite): direct
                self.factor = _direct().factor(A, self.modes)
                self.kind = "direct"
                self.stats["factorizations"] += 1
                X, more, ok = self._iterate(A, B2, rtol, maxit)
                iterations += more
            if not ok:
                raise ConvergenceError(f"linear solve with the tangent stiffness did not reach rtol {rtol:g} "
                                       f"with a fresh factor (singular tangent?)")
        self.stats["krylov_iterations"] += iterations
        info = {"iterations": iterations, "refactored": refactored, "method": self.kind}
        if refactored and "negative_pivots" in self.factor.info:
            info["negative_pivots"] = self.factor.info["negative_pivots"]
        self.last_info = info
        return (X[:, 0] if single else X), info

    def _iterate(self, A, B, rtol, maxit):
        """Refinement (fresh direct factor) or block PCG with the current factor as preconditioner."""
        def M(R):
            start = time.perf_counter()
            out = self.factor.apply(R)
            self.apply_time = (time.perf_counter() - start) / R.reshape(R.shape[0], -1).shape[1]
            return out

        bnorm = np.linalg.norm(B, axis=0)
        target = rtol * bnorm
        X = M(B).reshape(B.shape)
        R = B - A @ X
        done = np.linalg.norm(R, axis=0) <= target
        if done.all():
            return X, 0, True
        if not (self.fresh and self.kind == "direct"):
            X, R, k, ok = self._cg(A, B, X, R, done, target, maxit, M)
            worst = float(np.max(np.linalg.norm(R, axis=0) / np.where(bnorm > 0, bnorm, 1.0)))
            self.rate = min(max(worst, 1e-300) ** (1.0 / (k + 1)), 0.999) if ok else 0.999
            return X, k, ok
        for k in range(1, 4):                          # iterative refinement (exact factor, any inertia)
            X += M(R).reshape(B.shape)
            R = B - A @ X
            if np.all(np.linalg.norm(R, axis=0) <= target):
                return X, k, True
        return X, 3, False

    @staticmethod
    def _cg(A, B, X, R, done, target, maxit, M):
        """Block PCG from ``X`` (residual ``R``) with the preconditioner ``M``."""
        Z = M(R).reshape(B.shape)
        P = Z.copy()
        rz = np.einsum("ij,ij->j", R, Z)
        for k in range(1, maxit + 1):
            AP = A @ P
            pap = np.einsum("ij,ij->j", P, AP)
            active = ~done
            if np.any(pap[active] <= 0.0):             # negative curvature: not SPD (or stale factor)
                return X, R, k, False
            alpha = np.where(active, rz / np.where(active, pap, 1.0), 0.0)
            X += alpha * P
            R -= alpha * AP
            done = np.linalg.norm(R, axis=0) <= target
            if done.all():
                return X, R, k, True
            Z = M(R).reshape(B.shape)
            rz_new = np.einsum("ij,ij->j", R, Z)
            beta = np.where(active, rz_new / np.where(rz != 0, rz, 1.0), 0.0)
            P = Z + beta * P
            rz = rz_new
        return X, R, maxit, False


