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
        # general storage ab[kl + ku + i - j, j] = A[i, j]  (dgbtrf with kl = ku = kd)
        rows_gb = 3 * kd + 1
        self.lo_src = block_flat[inside]
        self.lo_dst = np.ravel_multi_index((2 * kd + row[inside] - col[inside], col[inside]), (rows_gb, n))
        # upper blocks: A[c, c+s] = upper[c, s]  -> rows 6c + a, cols 6(c+s) + b
        urow, ucol = 6 * c + a, 6 * (c + s) + b
        up = (c + s < n_blocks) & (s >= 1) & (ucol - urow <= kd)
        self.up_src = block_flat[up]
        self.up_dst = np.ravel_multi_index((2 * kd + urow[up] - ucol[up], ucol[up]), (rows_gb, n))
        self._symmetric_gather()

    def _symmetric_gather(self):
        """Indices into the flat stacked ``[lower, upper]`` block storage (plus one trailing zero)
        of ``A[i, j]`` and ``A[j, i]`` for every entry ``ab[d, j] = A[j + d, j]`` of the lower
        symmetric band: the symmetric part is then two gathers and an average."""
        nb, span, kd, n = self.n_blocks, self.span, self.kd, self.n
        per_band = nb * (span + 1) * 36
        self.storage_size = 2 * per_band + 1
        d, j = np.meshgrid(np.arange(kd + 1), np.arange(n), indexing="ij")
        i = j + d
        I, J, a, b = i // 6, j // 6, i % 6, j % 6
        s = I - J
        inside = (i < n) & (s <= span)
        flat = lambda band, c, off, r, col: band * per_band + ((c * (span + 1) + off) * 6 + r) * 6 + col  # noqa: E731
        zero = self.storage_size - 1
        ij = np.where(inside, flat(0, J, s, a, b), zero)                          # lower[J, s, a, b]
        ji = np.where(inside, np.where(s == 0, flat(0, J, 0, b, a), flat(1, J, s, b, a)), zero)
        self.sym_ij, self.sym_ji = ij.ravel(), ji.ravel()

    @property
    def block_shape(self) -> tuple:
        """Shape of one block band: ``(n_blocks, span + 1, 6, 6)``."""
        return (self.n_blocks, self.span + 1, 6, 6)

    def new_blocks(self):
        """Zeroed (lower, upper) block arrays ``(n_blocks, span + 1, 6, 6)``."""
        return np.zeros(self.block_shape), np.zeros(self.block_shape)

    def _link_gather(self):
        """Indices into a flat stack of link tangents (n_blocks, 12, 12) plus one trailing zero
        of the four terms of every entry of the lower symmetric band: on the diagonal block of
        free frame J the end-b block of link J and the end-a block of link J + 1, below it the
        (b, a) block of link J + 1, and the transposed partners."""
        nb, kd, n = self.n_blocks, self.kd, self.n
        d, j = np.meshgrid(np.arange(min(kd, 11) + 1), np.arange(n), indexing="ij")   # links: 2 blocks
        i = j + d
        I, J, a, b = i // 6, j // 6, i % 6, j % 6
        zero = nb * 144
        entry = lambda link, r, c: link * 144 + r * 12 + c    # noqa: E731
        diagonal = (i < n) & (I == J)
        below = (i < n) & (I == J + 1)
        nxt = diagonal & (J + 1 < nb)
        self.link_terms = tuple(x.ravel() for x in (
            np.where(diagonal, entry(J, 6 + a, 6 + b), np.where(below, entry(J + 1, 6 + a, b), zero)),
            np.where(diagonal, entry(J, 6 + b, 6 + a), np.where(below, entry(J + 1, b, 6 + a), zero)),
            np.where(nxt, entry(J + 1, a, b), zero),
            np.where(nxt, entry(J + 1, b, a), zero)))

    def symmetric_from_links(self, flat: np.ndarray) -> np.ndarray:
        """The first min(kd, 11) + 1 rows of the lower band (LAPACK storage) of the symmetric
        part of the chain's link tangents (links couple neighbouring frames only; wider bands
        come from cables), ``flat`` = the (n_blocks, 12, 12) tangents raveled, plus one
        trailing zero."""
        if not hasattr(self, "link_terms"):
            self._link_gather()
        t1, t2, t3, t4 = self.link_terms
        ab = flat.take(t1)
        ab += flat.take(t2)
        ab += flat.take(t3)
        ab += flat.take(t4)
        ab *= 0.5
        return ab.reshape(-1, self.n)

    def new_storage(self):
        """Zeroed flat storage for stacked [lower, upper] blocks plus a trailing zero, and the
        (2, n_blocks, span + 1, 6, 6) view of its blocks."""
        storage = np.zeros(self.storage_size)
        return storage, storage[:-1].reshape((2,) + self.block_shape)

    def symmetric_from_storage(self, storage: np.ndarray) -> np.ndarray:
        """Lower band (LAPACK storage) of the symmetric part ½(A + Aᵀ) of the blocks held in
        ``storage`` (see :meth:`new_storage`)."""
        ab = storage.take(self.sym_ij)
        ab += storage.take(self.sym_ji)
        ab *= 0.5
        return ab.reshape(self.kd + 1, self.n)

    def symmetric_band(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Lower band of the symmetric part ½(A + Aᵀ)."""
        storage, blocks = self.new_storage()
        blocks[0], blocks[1] = lower, upper
        return self.symmetric_from_storage(storage)

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
