"""Banded factorisations through LAPACK: Cholesky (``dpbtrf``) and LU (``dgbtrf``).

Both cost O(n · bandwidth²). A factor's :meth:`BandedFactor.solve` is the LAPACK solve
(``dpbtrs``/``dgbtrs``) itself, for one or many right-hand sides, with nothing in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eig_banded, lu_factor, lu_solve
from scipy.linalg.lapack import dgbtrf, dgbtrs, dpbtrf, dpbtrs, dtbtrs


@dataclass(slots=True)
class BandedFactor:
    """A factorised band matrix of order ``n``: ``kind`` "cholesky" (``data`` = the lower band
    factor, ``kd`` subdiagonals) or "lu" (``data`` = LAPACK's general band LU, ``kd`` sub- and
    superdiagonals, ``pivots``)."""

    kind: str
    data: np.ndarray
    kd: int
    pivots: np.ndarray | None = None

    def solve(self, rhs: np.ndarray, *, overwrite: bool = False, transposed: bool = False) -> np.ndarray:
        """``A⁻¹ rhs`` (``A⁻ᵀ rhs`` with ``transposed``) for ``rhs`` of shape (n,) or (n, k). With
        ``overwrite`` a Fortran-ordered float ``rhs`` is overwritten by the solution (no copy)."""
        if self.pivots is None:
            x, info = dpbtrs(self.data, rhs, lower=1, overwrite_b=overwrite)
        else:
            x, info = dgbtrs(self.data, self.kd, self.kd, rhs, self.pivots, trans=int(transposed),
                             overwrite_b=overwrite)
        if info:
            raise np.linalg.LinAlgError(f"banded solve failed (LAPACK info {info})")
        return x

    def forward(self, rhs: np.ndarray, *, overwrite: bool = False) -> np.ndarray:
        """``L⁻¹ rhs`` of a Cholesky factor ``A = L Lᵀ`` (one triangular band sweep, ``dtbtrs``):
        ``A⁻¹ = L⁻ᵀ L⁻¹``, so products ``Cᵀ A⁻¹ D`` are ``(L⁻¹C)ᵀ (L⁻¹D)``. ``overwrite``: as
        :meth:`solve`."""
        if self.pivots is not None:
            raise ValueError("an LU factor has no symmetric halves")
        x, info = dtbtrs(self.data, rhs, uplo="L", overwrite_b=overwrite)
        if info:
            raise np.linalg.LinAlgError(f"banded triangular solve failed (LAPACK info {info})")
        return x

    def backward(self, rhs: np.ndarray, *, overwrite: bool = False) -> np.ndarray:
        """``L⁻ᵀ rhs`` of a Cholesky factor ``A = L Lᵀ``: ``backward(forward(b)) = A⁻¹ b``."""
        if self.pivots is not None:
            raise ValueError("an LU factor has no symmetric halves")
        x, info = dtbtrs(self.data, rhs, uplo="L", trans="T", overwrite_b=overwrite)
        if info:
            raise np.linalg.LinAlgError(f"banded triangular solve failed (LAPACK info {info})")
        return x


def factor_cholesky(ab: np.ndarray) -> BandedFactor | None:
    """Banded Cholesky of a lower band (LAPACK storage ``ab[d, j] = A[j + d, j]``); ``None`` when
    the matrix is not positive definite."""
    c, info = dpbtrf(ab, lower=1)
    if info != 0:
        return None
    return BandedFactor("cholesky", c, ab.shape[0] - 1)


def factor_lu(ab_general: np.ndarray, kd: int) -> BandedFactor | None:
    """Banded LU of a general band (``ab[2kd + i − j, j] = A[i, j]``, ``3kd + 1`` rows); ``None``
    when the matrix is singular."""
    lu, piv, info = dgbtrf(ab_general, kd, kd)
    if info != 0:
        return None
    return BandedFactor("lu", lu, kd, piv)


@dataclass
class LowRankFactor:
    """The factor of ``A + U diag(d) Uᵀ`` from the factor of the band ``A``, with ``U`` (n, r)
    dense and ``d`` (r,) positive (Sherman–Morrison–Woodbury): stroke-driven tendons couple every
    frame they pass through, a rank-one term each, which a band cannot hold. Built with ``r``
    band solves; each solve is one band solve and two (n, r) products."""

    band: BandedFactor
    U: np.ndarray           # (n, r)
    Z: np.ndarray           # (n, r) A⁻¹ U
    capacitance: tuple      # LU of diag(1/d) + Uᵀ A⁻¹ U (r × r)

    @classmethod
    def of(cls, band: BandedFactor, U: np.ndarray, d: np.ndarray) -> "LowRankFactor":
        Z = band.solve(U)
        return cls(band, U, Z, lu_factor(np.diag(1.0 / d) + U.T @ Z, check_finite=False))

    @classmethod
    def definite(cls, lower: np.ndarray, U: np.ndarray, d: np.ndarray) -> "LowRankFactor | None":
        """The factor of ``A + U diag(d) Uᵀ`` when that is positive definite although the symmetric
        band ``A`` (its lower band) is not — tendons that hold a trunk their tension compresses
        beyond what its links alone carry — else None. The band is factored by LU; by
        Haynsworth's inertia additivity on ``[[A, U], [Uᵀ, −D⁻¹]]`` the whole has no
        non-positive eigenvalue exactly when ``A`` has as many negative eigenvalues as the
        capacitance ``D⁻¹ + Uᵀ A⁻¹ U`` (and neither is singular)."""
        band = factor_lu(general_band_of_symmetric(lower), lower.shape[0] - 1)
        if band is None:
            return None
        eigenvalues = eig_banded(lower, lower=True, eigvals_only=True, select="v", select_range=(-np.inf, 0.0),
                                 check_finite=False)
        Z = band.solve(U)
        capacitance = np.diag(1.0 / d) + U.T @ Z
        inner = np.linalg.eigvalsh(0.5 * (capacitance + capacitance.T))
        if np.any(inner == 0.0) or eigenvalues.size != int(np.count_nonzero(inner < 0.0)):
            return None
        return cls(band, U, Z, lu_factor(capacitance, check_finite=False))

    @property
    def kind(self) -> str:
        return self.band.kind

    def solve(self, rhs: np.ndarray, *, overwrite: bool = False) -> np.ndarray:
        """``(A + U diag(d) Uᵀ)⁻¹ rhs`` for ``rhs`` of shape (n,) or (n, k)."""
        y = self.band.solve(rhs, overwrite=overwrite)
        return y - self.Z @ lu_solve(self.capacitance, self.U.T @ y, check_finite=False)


def general_band_of_symmetric(lower: np.ndarray) -> np.ndarray:
    """LAPACK's general band storage (``ab[2kd + i − j, j] = A[i, j]``, ``3kd + 1`` rows, for
    ``dgbtrf``) of the symmetric matrix whose lower band is ``lower`` (``lower[d, j] = A[j + d, j]``)."""
    kd1, n = lower.shape
    kd = kd1 - 1
    ab = np.zeros((3 * kd + 1, n))
    for d in range(kd1):
        ab[2 * kd + d, :n - d] = lower[d, :n - d]          # A[j + d, j]
        ab[2 * kd - d, d:] = lower[d, :n - d]              # A[j, j + d]
    return ab


# ----------------------------------------------------------------------------- batched
@dataclass(slots=True)
class BlockCholesky:
    """Cholesky factors ``L Lᵀ`` of a batch of symmetric block-banded matrices (one per sample,
    leading axis): ``n_blocks`` diagonal blocks of ``size`` × ``size`` whose couplings reach
    ``span`` blocks. ``blocks[:, span + c, s]`` holds ``L[c + s, c]`` (block column ``c`` stored
    after ``span`` padding columns, and as many after it, so that every step of the factor and
    of its solves is one batched product without bounds); ``inverse[:, c]`` holds ``L[c, c]⁻¹``.
    ``ok[i]``: sample ``i``'s matrix is positive definite (the others' factors are meaningless).
    Built by :func:`factor_block_cholesky`."""

    blocks: np.ndarray
    inverse: np.ndarray
    ok: np.ndarray

    @property
    def span(self) -> int:
        return self.blocks.shape[2] - 1

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` per sample for ``rhs`` of shape (B, n) or (B, n, k) (n = blocks × size)."""
        with np.errstate(all="ignore"):         # (a refused sample's numbers are meaningless)
            return self._solve(rhs)

    def _solve(self, rhs: np.ndarray) -> np.ndarray:
        L, inverse = self.blocks, self.inverse
        B, nb, size = inverse.shape[0], inverse.shape[1], inverse.shape[2]
        p = self.span
        rhs = np.asarray(rhs, dtype=float)
        single = rhs.ndim == 2
        y = np.zeros((B, nb + 2 * p, size, 1 if single else rhs.shape[2]))
        y[:, p:p + nb] = rhs.reshape(B, nb, size, -1)
        offsets = np.arange(1, p + 1)
        for j in range(nb):                      # L y = b: y_j = L_jj⁻¹ (b_j − Σ_t L[j, j−t] y_{j−t})
            c = p + j
            acc = y[:, c]
            if p:
                acc = acc - np.add.reduce(L[:, c - offsets, offsets] @ y[:, c - offsets], 1)
            y[:, c] = inverse[:, j] @ acc
        for j in range(nb - 1, -1, -1):          # Lᵀ x = y: x_j = L_jj⁻ᵀ (y_j − Σ_s L[j+s, j]ᵀ x_{j+s})
            c = p + j
            acc = y[:, c]
            if p:
                acc = acc - np.add.reduce(L[:, c, 1:].mT @ y[:, c + 1:c + p + 1], 1)
            y[:, c] = inverse[:, j].mT @ acc
        x = y[:, p:p + nb]
        return x.reshape(B, nb * size) if single else x.reshape(B, nb * size, -1)


