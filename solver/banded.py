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
class BandedFactors:
    """Cholesky factors of a batch of symmetric band matrices, one LAPACK factor per sample:
    ``data[i].T`` is sample ``i``'s lower band factor (``dpbtrf``'s, Fortran-ordered (kd + 1, n)).
    ``ok[i]``: sample ``i``'s matrix is positive definite (``dpbtrf`` refused the others; their
    solves are zero). Built by :func:`factor_cholesky_batch`."""

    data: np.ndarray
    ok: np.ndarray

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` per sample for ``rhs`` of shape (B, n) or (B, n, k) (``dpbtrs``, sample by
        sample: each one LAPACK call on its whole band)."""
        rhs = np.asarray(rhs, dtype=float)
        out = np.zeros(rhs.shape)
        data = self.data
        for i in np.flatnonzero(self.ok).tolist():
            x, info = dpbtrs(data[i].T, rhs[i], lower=1)
            if info:
                raise np.linalg.LinAlgError(f"banded solve failed (LAPACK info {info})")
            out[i] = x
        return out


def factor_cholesky_batch(bands: np.ndarray) -> BandedFactors:
    """Banded Cholesky (``dpbtrf``, as :func:`factor_cholesky`) of a batch of symmetric positive
    definite band matrices given by their transposed lower bands ``bands`` (B, n, kd + 1),
    ``bands[i, j, d] = A_i[j + d, j]`` (C-ordered: each ``bands[i].T`` is LAPACK's band storage),
    factored in place. A sample whose matrix is not positive definite gets ``ok`` False; the
    others are not affected. One LAPACK call per sample: on bands of tens to hundreds of unknowns
    that costs less than any formulation of the factor as products over the batch (the factor's
    arithmetic is a few tens of thousands of operations, its steps 6×6 or smaller)."""
    B = bands.shape[0]
    ok = np.ones(B, bool)
    for i in range(B):
        ok[i] = dpbtrf(bands[i].T, lower=1, overwrite_ab=1)[1] == 0
    return BandedFactors(bands, ok)
