"""Linear solvers for the interior stiffness ``K_ii`` (SPD: both end faces are
eliminated, so the usual rigid-body modes are the near-null space). A registry
of small solver objects with two methods: ``factor(A, modes) -> Factor`` (an
object whose ``solve(B) -> (X, info)`` can be called many times — the Newton
iterations of the nonlinear models reuse one factor for the step and for the
condensed tangent) and ``solve(A, B, modes) -> (X, info)`` (factor, then solve).

* ``direct``: SuperLU with a symmetric fill-reducing ordering (small meshes).
  When SuperLU pivoted on the diagonal only (``perm_r == perm_c``) the factor
  also reports the number of negative pivots, i.e. of negative eigenvalues of a
  symmetric ``A`` (Sylvester's law of inertia) — how the nonlinear models see a
  tangent stiffness that lost positive definiteness.
* ``amg``: pyamg smoothed aggregation (3×3 blocks, rigid-body near-null space,
  ``coarse_solver='splu'`` — the default ``'pinv'`` cost ~30 s at 34k DoFs,
  measured — and Chebyshev smoothing) as preconditioner of conjugate
  gradients, one right-hand side at a time.
* ``auto``: ``direct`` below ``AUTO_THRESHOLD`` unknowns, ``amg`` above, and ``direct``
  again when AMG-PCG stalls (more than 150 iterations: thin-walled geometry).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vertebra.core.errors import ConvergenceError, VertebraError

AUTO_THRESHOLD = 12_000     # interior unknowns; measured crossover ~14k (P2 rod), direct 7.8 s at 20k (pneumatic): benchmarks/results/designer.md
AMG_RTOL = 1e-8             # relative residual of each PCG solve (compliance error ~1e-9, far below discretisation)
#: polynomial smoothing: ~2.4× faster than pyamg's default block Gauss–Seidel on a 45k-DoF P2
#: rod here (same iteration count), and symmetric, as PCG requires
AMG_SMOOTHER = ("chebyshev", {"degree": 3})
#: strength threshold: 0.1 (pyamg's default 0) coarsens less aggressively — 3 levels instead of 2,
#: 30 instead of 46 PCG iterations and ~40 % less time on a 45k-unknown P2 pneumatic, ν = 0.45
AMG_STRENGTH = ("symmetric", {"theta": 0.1})


class Factor(Protocol):
    info: dict

    def solve(self, B: np.ndarray) -> tuple[np.ndarray, dict]: ...

    def apply(self, B: np.ndarray) -> np.ndarray:
        """The factor as a preconditioner: ``A⁻¹ B`` exactly (direct) or one V-cycle (AMG)."""


class LinearSolver(Protocol):
    name: str

    def factor(self, A, modes: np.ndarray | None) -> Factor: ...

    def solve(self, A, B: np.ndarray, modes: np.ndarray | None) -> tuple[np.ndarray, dict]: ...


LINEAR_SOLVERS: dict[str, LinearSolver] = {}


def register_solver(cls):
    LINEAR_SOLVERS[cls.name] = cls()
    return cls


class _FactorThenSolve:
    def solve(self, A, B, modes=None):
        return self.factor(A, modes).solve(B)


@dataclass
class DirectFactor:
    lu: object
    info: dict

    def solve(self, B):
        return self.lu.solve(np.asarray(B, dtype=float)), self.info

    def apply(self, B):
        return self.lu.solve(np.asarray(B, dtype=float))


@register_solver
@dataclass
class Direct(_FactorThenSolve):
    """``diag_pivot_thresh``: SuperLU's threshold for keeping the diagonal pivot (None: its
    default, 1); a small value keeps ``perm_r == perm_c`` on symmetric matrices, so the
    inertia is known."""

    name: str = "direct"
    diag_pivot_thresh: float | None = None

    def factor(self, A, modes=None):
        from scipy.sparse.linalg import splu
        lu = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True},
                  diag_pivot_thresh=self.diag_pivot_thresh)
        info = {"solver": "direct", "method": "SuperLU (MMD_AT_PLUS_A)", "fill": int(lu.L.nnz + lu.U.nnz)}
        if np.array_equal(lu.perm_r, lu.perm_c):
            info["negative_pivots"] = int(np.count_nonzero(lu.U.diagonal() < 0))
        return DirectFactor(lu, info)


@dataclass
class AMGFactor:
    A: object
    preconditioner: object
    rtol: float
    maxiter: int
    info: dict = field(default_factory=dict)

    def solve(self, B):
        from scipy.sparse.linalg import cg
        B = np.asarray(B, dtype=float)
        single = B.ndim == 1
        B2 = B.reshape(B.shape[0], -1)
        X = np.zeros_like(B2)
        iterations = []
        for j in range(B2.shape[1]):
            count = [0]

            def callback(_x, count=count):
                count[0] += 1

            x, status = cg(self.A, B2[:, j], rtol=self.rtol, atol=0.0, M=self.preconditioner,
                           maxiter=self.maxiter, callback=callback)
            if status != 0:
                raise ConvergenceError(f"AMG-PCG did not reach rtol {self.rtol} in {self.maxiter} iterations "
                                       f"(right-hand side {j})")
            X[:, j] = x
            iterations.append(count[0])
        return (X[:, 0] if single else X), dict(self.info, iterations=iterations)

    def apply(self, B):
        B = np.asarray(B, dtype=float)
        if B.ndim == 1:
            return self.preconditioner @ B
        return np.column_stack([self.preconditioner @ B[:, j] for j in range(B.shape[1])])


@register_solver
@dataclass
class AMG(_FactorThenSolve):
    name: str = "amg"
    rtol: float = AMG_RTOL
    maxiter: int = 2000

    def factor(self, A, modes=None):
        import pyamg
        A = A.tocsr()
        if A.shape[0] % 3:
            raise VertebraError(f"AMG needs 3×3 nodal blocks, got {A.shape[0]} unknowns")
        ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(3, 3)), B=modes, coarse_solver="splu",
                                               max_coarse=500, presmoother=AMG_SMOOTHER,
                                               postsmoother=AMG_SMOOTHER, strength=AMG_STRENGTH)
        info = {"solver": "amg", "method": "pyamg smoothed aggregation + PCG", "rtol": self.rtol,
                "levels": len(ml.levels)}
        return AMGFactor(A, ml.aspreconditioner(), self.rtol, self.maxiter, info)


@dataclass
class AutoFactor:
    """AMG factor that falls back to a direct factor of the same matrix when PCG stalls."""

    A: object
    amg: AMGFactor
    direct: DirectFactor | None = None

    @property
    def info(self):
        return (self.direct or self.amg).info

    def apply(self, B):
        return (self.direct or self.amg).apply(B)

    def solve(self, B):
        if self.direct is None:
            try:
                return self.amg.solve(B)
            except ConvergenceError as error:
                self.direct = LINEAR_SOLVERS["direct"].factor(self.A)
                self.direct.info = dict(self.direct.info, amg_fallback=str(error))
        return self.direct.solve(B)


@dataclass
class Auto(_FactorThenSolve):
    """``direct`` below ``threshold`` unknowns; above it AMG, falling back to ``direct`` when
    AMG-PCG stalls (thin walls — a bellows — made smoothed aggregation need 600–900
    iterations where SuperLU took seconds)."""

    threshold: int = AUTO_THRESHOLD
    amg_maxiter: int = 150
    name: str = "auto"

    def factor(self, A, modes=None):
        if A.shape[0] < self.threshold:
            return LINEAR_SOLVERS["direct"].factor(A, modes)
        return AutoFactor(A, AMG(maxiter=self.amg_maxiter).factor(A, modes))


def get_solver(name: str, n_unknowns: int, threshold: int | None = None) -> LinearSolver:
    """The solver registered as ``name``; ``"auto"`` picks by size (see :class:`Auto`)."""
    if name == "auto":
        return Auto(threshold=AUTO_THRESHOLD if threshold is None else threshold)
    if name not in LINEAR_SOLVERS:
        raise VertebraError(f"unknown linear_solver {name!r} (known: auto, {', '.join(LINEAR_SOLVERS)})")
    return LINEAR_SOLVERS[name]
