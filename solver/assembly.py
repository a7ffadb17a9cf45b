"""Assembly of the trunk's tangent into band storage: every index map in one place.

The tangent couples only frames joined by a link (block offset 1) or by a cable piece (offset
= links per repetition), so it is block-banded with 6×6 blocks over the free frames. Its terms
arrive in two forms:

* the links' 12×12 tangents side by side (``n_links·144`` values and one trailing zero that
  the gathers point to where a band entry gets nothing);
* everything else (cables, gravity) as *block bands*: ``lower[c, s] = A[c+s, c]`` and
  ``upper[c, s] = A[c, c+s]`` stacked in one flat *storage* (with a trailing zero).

:class:`BandAssembler` holds the maps, computed once per model, that take them to LAPACK band
storage — the lower band of the symmetric part for ``dpbtrf``, the general band for
``dgbtrf`` — without any dense or general sparse global matrix. :class:`Tangent` is one
tangent in these forms and factorises it (:mod:`vertebra.solver.banded`).
"""

from __future__ import annotations

import functools
import numpy as np

from vertebra.solver.banded import BandedFactor, factor_cholesky, factor_lu


_NO_PIECES = np.zeros(0, int)


class BandAssembler:
    """Index maps from the tangent's terms to LAPACK band storage for ``n_blocks`` free frames
    whose couplings reach ``span`` blocks, and cable pieces joining frames ``piece_a`` →
    ``piece_b`` (frame 0 is the clamped base, block k is frame k + 1)."""

    def __init__(self, n_blocks: int, span: int, piece_a: np.ndarray = _NO_PIECES, piece_b: np.ndarray = _NO_PIECES):
        if np.any(piece_b - piece_a > span):
            raise ValueError(f"cable pieces couple frames up to {int(np.max(piece_b - piece_a))} apart; span is {span}")
        self.n_blocks = nb = n_blocks
        self.span = span
        self.n = n = 6 * nb
        self.kd = kd = min(6 * (span + 1) - 1, max(n - 1, 0))
        self.block_shape = (nb, span + 1, 6, 6)
        per_band = nb * (span + 1) * 36
        self.storage_size = 2 * per_band + 1
        c, s, a, b = np.meshgrid(np.arange(nb), np.arange(span + 1), np.arange(6), np.arange(6), indexing="ij")
        block_flat = np.ravel_multi_index((c, s, a, b), self.block_shape)
        # general storage ab[kl + ku + i − j, j] = A[i, j] (dgbtrf with kl = ku = kd)
        row, col = 6 * (c + s) + a, 6 * c + b
        inside = (c + s < nb) & (row - col <= kd)
        self._lower_source = block_flat[inside]
        self._lower_target = np.ravel_multi_index((2 * kd + row[inside] - col[inside], col[inside]), (3 * kd + 1, n))
        urow, ucol = 6 * c + a, 6 * (c + s) + b           # upper[c, s] = A[c, c+s]
        up = (c + s < nb) & (s >= 1) & (ucol - urow <= kd)
        self._upper_source = block_flat[up]
        self._upper_target = np.ravel_multi_index((2 * kd + urow[up] - ucol[up], ucol[up]), (3 * kd + 1, n))
        # lower symmetric band ab[d, j] = A[j + d, j]: where A[i, j] and A[j, i] sit in the storage
        d, j = np.meshgrid(np.arange(kd + 1), np.arange(n), indexing="ij")
        i = j + d
        I, J, a, b = i // 6, j // 6, i % 6, j % 6
        s = I - J
        inside = (i < n) & (s <= span)
        flat = lambda band, c, off, r, col: band * per_band + ((c * (span + 1) + off) * 6 + r) * 6 + col  # noqa: E731
        zero = self.storage_size - 1
        self._sym_ij = np.where(inside, flat(0, J, s, a, b), zero).ravel()                    # lower[J, s, a, b]
        self._sym_ji = np.where(inside, np.where(s == 0, flat(0, J, 0, b, a), flat(1, J, s, b, a)), zero).ravel()
        self._cable_maps(piece_a, piece_b)

    def _cable_maps(self, a: np.ndarray, b: np.ndarray) -> None:
        """Pieces join frames a → b (sorted by a, then b). When every pair of frames has frames of
        its own (consecutive vertebrae), each pair's summed tangent is written once per block
        (per-pair path); otherwise one gather-sum-scatter adds pieces that share a block."""
        first = np.flatnonzero(np.r_[a.size > 0, (a[1:] != a[:-1]) | (b[1:] != b[:-1])])
        self.pair_a, self.pair_b = a[first], b[first]
        self._pair_free = self.pair_a > 0
        self._pair_offset = (self.pair_b - self.pair_a)[self._pair_free]
        # the pieces of each pair, padded with a.size (no piece): CablePieces.tangent's groups
        counts = np.diff(np.r_[first, a.size])
        width = int(counts.max(initial=0))
        slot = np.arange(width)
        self.cable_groups = np.where(slot < counts[:, None], first[:, None] + slot, a.size)
        chains = np.unique(self.pair_a).size == first.size and np.unique(self.pair_b).size == first.size
        self.cable_scatter = None if chains else self.cable_scatter_map(self.pair_a, self.pair_b)

    def cable_scatter_map(self, a: np.ndarray, b: np.ndarray):
        """Where the 144 tangent entries of each pair of frames ``a`` → ``b`` go in the flat block
        storage, sorted by destination so that one ``add.reduceat`` sums the pairs that share a
        block: (source indices, segment starts, unique destinations)."""
        n_offsets = self.span + 1
        n_band = self.n_blocks * n_offsets
        piece = np.arange(a.size)
        free = a > 0
        # (pieces, row block, column block, destination block) for bb, aa, ba, ab
        parts = [(piece, 1, 1, (b - 1) * n_offsets),
                 (piece[free], 0, 0, (a[free] - 1) * n_offsets),
                 (piece[free], 1, 0, (a[free] - 1) * n_offsets + (b - a)[free]),
                 (piece[free], 0, 1, n_band + (a[free] - 1) * n_offsets + (b - a)[free])]
        r, c = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
        src, dst = [], []
        for p, rb, cb, block in parts:
            src.append((p[:, None] * 144 + (6 * rb + r.ravel()) * 12 + 6 * cb + c.ravel()).ravel())
            dst.append((block[:, None] * 36 + r.ravel() * 6 + c.ravel()).ravel())
        src, dst = np.concatenate(src), np.concatenate(dst)
        order = np.argsort(dst, kind="stable")
        src, dst = src[order], dst[order]
        starts = np.flatnonzero(np.r_[dst.size > 0, dst[1:] != dst[:-1]])
        return src, starts, dst[starts]

    @functools.cached_property
    def _link_terms(self) -> tuple:
        """Indices into the links' tangents side by side (plus the trailing zero) of the four terms
        of every entry in the first min(kd, 11) + 1 rows of the lower symmetric band: on the
        diagonal block of free frame J the end-b block of link J and the end-a block of link
        J + 1, below it the (b, a) block of link J + 1, and the transposed partners."""
        nb, n = self.n_blocks, self.n
        d, j = np.meshgrid(np.arange(min(self.kd, 11) + 1), np.arange(n), indexing="ij")   # links: 2 blocks
        i = j + d
        I, J, a, b = i // 6, j // 6, i % 6, j % 6
        zero = nb * 144
        entry = lambda link, r, c: link * 144 + r * 12 + c    # noqa: E731
        diagonal = (i < n) & (I == J)
        below = (i < n) & (I == J + 1)
        nxt = diagonal & (J + 1 < nb)
        return tuple(x.ravel() for x in (
            np.where(diagonal, entry(J, 6 + a, 6 + b), np.where(below, entry(J + 1, 6 + a, b), zero)),
            np.where(diagonal, entry(J, 6 + b, 6 + a), np.where(below, entry(J + 1, b, 6 + a), zero)),
            np.where(nxt, entry(J + 1, a, b), zero),
            np.where(nxt, entry(J + 1, b, a), zero)))

    # ------------------------------------------------------------------ block storage
    def new_storage(self):
        """Zeroed flat block storage and the (2, n_blocks, span + 1, 6, 6) view of its
        ``[lower, upper]`` block bands."""
        storage = np.zeros(self.storage_size)
        return storage, storage[:-1].reshape((2,) + self.block_shape)

    @staticmethod
    def diagonal(blocks: np.ndarray) -> np.ndarray:
        """The diagonal blocks (n_blocks, 6, 6) of free frames 1 … N−1 in a block-band view."""
        return blocks[0, :, 0]

    def add_cables(self, blocks: np.ndarray, H: np.ndarray) -> None:
        """Add the cables' tangents ``H`` (pairs, 12, 12), summed over the pieces of each pair of
        frames (``CablePieces.tangent`` with :attr:`cable_groups`), to the block bands."""
        lower, upper = blocks[0], blocks[1]
        if self.cable_scatter is None:
            free, fa = self._pair_free, self.pair_a[self._pair_free] - 1
            lower[self.pair_b - 1, 0] += H[:, 6:, 6:]
            lower[fa, 0] += H[free, :6, :6]
            lower[fa, self._pair_offset] += H[free, 6:, :6]
            upper[fa, self._pair_offset] += H[free, :6, 6:]
        else:
            source, starts, target = self.cable_scatter
            blocks.reshape(-1)[target] += np.add.reduceat(H.reshape(-1).take(source), starts)

    def add_links(self, blocks: np.ndarray, link_tangents: np.ndarray) -> None:
        """Add the links' tangents (the flat side-by-side form) to the block bands."""
        lower, upper = blocks[0], blocks[1]
        H = link_tangents[:-1].reshape(self.n_blocks, 12, 12)
        lower[:, 0] += H[:, 6:, 6:]
        lower[:-1, 0] += H[1:, :6, :6]
        lower[:-1, 1] += H[1:, 6:, :6]
        upper[:-1, 1] += H[1:, :6, 6:]

    # ------------------------------------------------------------------ LAPACK storage
    def symmetric_from_links(self, link_tangents: np.ndarray) -> np.ndarray:
        """The first min(kd, 11) + 1 rows of the lower band of the symmetric part of the links'
        tangents (links couple neighbouring frames only; wider bands come from cables)."""
        t1, t2, t3, t4 = self._link_terms
        ab = link_tangents.take(t1)
        ab += link_tangents.take(t2)
        ab += link_tangents.take(t3)
        ab += link_tangents.take(t4)
        ab *= 0.5
        return ab.reshape(-1, self.n)

    def symmetric_from_storage(self, storage: np.ndarray) -> np.ndarray:
        """Lower band of the symmetric part ½(A + Aᵀ) of the blocks held in ``storage``."""
        ab = storage.take(self._sym_ij)
        ab += storage.take(self._sym_ji)
        ab *= 0.5
        return ab.reshape(self.kd + 1, self.n)

    def general_band(self, blocks: np.ndarray) -> np.ndarray:
        """General band storage (``3kd + 1`` rows) of the block bands."""
        ab = np.zeros((3 * self.kd + 1, self.n))
        flat = ab.ravel()
        flat[self._lower_target] = blocks[0].ravel()[self._lower_source]
        flat[self._upper_target] = blocks[1].ravel()[self._upper_source]
        return ab


