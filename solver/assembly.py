"""Assembly of the trunk's tangent into band storage: every index map in one place.

The tangent couples only frames joined by a link (block offset 1) or by a cable piece (offset
= links per repetition), so it is block-banded with 6×6 blocks over the free frames. Its terms
are written side by side in one flat array, the *terms* (:meth:`BandAssembler.new_terms`):

* the links' 12×12 tangents, one per link;
* the cables' 12×12 tangents, summed over the pieces that join the same two frames (one per
  pair of frames, :attr:`BandAssembler.cable_groups`);
* the turning of frame-fixed loads, a 6×3 block of each free frame's force and moment rows on
  its rotation (when the trunk has gravity — the weight's lever arms turn — or follower loads);
* one trailing zero.

:class:`BandAssembler` holds the maps, computed once per model, that take the terms to LAPACK
band storage — the lower band of the symmetric part for ``dpbtrf`` in one gather and one
sum, and the *block bands* (``lower[c, s] = A[c+s, c]``, ``upper[c, s] = A[c, c+s]``,
stacked in one flat *storage* with a trailing zero) from which the general band for ``dgbtrf``
is gathered — without any dense or general sparse global matrix. :class:`Tangent` is one
tangent's terms and factorises it (:mod:`vertebra.solver.banded`).
"""

from __future__ import annotations

import numpy as np

from vertebra.solver.banded import BandedFactor, LowRankFactor, factor_cholesky, factor_lu


_NO_PIECES = np.zeros(0, int)


def _as_slice(index: np.ndarray):
    """``index`` (increasing, non-negative) as the slice that takes the same entries when they are
    evenly spaced, else as it is."""
    if index.size == 0:
        return index
    step = int(index[1] - index[0]) if index.size > 1 else 1
    if step > 0 and np.array_equal(index, index[0] + step * np.arange(index.size)):
        return slice(int(index[0]), int(index[-1]) + 1, step)
    return index


