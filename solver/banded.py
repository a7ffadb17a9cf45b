"""Block-banded tangent matrices: assembly straight into LAPACK band storage.

The trunk's tangent stiffness couples only frames joined by a link (block offset 1)
or by a cable piece (offset = links per repetition), so it is block-banded with
6×6 blocks. Blocks are kept as ``lower[c, s] = A[c+s, c]`` and ``upper[c, s] = A[c, c+s]``;
index maps computed once per model scatter them into LAPACK storage without any
dense or general sparse global matrix. Factorisation is banded Cholesky (``dpbtrf``)
when the matrix is symmetric positive definite, banded LU (``dgbtrf``) otherwise —
both O(frames · bandwidth²).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack


class BandLayout:
    """Index maps from block-band storage to LAPACK band storage for ``n_blocks`` blocks."""

    def __init__(self, n_blocks: int, span: int):
        self.n_blocks, self.span = n_blocks, span
        self.n = n = 6 * n_blocks
        self.kd = kd = min(6 * (span + 1) - 1, max(n - 1, 0))
        c, s, a, b = np.meshgrid(np.arange(n_blocks), np.arange(span + 1), np.arange(6), np.arange(6),
                                 indexing="ij")
        row = 6 * (c + s) + a
        col = 6 * c + b
        inside = (c + s < n_blocks) & (row - col <= kd)
        block_flat = np.ravel_multi_index((c, s, a, b), (n_blocks, span + 1, 6, 6))
        # symmetric lower storage ab[i - j, j] = A[i, j], i >= j  (dpbtrf, lower=1)
        lower = inside & (row >= col)
        self.sym_src = block_flat[lower]
        self.sym_dst = np.ravel_multi_index((row[lower] - col[lower], col[lower]), (kd + 1, n))
        # general storage ab[kl + ku + i - j, j] = A[i, j]  (dgbtrf with kl = ku = kd)
        rows_gb = 3 * kd + 1
        self.lo_src = block_flat[inside]
        self.lo_dst = np.ravel_multi_index((2 * kd + row[inside] - col[inside], col[inside]), (rows_gb, n))
        # upper blocks: A[c, c+s] = upper[c, s]  -> rows 6c + a, cols 6(c+s) + b
        urow, ucol = 6 * c + a, 6 * (c + s) + b
        up = (c + s < n_blocks) & (s >= 1) & (ucol - urow <= kd)
        self.up_src = block_flat[up]
        self.up_dst = np.ravel_multi_index((2 * kd + urow[up] - ucol[up], ucol[up]), (rows_gb, n))

    @property
    def block_shape(self) -> tuple:
        """Shape of one block band: ``(n_blocks, span + 1, 6, 6)``."""
        return (self.n_blocks, self.span + 1, 6, 6)

    def new_blocks(self):
        """Zeroed (lower, upper) block arrays ``(n_blocks, span + 1, 6, 6)``."""
        return np.zeros(self.block_shape), np.zeros(self.block_shape)

    def symmetric_band(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Lower band of the symmetric part ½(A + Aᵀ)."""
        sym = lower.copy()
        sym[:, 1:] += np.swapaxes(upper[:, 1:], -1, -2)
        sym[:, 1:] *= 0.5
        sym[:, 0] = 0.5 * (lower[:, 0] + np.swapaxes(lower[:, 0], -1, -2))
        ab = np.zeros((self.kd + 1, self.n))
        ab.ravel()[self.sym_dst] = sym.ravel()[self.sym_src]
        return ab

    def general_band(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        ab = np.zeros((3 * self.kd + 1, self.n))
        flat = ab.ravel()
        flat[self.lo_dst] = lower.ravel()[self.lo_src]
        flat[self.up_dst] = upper.ravel()[self.up_src]
        return ab


@dataclass
class BandedFactor:
    """A factorised band matrix; ``solve`` takes one or many right-hand sides."""

    kind: str            # "cholesky" | "lu"
    data: np.ndarray
    kd: int
    pivots: np.ndarray | None = None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        b = rhs.reshape(rhs.shape[0], -1)
        if self.kind == "cholesky":
            x, info = lapack.dpbtrs(self.data, b, lower=1)
        else:
            x, info = lapack.dgbtrs(self.data, self.kd, self.kd, b, self.pivots)
        if info != 0:
            raise np.linalg.LinAlgError(f"banded solve failed (LAPACK info {info})")
        return x.reshape(rhs.shape)


def factor_cholesky(ab: np.ndarray) -> BandedFactor | None:
    """Banded Cholesky of a lower band; ``None`` when the matrix is not positive definite."""
    c, info = lapack.dpbtrf(ab, lower=1)
    if info != 0:
        return None
    return BandedFactor("cholesky", c, ab.shape[0] - 1)


def factor_lu(ab_general: np.ndarray, kd: int) -> BandedFactor | None:
    lu, piv, info = lapack.dgbtrf(ab_general, kd, kd)
    if info != 0:
        return None
    return BandedFactor("lu", lu, kd, piv)