class Tangent:
    """The tangent stiffness at one state: the links' tangents side by side (with the trailing
    zero) and, when cables or gravity act, their blocks in flat block storage. Its full block
    storage (LU and shifted LU factors) and the lower band of its symmetric part are assembled
    on first need and kept."""

    __slots__ = ("assembler", "links", "extra", "_storage", "_band")

    def __init__(self, assembler: BandAssembler, links: np.ndarray, extra: np.ndarray | None):
        self.assembler, self.links, self.extra = assembler, links, extra
        self._storage = None
        self._band = None

    def storage(self) -> np.ndarray:
        """Flat block storage of the whole tangent (read it through ``new_storage``'s view shape)."""
        if self._storage is None:
            storage, blocks = self.assembler.new_storage()
            if self.extra is not None:
                storage[:] = self.extra
            self.assembler.add_links(blocks, self.links)
            self._storage = storage
        return self._storage

    def blocks(self) -> np.ndarray:
        """``[lower, upper]`` block bands (2, n_blocks, span + 1, 6, 6) of the whole tangent."""
        return self.storage()[:-1].reshape((2,) + self.assembler.block_shape)

    def symmetric_band(self) -> np.ndarray:
        """LAPACK lower band of the tangent's symmetric part (kept: do not modify it)."""
        if self._band is None:
            assembler = self.assembler
            links = assembler.symmetric_from_links(self.links)
            if links.shape[0] == assembler.kd + 1 and self.extra is None:
                band = links
            else:
                band = (assembler.symmetric_from_storage(self.extra) if self.extra is not None
                        else np.zeros((assembler.kd + 1, assembler.n)))
                band[:links.shape[0]] += links
            self._band = band
        return self._band

    def diagonal(self) -> np.ndarray:
        """The tangent's diagonal (n,)."""
        return self.symmetric_band()[0]

    def factor(self, shift: float = 0.0, *, symmetric: bool = True, scale: np.ndarray | None = None,
               definite: bool = False) -> tuple[BandedFactor | None, str]:
        """Factor the tangent plus ``shift`` · diag(``scale``) (``scale`` (n,): default |diag|):
        banded Cholesky of its symmetric part when that is exact (``symmetric``: conservative
        loads) and positive definite, banded LU otherwise (never with ``definite``: a symmetric
        matrix that is not positive definite then gives no factor). Returns the factor (None
        when singular, or indefinite with ``definite``) and its kind: "cholesky", "shifted"
        (Cholesky of the shifted matrix), "lu" or "shifted-lu"."""
        assembler = self.assembler
        if shift and scale is None:
            scale = np.abs(self.diagonal()) + 1e-300
        if symmetric:
            band = self.symmetric_band()
            if shift:
                band = band.copy()
                band[0] += shift * scale
            factor = factor_cholesky(band)
            if factor is not None:
                return factor, ("shifted" if shift else "cholesky")
            if definite:
                return None, None
        storage = self.storage()
        if shift:
            storage = storage.copy()
            diagonal = assembler.diagonal(storage[:-1].reshape((2,) + assembler.block_shape))
            diagonal += np.einsum("ci,ij->cij", shift * scale.reshape(-1, 6), np.eye(6))
        blocks = storage[:-1].reshape((2,) + assembler.block_shape)
        factor = factor_lu(assembler.general_band(blocks), assembler.kd)
        return factor, ("shifted-lu" if shift else "lu") if factor is not None else None
