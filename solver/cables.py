"""Cables: their routing through the vertebrae's holes, and the closed-form kinematics of their pieces.

A cable runs from the hole of vertebra ``from − 1`` through the holes of vertebrae
``from … to`` and is terminated at ``to``; each stretch between two consecutive vertebrae is a
*piece* between two frames. Frictionless: the potential is ``τ L(q)`` with
``L = Σ |P_b − P_a|`` over the cable's pieces.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.lie import HAT_TABLE, qrotate

_C_CONST = np.zeros((12, 3))
_C_CONST[:3], _C_CONST[6:9] = -np.eye(3), np.eye(3)
_C_TABLE = np.zeros((6, 12, 3))
_C_TABLE[:3, 3:6] = -HAT_TABLE.reshape(3, 3, 3)        # −ŝ_a
_C_TABLE[3:, 9:] = HAT_TABLE.reshape(3, 3, 3)          # ŝ_b
_C_TABLE = _C_TABLE.reshape(6, 36)


def _group_table() -> np.ndarray:
    """(70, 144): the part ``Σ t (C Cᵀ + (−û ŝ_a on dφ_a) + (û ŝ_b on dφ_b)) |d|`` of a group's
    tangent (:meth:`CablePieces.tangent`) from the moments ``Σ t x yᵀ`` with ``x = [1, s_a, s_b]``,
    ``y = [1, s_a, s_b, d]`` and ``t = τ/|d|``. Blocks (x_a, φ_a, x_b, φ_b) of ``C Cᵀ``:
    ``[[I, −ŝ_a, −I, ŝ_b], [ŝ_a, |s_a|²I − s_a s_aᵀ, −ŝ_a, s_b s_aᵀ − (s_a·s_b)I], …]`` (symmetric),
    and ``û ŝ = s uᵀ − (u·s) I`` with ``τ u = t d``."""
    hat = HAT_TABLE.reshape(3, 3, 3)          # hat[k] = ê_k^
    table = np.zeros((7, 10, 12, 12))
    eye = np.eye(3)
    block = [slice(3 * i, 3 * i + 3) for i in range(4)]
    a, b, d = (1, 2, 3), (4, 5, 6), (7, 8, 9)      # rows/columns of s_a, s_b, d among the moments
    for i, j, sign in ((0, 0, 1), (0, 2, -1), (2, 0, -1), (2, 2, 1)):
        table[0, 0, block[i], block[j]] += sign * eye
    for k in range(3):
        for i, j, sign in ((0, 1, -1), (1, 0, 1), (1, 2, -1), (2, 1, 1)):     # ±ŝ_a
            table[0, a[k], block[i], block[j]] += sign * hat[k]
        for i, j, sign in ((0, 3, 1), (3, 0, -1), (2, 3, -1), (3, 2, 1)):     # ±ŝ_b
            table[0, b[k], block[i], block[j]] += sign * hat[k]
        for l in range(3):
            table[a[k], a[l], 3 + k, 3 + l] -= 1.0           # −s_a s_aᵀ
            table[b[k], b[l], 9 + k, 9 + l] -= 1.0           # −s_b s_bᵀ
            table[b[k], a[l], 3 + k, 9 + l] += 1.0           # s_b s_aᵀ on (φ_a, φ_b)
            table[a[k], b[l], 9 + k, 3 + l] += 1.0           # s_a s_bᵀ on (φ_b, φ_a)
            table[a[k], d[l], 3 + k, 3 + l] -= 1.0           # −τ s_a uᵀ
            table[b[k], d[l], 9 + k, 9 + l] += 1.0           # τ s_b uᵀ
        table[a[k], a[k], block[1], block[1]] += eye         # |s_a|² I
        table[b[k], b[k], block[3], block[3]] += eye         # |s_b|² I
        table[a[k], b[k], block[1], block[3]] -= eye         # −(s_a·s_b) I
        table[a[k], b[k], block[3], block[1]] -= eye
        table[a[k], d[k], block[1], block[1]] += eye         # τ (u·s_a) I
        table[b[k], d[k], block[3], block[3]] -= eye         # −τ (u·s_b) I
    return table.reshape(70, 144)


_GROUP_TABLE = _group_table()
# (a × b)_i = a_{i+1} b_{i+2} − a_{i+2} b_{i+1}: the cross products of the pieces' kinematics as
# elementwise products of two gathers (one product for all the terms, whatever the number of rows).
# These constant indices are taken with ``mode="clip"``: numpy's default mode checks every index and
# gathers a few columns of many rows 2–4× slower (1.6 against 0.4 ms for 56,000 rows; 1.2 against
# 0.6 µs for a tick's 56)
_UNIT_OFFSETS = np.array([1, 2, 0, 4, 5, 3, 2, 0, 1, 5, 3, 4])       # [s_a, s_b] at i+1, then at i+2
_UNIT_SPAN = np.array([2, 0, 1, 2, 0, 1, 1, 2, 0, 1, 2, 0])          # u at i+2, then at i+1
_CHANGE_OFFSETS = np.array([1, 2, 0, 2, 0, 1, 5, 3, 4, 4, 5, 3])     # s_a at i+1, i+2; s_b at i+2, i+1
_CHANGE_MOVES = np.array([5, 3, 4, 4, 5, 3, 10, 11, 9, 11, 9, 10])   # dφ_a at i+2, i+1; dφ_b at i+1, i+2


@dataclass
class CablePieces:
    """Kinematics of cable pieces between holes ``r_a``, ``r_b`` of two frames.

    With ``s = R r``, ``d = P_b − P_a``, ``u = d/|d|`` and ``C = [−I; −ŝ_a; I; ŝ_b]`` (12×3), the
    change of ``d`` under frame increments is ``Cᵀ dq``, so the gradient of the length is
    ``C u = [−u; −s_a × u; u; s_b × u]`` and the tangent of ``τ|d|`` is
    ``τ (C Π Cᵀ − (û ŝ_a on dφ_a) + (û ŝ_b on dφ_b))``, ``Π = (I − uuᵀ)/|d|``: one evaluation
    serves the forces, the tangent, the actuator Jacobian (unit tension) and the cable lengths."""

    u: np.ndarray          # (m, 3)
    length: np.ndarray     # (m,)
    unit: np.ndarray       # (m, 12) gradient of the length
    offsets: np.ndarray    # (m, 6) [s_a, s_b]
    d: np.ndarray          # (m, 3) P_b − P_a

    @property
    def C(self) -> np.ndarray:
        """(m, 12, 3) ``[−I; −ŝ_a; I; ŝ_b]``: the change of ``d`` is ``Cᵀ dq`` (made when asked)."""
        return (self.offsets @ _C_TABLE).reshape(-1, 12, 3) + _C_CONST

    @classmethod
    def of(cls, Ra, xa, Rb, xb, hole_a, hole_b) -> "CablePieces":
        m = xa.shape[0]
        return cls.of_pairs(np.stack([Ra, Rb], 1).reshape(2 * m, 3, 3), np.stack([xa, xb], 1).reshape(2 * m, 3),
                            np.stack([hole_a, hole_b], 1).reshape(2 * m, 3, 1))

    @classmethod
    def of_pairs(cls, R, x, holes) -> "CablePieces":
        """From the rotations (2m, 3, 3), positions (2m, 3) and hole offsets (2m, 3, 1) of the two
        ends of every piece, interleaved (a₀, b₀, a₁, b₁, …)."""
        return cls.of_spans(*_spans(R, x, holes))

    @classmethod
    def of_spans(cls, offsets, d, length) -> "CablePieces":
        """From the pieces' hole offsets ``[s_a, s_b]`` (m, 6), spans (m, 3) and lengths (m,)
        (:meth:`CableRouting.spans`)."""
        m = d.shape[0]
        u = d / length[:, None]
        terms = offsets.take(_UNIT_OFFSETS, 1, mode="clip")     # the terms of s_a × u and s_b × u
        terms *= u.take(_UNIT_SPAN, 1, mode="clip")
        unit = np.empty((m, 12))
        np.negative(u, out=unit[:, 0:3])
        unit[:, 6:9] = u
        np.subtract(terms[:, 6:9], terms[:, 0:3], out=unit[:, 3:6])      # −s_a × u
        np.subtract(terms[:, 3:6], terms[:, 9:12], out=unit[:, 9:12])    # s_b × u
        return cls(u, length, unit, offsets, d)

    def change(self, moves: np.ndarray) -> np.ndarray:
        """``Δd = Cᵀ [dq_a; dq_b]`` (m, 3), the linearised change of every piece's span under the
        increments ``moves`` (m, 12) of its two frames: ``dx_b − dx_a − dφ_a × s_a + dφ_b × s_b``."""
        terms = self.offsets.take(_CHANGE_OFFSETS, 1, mode="clip")   # the terms of s_a × dφ_a and dφ_b × s_b
        terms *= moves.take(_CHANGE_MOVES, 1, mode="clip")
        delta = moves[:, 6:9] - moves[:, 0:3]
        delta += terms[:, 0:3]
        delta -= terms[:, 3:6]
        delta += terms[:, 6:9]
        delta -= terms[:, 9:12]
        return delta

    def tangent(self, tension: np.ndarray, groups: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """Tangent (g, 12, 12) of ``Σ τ |d|`` over each group of pieces that join the same two
        frames: ``groups`` (g, k) holds piece indices, padded with m (no piece); default: every
        piece alone. With ``t = τ/|d|`` and ``g = C u`` a piece's tangent is
        ``t C Cᵀ − t g gᵀ − τ û ŝ_a (on dφ_a) + τ û ŝ_b (on dφ_b)``: every term but ``t g gᵀ`` is
        linear in the moments ``t x yᵀ`` (:func:`_group_table`), so a group's tangent comes from
        the sums of the moments and of ``t g gᵀ`` over its pieces — one batched product.
        ``out``: a C-contiguous (g, 12, 12) array to write into."""
        m = self.length.shape[0]
        if groups is None:
            groups = np.arange(m)[:, None]
        t = np.zeros(m + 1)
        np.divide(tension, self.length, out=t[:m])
        Y = np.zeros((m + 1, 22))                             # [1, s_a, s_b, d, g]; row m: no piece
        Y[:m, 0] = 1.0
        Y[:m, 1:7] = self.offsets
        Y[:m, 7:10] = self.d
        Y[:m, 10:] = self.unit
        grouped = Y.take(groups, 0)                           # (g, k, 22)
        weighted = grouped * t.take(groups)[:, :, None]
        moments = grouped[:, :, :7].mT @ weighted[:, :, :10]  # Σ t x yᵀ (the two products needed, not
        if out is None:                                       # the whole 22 × 22)
            out = np.empty((groups.shape[0], 12, 12))
        np.dot(moments.reshape(-1, 70), _GROUP_TABLE, out=out.reshape(-1, 144))
        out -= grouped[:, :, 10:].mT @ weighted[:, :, 10:]    # Σ t g gᵀ
        return out


def _spans(R, x, holes):
    """Hole offsets ``[s_a, s_b]`` (m, 6), spans ``d = P_b − P_a`` (m, 3) and lengths (m,) of the
    pieces whose ends have rotations ``R`` (2m, 3, 3), positions ``x`` (2m, 3) and hole offsets
    ``holes`` (2m, 3, 1), interleaved."""
    offsets = (R @ holes).reshape(-1, 3)
    ends = x + offsets
    d = ends[1::2] - ends[::2]
    return offsets.reshape(-1, 6), d, np.sqrt(np.add.reduce(d * d, 1))


def hole_offsets(radius: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Hole offsets (n, 3) in a vertebra's frame at distance ``radius`` from the axis and ``angle``
    about local +z from local +x."""
    return np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(radius)], 1)


