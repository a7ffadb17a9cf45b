"""Banded factorisations through LAPACK: Cholesky (``dpbtrf``) and LU (``dgbtrf``).

Both cost O(n · bandwidth²). A factor's :meth:`BandedFactor.solve` is the LAPACK solve
(``dpbtrs``/``dgbtrs``) itself, for one or many right-hand sides, with nothing in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgbtrf, dgbtrs, dpbtrf, dpbtrs


@dataclass(slots=True)
class BandedFactor:
    """A factorised band matrix of order ``n``: ``kind`` "cholesky" (``data`` = the lower band
    factor, ``kd`` subdiagonals) or "lu" (``data`` = LAPACK's general band LU, ``kd`` sub- and
    superdiagonals, ``pivots``)."""

    kind: str
    data: np.ndarray
    kd: int
    pivots: np.ndarray | None = None

    def solve(self, rhs: np.ndarray, *, overwrite: bool = False) -> np.ndarray:
        """``A⁻¹ rhs`` for ``rhs`` of shape (n,) or (n, k). With ``overwrite`` a Fortran-ordered
        float ``rhs`` is overwritten by the solution (no copy)."""
        if self.pivots is None:
            x, info = dpbtrs(self.data, rhs, lower=1, overwrite_b=overwrite)
        else:
            x, info = dgbtrs(self.data, self.kd, self.kd, rhs, self.pivots, overwrite_b=overwrite)
        if info:
            raise np.linalg.LinAlgError(f"banded solve failed (LAPACK info {info})")
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