class BandAssembler:
    """Index maps from the tangent's terms to LAPACK band storage for ``n_blocks`` free frames
    whose couplings reach ``span`` blocks, cable pieces joining frames ``piece_a`` → ``piece_b``
    (sorted by a, then b) and, with ``turning``, the turning blocks of frame-fixed loads (frame 0
    is the clamped base, block k is frame k + 1, link k joins frames k and k + 1)."""

    def __init__(self, n_blocks: int, span: int, piece_a: np.ndarray = _NO_PIECES, piece_b: np.ndarray = _NO_PIECES,
                 turning: bool = False, coupled: np.ndarray = _NO_PIECES):
        coupled = np.asarray(coupled, int).reshape(-1, 2)          # (k, 2) frames a < b other terms couple
        span = max(span, int(np.max(coupled[:, 1] - coupled[:, 0], initial=0)))
        if np.any(piece_b - piece_a > span):
            raise ValueError(f"cable pieces couple frames up to {int(np.max(piece_b - piece_a))} apart; span is {span}")
        self.n_blocks = nb = n_blocks
        self.span = span
        self.n = n = 6 * nb
        self.kd = kd = min(6 * (span + 1) - 1, max(n - 1, 0))
        self.block_shape = (nb, span + 1, 6, 6)
        self._per_band = per_band = nb * (span + 1) * 36
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
        zero = self.storage_size - 1
        sym_ij = np.where(inside, self._flat(0, J, s, a, b), zero).ravel()                    # lower[J, s, a, b]
        sym_ji = np.where(inside, np.where(s == 0, self._flat(0, J, 0, b, a), self._flat(1, J, s, b, a)), zero).ravel()
        self._sym_ij, self._sym_ji = sym_ij, sym_ji
        # cable pieces: the pairs of frames they join, and the pieces of each pair padded with
        # piece_a.size (no piece), CablePieces.tangent's groups
        first = np.flatnonzero(np.r_[piece_a.size > 0, (piece_a[1:] != piece_a[:-1]) | (piece_b[1:] != piece_b[:-1])])
        self.pair_a, self.pair_b = piece_a[first], piece_b[first]
        counts = np.diff(np.r_[first, piece_a.size])
        slot = np.arange(int(counts.max(initial=0)))
        self.cable_groups = np.where(slot < counts[:, None], first[:, None] + slot, piece_a.size)
        # pairs of frames that the contacts between vertebra discs couple (solver/contact.py) and
        # no cable piece joins: a slot of their own among the cable pairs', with no piece
        joined = set(zip(self.pair_a.tolist(), self.pair_b.tolist()))
        extra = sorted({(a, b) for a, b in coupled.tolist() if (a, b) not in joined})
        if extra:
            self.pair_a = np.r_[self.pair_a, [a for a, _ in extra]]
            self.pair_b = np.r_[self.pair_b, [b for _, b in extra]]
            self.cable_groups = np.vstack([self.cable_groups,
                                           np.full((len(extra), self.cable_groups.shape[1]), piece_a.size)])
        first = self.pair_a
        # the terms: links, cable pairs, turning blocks, a zero
        self.n_pairs = first.size
        self._cable_start = nb * 144
        self._turning_start = self._cable_start + self.n_pairs * 144
        self.turning = turning
        self.terms_size = self._turning_start + (nb * 18 if turning else 0) + 1
        destination = self._term_destinations()
        self._storage_gather, band_gather = self._gathers(destination, sym_ij, sym_ji)
        self._band_matrix = self._summing_matrix(band_gather, 0.5)
        self._offsets = None               # the cable pairs by block offset (symmetric_bands), when first asked for
        self._band_index = None            # symmetric_bands' gather, when first asked for

    def _flat(self, band, c, offset, r, col):
        """Index in the flat storage of ``[lower, upper][band][c, offset, r, col]``."""
        return band * self._per_band + ((c * (self.span + 1) + offset) * 6 + r) * 6 + col

    def _term_destinations(self) -> np.ndarray:
        """Where each entry of the terms goes in the flat storage (−1: nowhere)."""
        nb = self.n_blocks
        destination = np.full(self.terms_size, -1)
        r, c = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
        r, c = r.ravel(), c.ravel()

        def place(start, k, a_block, b_block, free, offset):
            """12×12 terms number ``k`` (from ``start``) coupling blocks ``a_block`` → ``b_block``
            (``free``: a is a free frame) ``offset`` apart."""
            base = start + k[:, None] * 144
            destination[base + (6 + r) * 12 + 6 + c] = self._flat(0, b_block[:, None], 0, r, c)
            base, a_block, offset = base[free], a_block[free][:, None], offset[free][:, None]
            destination[base + r * 12 + c] = self._flat(0, a_block, 0, r, c)
            destination[base + (6 + r) * 12 + c] = self._flat(0, a_block, offset, r, c)
            destination[base + r * 12 + 6 + c] = self._flat(1, a_block, offset, r, c)

        links = np.arange(nb)
        place(0, links, links - 1, links, links > 0, np.ones(nb, int))
        pairs = np.arange(self.n_pairs)
        place(self._cable_start, pairs, self.pair_a - 1, self.pair_b - 1, self.pair_a > 0, self.pair_b - self.pair_a)
        if self.turning:
            r6, c3 = np.meshgrid(np.arange(6), np.arange(3), indexing="ij")
            destination[self._turning_start + links[:, None] * 18 + (r6 * 3 + c3).ravel()] = \
                self._flat(0, links[:, None], 0, r6.ravel(), 3 + c3.ravel())
        return destination

    def _gathers(self, destination: np.ndarray, sym_ij: np.ndarray, sym_ji: np.ndarray) -> tuple:
        """Indices (k, entries) into the terms whose sum over the first axis gives every storage
        entry, and every entry of the symmetric band (twice: ``A[i, j] + A[j, i]``); ``k`` is the
        most terms any entry gathers, and the shorter columns point to the terms' zero."""
        positions = self.storage_size - 1
        zero = self.terms_size - 1
        source = np.flatnonzero(destination >= 0)
        target = destination[source]
        order = np.argsort(target, kind="stable")
        source, target = source[order], target[order]
        count = np.bincount(target, minlength=positions + 1)        # position `positions`: outside, none
        first = np.cumsum(count) - count

        def gather(*where):
            counts = [count[p] for p in where]
            indices = np.full((max(1, int(sum(counts).max(initial=0))), where[0].size), zero)
            at = np.zeros(where[0].size, int)
            for p, k in zip(where, counts):
                entry = np.repeat(np.arange(p.size), k)
                rank = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
                indices[at[entry] + rank, entry] = source[first[p[entry]] + rank]
                at += k
            return indices

        return gather(np.arange(positions)), gather(sym_ij, sym_ji)

    def _summing_matrix(self, gather: np.ndarray, weight: float):
        """The sparse matrix (CSR, entries × terms) whose product with the terms is ``weight`` times
        the sums of a gather (:meth:`_gathers`): each row keeps its column's indices in the gather's
        order, without those of the terms' zero. With ``weight`` a power of two its products are
        the gather's sums scaled, to the bit: the same additions in the same order, without the
        padding (most of a band's gather: an entry of a block coupling a cable pair sums up to 10
        terms, most entries one or two)."""
        from scipy.sparse import csr_array

        real = gather != self.terms_size - 1
        entry, row = np.nonzero(real.T)           # entry by entry, each in the gather's order
        indptr = np.zeros(gather.shape[1] + 1, dtype=np.int32)
        np.cumsum(real.sum(axis=0), out=indptr[1:])
        return csr_array((np.full(entry.size, weight), gather[row, entry].astype(np.int32), indptr),
                         shape=(gather.shape[1], self.terms_size))

    # ------------------------------------------------------------------ terms
    def new_terms(self) -> tuple:
        """Uninitialised terms (their trailing zero set) and the views to fill (:meth:`views`)."""
        terms = np.empty(self.terms_size)
        terms[-1] = 0.0
        return (terms,) + self.views(terms)

    def views(self, terms: np.ndarray) -> tuple:
        """The parts of ``terms``: the links' tangents (n_blocks, 12, 12), the cable pairs'
        (n_pairs, 12, 12) and the turning blocks (n_blocks, 6, 3: each free frame's force and
        moment rows on its rotation; None without gravity and follower loads)."""
        nb = self.n_blocks
        links = terms[:self._cable_start].reshape(nb, 12, 12)
        cables = terms[self._cable_start:self._turning_start].reshape(self.n_pairs, 12, 12)
        turning = terms[self._turning_start:-1].reshape(nb, 6, 3) if self.turning else None
        return links, cables, turning

    def storage_of(self, terms: np.ndarray) -> np.ndarray:
        """Flat block storage (with its trailing zero) of the tangent whose terms are ``terms``."""
        storage = np.empty(self.storage_size)
        np.add.reduce(terms.take(self._storage_gather, mode="clip"), axis=0, out=storage[:-1])
        storage[-1] = 0.0
        return storage

    def symmetric_band_of(self, terms: np.ndarray) -> np.ndarray:
        """Lower band (kd + 1, n) of the symmetric part of the tangent whose terms are ``terms``."""
        return (self._band_matrix @ terms).reshape(self.kd + 1, self.n)

    def symmetric_bands(self, links: np.ndarray, cables: np.ndarray | None, weight: np.ndarray | None) -> np.ndarray:
        """LAPACK lower bands of the symmetric parts ½(A + Aᵀ) of a batch of tangents given by their
        terms — the links' (B, n_blocks, 12, 12), the cable pairs' (B, n_pairs, 12, 12) and the
        weight's (B, n_blocks, 3, 3) (None: none) — as (B, n, kd + 1) with ``[:, j, d] = A[j + d, j]``:
        each sample's ``[i].T`` is the (kd + 1, n) Fortran-ordered band ``dpbtrf`` factors in place
        (:func:`~vertebra.solver.banded.factor_cholesky_batch`). Each term's 6×6 blocks are added
        where they couple (one batched sum per block offset) into the lower block band, whose
        entries one gather puts in band order."""
        nb = self.n_blocks
        B = links.size // (nb * 144)
        S = np.zeros((B,) + self.block_shape)               # the lower block band
        H = links.reshape(B, nb, 2, 6, 2, 6)                # link k joins blocks k − 1 (a) and k (b)
        S[:, :, 0] += H[:, :, 1, :, 1, :]
        S[:, :-1, 0] += H[:, 1:, 0, :, 0, :]
        S[:, :-1, 1] += H[:, 1:, 1, :, 0, :] + H[:, 1:, 0, :, 1, :].mT
        if cables is not None and self.n_pairs:
            C = cables.reshape(B, self.n_pairs, 2, 6, 2, 6)
            aa, ab, ba, bb = C[:, :, 0, :, 0, :], C[:, :, 0, :, 1, :], C[:, :, 1, :, 0, :], C[:, :, 1, :, 1, :]
            for offset, pairs, b, free_pairs, a in self._pair_offsets():
                S[:, b, 0] += bb[:, pairs]
                S[:, a, 0] += aa[:, free_pairs]
                S[:, a, offset] += ba[:, free_pairs] + ab[:, free_pairs].mT
        if weight is not None:
            S[:, :, 0, 3:, 3:] += weight
        diagonal = S[:, :, 0]
        S[:, :, 0] = diagonal + diagonal.mT
        bands = S.reshape(B, -1)[:, self._band_of_blocks()].reshape(B, self.n, self.kd + 1)
        bands *= 0.5
        return bands

    def _band_of_blocks(self) -> np.ndarray:
        """(n · (kd + 1),): for every entry ``[j, d]`` of a transposed lower band, its place in a
        flattened lower block band; an entry outside the block band or the matrix takes the block
        band's last entry, ``[n_blocks − 1, span, 5, 5]``, which lies outside the matrix (no term
        is added there: it stays zero)."""
        if self._band_index is None:
            nb, span, kd = self.n_blocks, self.span, self.kd
            j, d = np.meshgrid(np.arange(self.n), np.arange(kd + 1), indexing="ij")
            i = j + d
            J, s = j // 6, i // 6 - j // 6
            inside = (i < self.n) & (s <= span)
            self._band_index = np.where(inside, self._flat(0, J, np.minimum(s, span), i % 6, j % 6),
                                        self._per_band - 1).ravel()
        return self._band_index

    def _pair_offsets(self) -> list:
        """The cable pairs by block offset: (offset, pairs, their blocks b, the pairs whose block a
        is free, those blocks a), each with distinct blocks (so that one batched sum per offset adds
        no block twice). Evenly spaced indices (the usual routing: a cable pair every few blocks)
        are slices, so that the sums are taken on views rather than by gathers and scatters."""
        if self._offsets is None:
            gap = self.pair_b - self.pair_a
            self._offsets = []
            for o in np.unique(gap):
                pairs = np.flatnonzero(gap == o)
                free = self.pair_a[pairs] > 0
                self._offsets.append((int(o), _as_slice(pairs), _as_slice(self.pair_b[pairs] - 1),
                                      _as_slice(pairs[free]), _as_slice(self.pair_a[pairs][free] - 1)))
        return self._offsets

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

    def symmetric_from_storage(self, storage: np.ndarray) -> np.ndarray:
        """Lower band of the symmetric part ½(A + Aᵀ) of the blocks held in ``storage``."""
        ab = storage.take(self._sym_ij, mode="clip")       # indices made with the assembler (clip: no check)
        ab += storage.take(self._sym_ji, mode="clip")
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
    """The tangent stiffness at one state: its terms side by side (:meth:`BandAssembler.new_terms`).
    The lower band of its symmetric part and its full block storage (LU and shifted LU factors)
    are assembled on first need and kept."""

    __slots__ = ("assembler", "terms", "low_rank", "_storage", "_band")

    def __init__(self, assembler: BandAssembler, terms: np.ndarray, low_rank: tuple | None = None):
        self.assembler, self.terms = assembler, terms
        self.low_rank = low_rank      # (U (n, r), d (r,)): a dense term U diag(d) Uᵀ beside the band, or None
        self._storage = None
        self._band = None

    def storage(self) -> np.ndarray:
        """Flat block storage of the whole tangent (read it through ``new_storage``'s view shape)."""
        if self._storage is None:
            self._storage = self.assembler.storage_of(self.terms)
        return self._storage

    def blocks(self) -> np.ndarray:
        """``[lower, upper]`` block bands (2, n_blocks, span + 1, 6, 6) of the whole tangent."""
        return self.storage()[:-1].reshape((2,) + self.assembler.block_shape)

    def symmetric_band(self) -> np.ndarray:
        """LAPACK lower band of the tangent's symmetric part (kept: do not modify it)."""
        if self._band is None:
            self._band = self.assembler.symmetric_band_of(self.terms)
        return self._band

    def diagonal(self) -> np.ndarray:
        """The tangent's diagonal (n,), the dense term's included."""
        if self.low_rank is None:
            return self.symmetric_band()[0]
        U, d = self.low_rank
        return self.symmetric_band()[0] + (U * U) @ d

    def quadratic(self, p: np.ndarray) -> float:
        """``pᵀHp`` (the symmetric part's: the dense term's included)."""
        band = self.symmetric_band()
        n = band.shape[1]
        Hp = band[0] * p
        for k in range(1, band.shape[0]):              # row j + k, column j of the lower band, and its mirror
            Hp[k:] += band[k, :n - k] * p[:n - k]
            Hp[:n - k] += band[k, :n - k] * p[k:]
        value = float(p @ Hp)
        if self.low_rank is not None:
            U, d = self.low_rank
            Up = U.T @ p
            value += float(d @ (Up * Up))
        return value

    def factor(self, shift: float = 0.0, *, symmetric: bool = True, scale: np.ndarray | None = None,
               definite: bool = False) -> tuple[BandedFactor | None, str]:
        """Factor the tangent plus ``shift`` · diag(``scale``) (``scale`` (n,): default |diag|):
        banded Cholesky of its symmetric part when that is exact (``symmetric``: conservative
        loads) and positive definite, banded LU otherwise (never with ``definite``: a symmetric
        matrix that is not positive definite then gives no factor). Returns the factor (None
        when singular, or indefinite with ``definite``) and its kind: "cholesky", "shifted"
        (Cholesky of the shifted matrix), "lu" or "shifted-lu". With a dense term beside the
        band the factor is the band's, updated (:class:`~vertebra.solver.banded.LowRankFactor`):
        the band alone decides definiteness (the dense term is positive semi-definite)."""
        if shift and scale is None:
            scale = np.abs(self.diagonal()) + 1e-300
        factor, kind = self._band_factor(shift, symmetric, scale, definite)
        if self.low_rank is None:
            return factor, kind
        if factor is not None:
            return LowRankFactor.of(factor, *self.low_rank), kind
        if not (symmetric and definite):
            return None, None
        # the band is not positive definite; the whole may be (the tendons' term is semi-definite)
        band = self.symmetric_band()
        if shift:
            band = band.copy()
            band[0] += shift * scale
        factor = LowRankFactor.definite(band, *self.low_rank)
        return (factor, ("shifted" if shift else "cholesky")) if factor is not None else (None, None)

    def _band_factor(self, shift, symmetric, scale, definite):
        assembler = self.assembler
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