def scatter_rows(rows: np.ndarray, values: np.ndarray, n_rows: int, flat: np.ndarray | None = None) -> np.ndarray:
    """``E @ values`` for the incidence ``E`` (n_rows, len(rows)) with a 1 at (rows[k], k): the
    rows of ``values`` (len(rows), c) summed into their targets, by one ``bincount`` (no matrix;
    ``flat``: the flat targets ``rows·c + column`` when already made)."""
    c = values.shape[1]
    if flat is None:
        flat = (rows[:, None] * c + np.arange(c)).reshape(-1)
    return np.bincount(flat, values.reshape(-1), minlength=n_rows * c).reshape(n_rows, c)


def _turn_index(ends: np.ndarray, holes: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct holes (K, 3) of the pieces (``holes`` (m, 3), the same at both ends) and, for
    every piece end (frames ``ends`` (2m,)), the flat indices (2m, 3) of its turned hole's
    components among the frames' turned holes (n_frames, 3, K)."""
    end_holes = np.repeat(holes, 2, axis=0)
    if not end_holes.size:
        return np.zeros((1, 3)), np.zeros((0, 3), int)
    hole_set, which = np.unique(end_holes, axis=0, return_inverse=True)
    K = hole_set.shape[0]
    index = ends[:, None] * 3 * K + np.arange(3)[None, :] * K + which.reshape(-1)[:, None]
    return hole_set, index


def _jacobian_ends(owner: np.ndarray, a: np.ndarray, b: np.ndarray, n_cables: int, n_frames: int) -> np.ndarray:
    """(2, n_cables·n_frames): for every (cable, frame) row of the cables' Jacobian, the row of the
    piece ends' gradients (``unit.reshape(-1, 6)``: piece k's a end is row 2k, its b end 2k + 1)
    of the cable's piece that starts at the frame and of the one that ends there; 2m where none
    does (a cable passes each frame once)."""
    m = owner.size
    ends = np.full((2, n_cables * n_frames), 2 * m)
    ends[0, owner * n_frames + a] = 2 * np.arange(m)
    ends[1, owner * n_frames + b] = 2 * np.arange(m) + 1
    return ends


@dataclass(frozen=True)
class CableRouting:
    """The pieces of every cable, sorted by the pair of frames they join (a, then b)."""

    n_cables: int
    n_frames: int
    piece_a: np.ndarray        # (m,) frame of each piece's first hole
    piece_b: np.ndarray        # (m,) frame of its second hole
    hole_a: np.ndarray         # (m, 3) hole offset in frame a
    hole_b: np.ndarray         # (m, 3) hole offset in frame b
    owner: np.ndarray          # (m,) cable of each piece
    ends: np.ndarray           # (2m,) frames a₀ b₀ a₁ b₁ …
    holes: np.ndarray          # (2m, 3, 1) hole offsets in the same order
    frame_targets: np.ndarray  # (2m·6,) flat (frame, component) of each piece end's six entries
    jacobian_ends: np.ndarray  # (2, n_cables·n_frames): the piece-end rows (2m: none) whose length gradients
                               # make each (cable, frame) row of the Jacobian: the piece starting there, the one ending there
    hole_set: np.ndarray       # (K, 3) the distinct hole offsets
    turn_index: np.ndarray     # (2m, 3) where each piece end's turned hole sits among the frames' turned holes
                               # (the flat (n_frames, 3, K) products R_f hole_setᵀ: see spans)

    @classmethod
    def of(cls, cables, vertebra_frames: np.ndarray, n_frames: int) -> "CableRouting":
        """From the scene's cables and the frame index of each vertebra."""
        pa, pb, ha, owner = [], [], [], []
        for c, cable in enumerate(cables):
            hole = hole_offsets(np.array([cable.radius]), np.array([cable.angle]))[0]
            route = [vertebra_frames[v] for v in range(cable.first - 1, cable.last + 1)]
            for f_a, f_b in zip(route[:-1], route[1:]):
                pa.append(f_a), pb.append(f_b), ha.append(hole), owner.append(c)
        order = np.lexsort((np.array(pb, int), np.array(pa, int)))
        a, b = np.array(pa, int)[order], np.array(pb, int)[order]
        hole = np.array(ha).reshape(-1, 3)[order]
        owner = np.array(owner, int)[order]
        ends = np.stack([a, b], 1).reshape(-1)
        return cls(len(cables), n_frames, a, b, hole, hole.copy(), owner, ends,
                   np.stack([hole, hole], 1).reshape(-1, 3, 1), (ends[:, None] * 6 + np.arange(6)).reshape(-1),
                   _jacobian_ends(owner, a, b, len(cables), n_frames), *_turn_index(ends, hole, n_frames))

    def with_holes(self, radius: np.ndarray, angle: np.ndarray) -> "CableRouting":
        """The routing with every cable's holes at distance ``radius`` (n_cables,) from the axis and
        at ``angle`` (n_cables,) about local +z from local +x, in every vertebra it passes."""
        holes = hole_offsets(radius, angle)[self.owner]
        hole_set, turn_index = _turn_index(self.ends, holes, self.n_frames)
        return dataclasses.replace(self, hole_a=holes, hole_b=holes.copy(),
                                   holes=np.stack([holes, holes], 1).reshape(-1, 3, 1), hole_set=hole_set,
                                   turn_index=turn_index)

    @property
    def span(self) -> int:
        """Largest block offset a piece couples (links couple neighbours: at least 1)."""
        return int(max(1, np.max(self.piece_b - self.piece_a, initial=1)))

    def pieces(self, positions: np.ndarray, rotations: np.ndarray) -> CablePieces:
        """Kinematics of every piece at frame ``positions`` (N, 3) and ``rotations`` (N, 3, 3)."""
        return CablePieces.of_pairs(rotations.take(self.ends, 0), positions.take(self.ends, 0), self.holes)

    def spans(self, positions: np.ndarray, rotations: np.ndarray) -> tuple:
        """Hole offsets ``[s_a, s_b]`` (m, 6), spans ``d = P_b − P_a`` (m, 3) and lengths (m,) of
        the pieces at frame ``positions`` (N, 3) and ``rotations`` (N, 3, 3): their lengths without
        the kinematics (:meth:`CablePieces.of_spans` completes them). Every frame turns the few
        distinct holes in one product (``R hole_setᵀ`` for all frames at once), and each piece
        end takes its own. With leading batch axes (B, N, …): the B·m pieces as rows, sample by sample."""
        lead = rotations.shape[:-3]
        turned = rotations.reshape(-1, 3).dot(self.hole_set.T).reshape(lead + (-1,))
        offsets = turned.take(self.turn_index, axis=-1)                     # (…, 2m, 3)
        ends = positions.take(self.ends, axis=-2)
        ends += offsets
        d = ends[..., 1::2, :] - ends[..., ::2, :]
        d = d.reshape(-1, 3)
        return offsets.reshape(-1, 6), d, np.sqrt(np.add.reduce(d * d, 1))

    def lengths(self, pieces: CablePieces) -> np.ndarray:
        """Length of each cable (sum of its pieces)."""
        return np.bincount(self.owner, pieces.length, minlength=self.n_cables)

    def frame_forces(self, pieces: CablePieces, piece_tension: np.ndarray) -> np.ndarray:
        """Gradient (n_frames, 6) of ``Σ τ L`` with the tension of each piece."""
        return scatter_rows(self.ends, (piece_tension[:, None] * pieces.unit).reshape(-1, 6), self.n_frames,
                            self.frame_targets)

    def jacobian(self, pieces: CablePieces) -> np.ndarray:
        """``∂L/∂q`` (n_cables, n_frames, 6) of every cable: on each frame, the length gradients of
        the cable's piece starting there and of its piece ending there (two gathers)."""
        ends = np.empty((2 * pieces.unit.shape[0] + 1, 6))       # the piece ends' gradients, then a zero row
        ends[:-1] = pieces.unit.reshape(-1, 6)
        ends[-1] = 0.0
        starting, ending = self.jacobian_ends
        jacobian = ends.take(starting, 0)
        jacobian += ends.take(ending, 0)
        return jacobian.reshape(self.n_cables, self.n_frames, 6)

    def paths(self, positions: np.ndarray, quaternions: np.ndarray) -> list[np.ndarray]:
        """World polyline of each cable through its holes."""
        paths = []
        for k in range(self.n_cables):
            pieces = np.flatnonzero(self.owner == k)
            a, b = self.piece_a[pieces], self.piece_b[pieces]
            start = positions[a[:1]] + qrotate(quaternions[a[:1]], self.hole_a[pieces[:1]])
            rest = positions[b] + qrotate(quaternions[b], self.hole_b[pieces])
            paths.append(np.vstack([start, rest]))
        return paths