def _update_pairs(span: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The trailing update of a block column: for 1 ≤ s ≤ s′ ≤ span, block ``(j+s′, j+s)`` loses
    ``L[j+s′, j] L[j+s, j]ᵀ``; returned as (s′ − 1, s − 1, column offset s, band offset s′ − s)."""
    pairs = [(b, a) for a in range(1, span + 1) for b in range(a, span + 1)]
    late, early = (np.array(v, int) for v in zip(*pairs)) if pairs else (np.zeros(0, int),) * 2
    return late - 1, early - 1, early, late - early


def _cholesky_blocks(pivot: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factors and their inverses (B, k, k) of symmetric blocks ``pivot``, column
    by column over the batch (a pivot that is not positive — or NaN — refuses the sample in
    ``ok``, as LAPACK's ``dpotrf``/``dpbtrf`` refuse the matrix; its factor is then meaningless).
    Worked with the samples as the last axis (k, k, B): every scalar step of the factor is one
    operation over the batch (a small matrix product per sample would cost more than its
    arithmetic)."""
    B, size = pivot.shape[0], pivot.shape[1]
    P = np.ascontiguousarray(pivot.transpose(1, 2, 0))
    L = np.zeros_like(P)
    for j in range(size):
        row = L[j, :j]
        d = P[j, j] - np.add.reduce(row * row, 0) if j else P[j, j].copy()
        positive = d > 0.0
        if not positive.all():
            ok &= positive
            d[~positive] = 1.0
        root = np.sqrt(d)
        L[j, j] = root
        if j + 1 < size:
            column = P[j + 1:, j]
            if j:
                column = column - np.add.reduce(L[j + 1:, :j] * row, 1)
            np.divide(column, root, out=L[j + 1:, j])
    inverse = np.zeros_like(P)
    diagonal = 1.0 / L[np.arange(size), np.arange(size)]
    inverse[np.arange(size), np.arange(size)] = diagonal
    for i in range(1, size):          # row i of L⁻¹: −(L[i, :i] L⁻¹[:i, :i]) / L[i, i]
        inverse[i, :i] = -np.add.reduce(L[i, :i, None] * inverse[:i, :i], 0) * diagonal[i]
    return L.transpose(2, 0, 1), inverse.transpose(2, 0, 1)


def factor_block_cholesky(lower: np.ndarray) -> BlockCholesky:
    """Batched block-banded Cholesky of symmetric positive definite matrices given by their
    lower block band ``lower`` (B, n_blocks, span + 1, size, size), ``lower[:, c, s] = A[c + s, c]``
    (entries with ``c + s ≥ n_blocks`` are ignored). Right-looking, one block column at a time:
    every step is a batched product over the samples. A sample whose matrix is not positive
    definite (a pivot that is not positive, where ``dpbtrf`` refuses its band) gets ``ok`` False;
    the others are not affected."""
    with np.errstate(all="ignore"):             # (a refused sample's numbers are meaningless)
        return _factor_block_cholesky(lower)


def _factor_block_cholesky(lower: np.ndarray) -> BlockCholesky:
    B, nb, p1, size = lower.shape[0], lower.shape[1], lower.shape[2], lower.shape[3]
    p = p1 - 1
    L = np.zeros((B, nb + 2 * p, p1, size, size))
    L[:, p:p + nb] = lower
    for s in range(1, p1):                       # blocks beyond the matrix
        L[:, p + nb - s:p + nb, s] = 0.0
    inverse = np.empty((B, nb, size, size))
    ok = np.ones(B, bool)
    late, early, column, offset = _update_pairs(p)
    for j in range(nb):
        c = p + j
        factor, inv = _cholesky_blocks(L[:, c, 0], ok)
        L[:, c, 0] = factor
        inverse[:, j] = inv
        if p:
            below = L[:, c, 1:] @ inv.mT[:, None]               # L[j+s, j] = A[j+s, j] L_jj⁻ᵀ
            L[:, c, 1:] = below
            L[:, c + column, offset] -= below[:, late] @ below[:, early].mT
    return BlockCholesky(L, inverse, ok)
