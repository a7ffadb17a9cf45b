"""Many forward solves at once: B independent equilibria advanced together.

:func:`solve_batch` runs the forward solve of :mod:`vertebra.solver.newton` for a batch of
actuations (and start states) with every array carrying a leading sample axis: the chain of
poses (:func:`~vertebra.solver.chain.chain_poses`), the link kinematics and tangents
(:mod:`~vertebra.solver.links`, over the B·n links), the link energies (their ``prepare``,
``response`` and ``material_tangent`` take batches), the cable pieces
(:mod:`~vertebra.solver.cables`), the assembly (:meth:`BandAssembler.symmetric_bands`) and the
band's Cholesky factor of every sample (:func:`~vertebra.solver.banded.factor_cholesky_batch`). The
kernels are the single solve's own; what differs is the orchestration: per-sample masks, shifts,
step caps, line searches, load stages and convergence tests, each the single solve's rule
applied to every sample of the active set.

The batch follows the single solve's main path — (shifted) Cholesky steps, the strain-space step
caps, the backtracking line search on the energy, the adaptation of the shift, load stages from
rest, the representability checks and the stability test at convergence. A sample that leaves
it (a negative-curvature step, a step below the resolution of the poses, a stage that fails and
would be retried in smaller increments, a state the links cannot represent, a start state
without carried strains, non-finite values, dead moments (LU factors)) is solved again from its
own start by the single solve (``model.solve``), so its result, and its
failure message, are exactly the single solve's; ``BatchResult.single`` marks those samples.

Samples that converge leave the active set; a batch is cut into chunks whose working arrays stay
within a memory budget (:func:`chunk_size`).
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import math
import platform
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver import bounds, newton
from vertebra.solver.banded import factor_cholesky_batch
from vertebra.solver.cables import CablePieces
from vertebra.solver.chain import CARRY_ANGLE, chain_poses
from vertebra.solver.globalise import ARMIJO, NEUTRAL, ROUNDING, SEARCH_FLOOR
from vertebra.solver.links import Links, link_tangent
from vertebra.solver.newton import (BEND_SHIFT, BUDGET, MAX_STRETCH, MAX_TURN, RESOLUTION, SHIFT_CEILING,
                                    SHIFT_FLOOR, SHIFT_START, SQRT3, STRETCHING, TRUSTED_RESIDUAL)
from vertebra.solver.potential import out_of_range
from vertebra.solver.representable import COLLAPSE_LIMIT, FOLD_LIMIT, TURN_LIMIT
from vertebra.solver.state import compose as compose_state
from vertebra.core.lie import hat
from vertebra.core.errors import ConvergenceError

MEMORY_BUDGET = 256 * 2**20     # bytes of working arrays per chunk (see chunk_size)


def _c_mallopt():
    """glibc's ``mallopt``, or None under another C library (whose ``mallopt``, where it has one,
    does not number its parameters as glibc does)."""
    if platform.libc_ver()[0] != "glibc":
        return None
    try:
        return ctypes.CDLL(None).mallopt
    except (AttributeError, OSError, TypeError):
        return None


_MALLOPT = _c_mallopt()
_M_TOP_PAD = -2                  # glibc's mallopt parameter: free heap kept at the top when trimming
_TOP_PAD_DEFAULT = 128 * 1024    # glibc's default
_heap_lock = threading.Lock()
_heap_users = 0


@contextlib.contextmanager
def kept_heap():
    """While batches run, the C library keeps up to :data:`MEMORY_BUDGET` of freed memory at the
    top of its heap (glibc's ``mallopt(M_TOP_PAD)``) instead of giving it back to the kernel at
    every free. A batch allocates and frees arrays of 0.1–30 MB in every iteration; each page
    given back is zeroed and faulted in again at its next use (measured: 160,000–200,000 page faults
    and 0.3–0.5 s of system time in a 10,000-sample workspace of ``paper_5v_16t``, 10–13 % of its
    CPU time; none with the pad). The peak memory is unchanged (the pad is kept only as the heap's
    top shrinks); glibc's default (128 KiB) is restored when the outermost batch ends. Nothing
    where the C library has no ``mallopt``."""
    global _heap_users
    with _heap_lock:
        if _heap_users == 0 and _MALLOPT is not None:
            _MALLOPT(_M_TOP_PAD, MEMORY_BUDGET)
        _heap_users += 1
    try:
        yield
    finally:
        with _heap_lock:
            _heap_users -= 1
            if _heap_users == 0 and _MALLOPT is not None:
                _MALLOPT(_M_TOP_PAD, _TOP_PAD_DEFAULT)

# the single solve's failures a batch sample reports as its own (the single solve raised them)
_FAILURES = (ConvergenceError, FloatingPointError, ValueError, np.linalg.LinAlgError)


# ----------------------------------------------------------------------------- states
@dataclass
class States:
    """A batch of composed states: link strains ``xi`` (B, n, 6) and the chain composed from
    them (poses (B, N, …), link coefficients (B·n, 31), largest rotation² per sample)."""

    xi: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    rotations: np.ndarray
    coefficients: np.ndarray
    turns2: np.ndarray

    def __len__(self) -> int:
        return self.xi.shape[0]

    def take(self, rows: np.ndarray) -> "States":
        n = self.xi.shape[1]
        if not len(rows):
            return States(self.xi[:0], self.positions[:0], self.quaternions[:0], self.rotations[:0],
                          self.coefficients[:0], self.turns2[:0])
        coefficients = self.coefficients.reshape(len(self), n, -1)[rows].reshape(-1, self.coefficients.shape[1])
        return States(self.xi[rows], self.positions[rows], self.quaternions[rows], self.rotations[rows],
                      coefficients, self.turns2[rows])

    def put(self, rows: np.ndarray, other: "States") -> None:
        """Replace the samples ``rows`` by ``other``'s (in order)."""
        if not len(rows):
            return
        n = self.xi.shape[1]
        self.xi[rows], self.positions[rows], self.quaternions[rows] = other.xi, other.positions, other.quaternions
        self.rotations[rows], self.turns2[rows] = other.rotations, other.turns2
        self.coefficients.reshape(len(self), n, -1)[rows] = other.coefficients.reshape(len(other), n, -1)


def compose(trunk, xi: np.ndarray) -> tuple[States, np.ndarray]:
    """The states composed from link strains ``xi`` (B, n, 6) (:func:`vertebra.solver.state.compose`
    for a batch), and which of them carry their strains (every link turns less than
    :data:`~vertebra.solver.chain.CARRY_ANGLE`); the others' poses are not meaningful."""
    base = trunk.rest_state
    q0, x0 = base.quaternions[0], base.positions[0]
    chain = chain_poses(q0, x0, xi)
    carried = chain.largest_turns2 < CARRY_ANGLE ** 2
    if chain.link_coefficients is None:        # some sample turns beyond: compose the others alone
        rows = np.flatnonzero(carried)
        coefficients = np.zeros((xi.shape[0] * xi.shape[1], 31))
        if rows.size:
            inner, _ = compose(trunk, xi[rows])
            coefficients.reshape(xi.shape[0], xi.shape[1], 31)[rows] = inner.coefficients.reshape(rows.size, -1, 31)
            chain.positions[rows], chain.quaternions[rows] = inner.positions, inner.quaternions
            chain.rotations[rows] = inner.rotations
    else:
        coefficients = chain.link_coefficients
    chain.quaternions[:, 0], chain.positions[:, 0] = q0, x0
    return States(xi, chain.positions, chain.quaternions, chain.rotations, coefficients, chain.largest_turns2), carried


# ----------------------------------------------------------------------------- loads
@dataclass
class Loads:
    """The load cases of a batch: each sample's actuation at its own load factor (what
    :meth:`vertebra.solver.potential.LoadCase.of` makes of one)."""

    actuation: np.ndarray            # (B, n_act)
    scale: np.ndarray                # (B,)
    pressures: np.ndarray            # (B, chambers), scaled
    link_loads: tuple                # what each link energy prepared of the pressures (batched)
    piece_tension: np.ndarray | None     # (B, m) tension-driven cables' piece tensions (None: all slack)
    tendons: tuple | None            # (cables, k, L₀, shift (B, t)) of the stroke-driven tendons
    weight: np.ndarray | None        # (B, 3)
    weight_hat: np.ndarray | None    # (B, 3, 3)
    frame_weight: np.ndarray | None  # (B, N, 3)
    dead: np.ndarray | None          # (B, N, 6)

    @classmethod
    def of(cls, trunk, actuation: np.ndarray, scale: np.ndarray) -> "Loads":
        actuators = trunk.actuators
        n_cables = actuators.n_cables
        factor = scale[:, None]
        tensions = factor * actuation[:, :n_cables]
        pressures = factor * actuation[:, n_cables:]
        link_loads = tuple(e.prepare(pressures) for e in trunk.links.energies)
        tendons = None
        if n_cables and actuators.stroke_driven.any():
            cables = actuators.tendons
            k = actuators.cable_stiffness[cables]
            tendons = (cables, k, trunk.rest_cable_lengths[cables],
                       tensions[:, cables] + factor * (actuators.pretension[cables] / k))
            tensions = np.where(actuators.stroke_driven, 0.0, tensions)
        piece_tension = tensions.take(trunk.cables.owner, 1, mode="clip") if n_cables and np.any(tensions) else None
        weight = weight_hat = frame_weight = dead = None
        loads = trunk.loads
        if loads.has_gravity:
            weight = factor * loads.gravity
            weight_hat = hat(weight)
            frame_weight = trunk.frames.mass[:, None] * weight[:, None, :]
        if loads.has_dead_forces or loads.has_dead_moments:
            dead = scale[:, None, None] * loads.dead
        return cls(actuation, scale, pressures, link_loads, piece_tension, tendons, weight, weight_hat,
                   frame_weight, dead)

    @property
    def cables(self) -> bool:
        return self.piece_tension is not None or self.tendons is not None

    def take(self, trunk, rows: np.ndarray) -> "Loads":
        """The load cases of the samples ``rows`` (made again: the link energies prepare theirs)."""
        return Loads.of(trunk, self.actuation[rows], self.scale[rows])


# ----------------------------------------------------------------------------- evaluation
class _Context:
    """What a batch of samples of one trunk reuses: the quadratic links' constant material tangents as rows, kept for the largest batch asked for
    (a smaller batch takes their first rows), and each batch's cable groups."""

    def __init__(self, trunk):
        self.trunk = trunk
        self._kept = {}
        self._rest = None
        self._rest_tiled, self._rest_count = None, 0

    def rest(self, B):
        """The rest state of B samples and its :class:`Geometry`, composed once and repeated
        (every sample's reference force scale is taken there, under its own loads)."""
        if self._rest is None:
            trunk = self.trunk
            states, _ = compose(trunk, trunk.rest_state.strains.xi[None].copy())
            spans = pieces = None
            if trunk.cables.piece_a.size:
                spans = trunk.cables.spans(states.positions, states.rotations)
                pieces = CablePieces.of_spans(*spans)
            self._rest = states, Geometry(_links(states), spans, pieces)
        count = self._rest_count
        if count < B:                  # repeated for the largest batch asked; a smaller one takes views of it
            states, geometry = self._rest
            rows = np.zeros(B, int)
            self._rest_tiled, self._rest_count = (states.take(rows), _take(geometry, rows, 1)), B
            count = B
        return _samples(self._rest_tiled, 0, B, count)

    def _rows(self, key, B, make):
        """The first rows, for B samples, of what ``make(count)`` builds for ``count`` samples."""
        value, count = self._kept.get(key, (None, 0))
        if count < B:
            value, count = make(B), B
            self._kept[key] = (value, count)
        return value[:len(value) // count * B]

    def piece_ends(self):
        """(2m·6, N·6) sparse incidence summing the piece ends' forces (rows ``a₀ b₀ a₁ b₁ …`` of
        :attr:`CableRouting.ends`, six each) into their frames' (one sparse product per batch)."""
        if "ends" not in self._kept:
            from scipy.sparse import csr_array

            cables = self.trunk.cables
            rows = np.arange(cables.ends.size * 6)
            self._kept["ends"] = csr_array((np.ones(rows.size), (rows, cables.frame_targets)),
                                           shape=(rows.size, self.trunk.frames.count * 6))
        return self._kept["ends"]

    def groups(self, B):
        """Each sample's groups of pieces (``CablePieces.tangent``), offset to its rows; B·m: none."""
        groups, m = self.trunk.assembler.cable_groups, self.trunk.cables.piece_a.size
        offset = (np.arange(B) * m)[:, None, None]
        return np.where(groups[None] < m, groups[None] + offset, B * m).reshape(-1, groups.shape[1])

    def material(self, B, energy):
        return self._rows(("material", id(energy)), B, lambda count: np.ascontiguousarray(
            np.broadcast_to(energy.stiffness, (count,) + energy.stiffness.shape).reshape(-1, 6, 6)))


@dataclass
class Evaluation:
    """Potential (B,) and gradient (B, N, 6) of a batch of states, with what the tangent reuses
    (the batch's :class:`vertebra.solver.potential.Evaluation`)."""

    energy: np.ndarray
    gradient: np.ndarray
    links: Links                     # over the B·n links
    w: np.ndarray                    # (B, n, 6)
    kept: tuple
    link_gradient: np.ndarray        # (B·n, 12)
    pieces: CablePieces | None       # over the B·m pieces
    piece_tension: np.ndarray | None     # (B, m) every piece's tension, the tendons' included
    elongation: np.ndarray | None    # (B, t) the tendons' elongation
    lever: np.ndarray | None         # (B, N, 3)
    load: Loads


def _link_response(trunk, xi: np.ndarray, link_loads: tuple):
    energies = trunk.links.energies
    if len(energies) == 1:
        total, w, kept = energies[0].response(xi, link_loads[0])
        return total, w, (kept,)
    w = np.empty_like(xi)
    total = np.zeros(xi.shape[0])
    kept = []
    for energy, prepared in zip(energies, link_loads):
        part, w[:, energy.links], values = energy.response(xi[:, energy.links], prepared)
        total = total + part
        kept.append(values)
    return total, w, tuple(kept)


def _links(states: States) -> Links:
    """The link kinematics of every sample (the B·n links as rows)."""
    x, R = states.positions, states.rotations
    return Links.of_strains(R[:, :-1].reshape(-1, 3, 3), states.xi.reshape(-1, 6),
                            (x[:, 1:] - x[:, :-1]).reshape(-1, 3), states.coefficients)


@dataclass
class Geometry:
    """The kinematics of a batch of states that do not depend on the loads: the links, and the
    cable pieces' spans and pieces (None without cables)."""

    links: Links
    spans: tuple | None
    pieces: CablePieces | None


def evaluate(context: _Context, states: States, load: Loads, geometry: Geometry | None = None) -> Evaluation:
    """Potential and gradient of every sample (the terms of :func:`vertebra.solver.potential.evaluate`);
    ``geometry``: the states' kinematics when already known (:meth:`_Context.rest`)."""
    trunk = context.trunk
    B, n = states.xi.shape[:2]
    x, R = states.positions, states.rotations
    links = _links(states) if geometry is None else geometry.links
    energy, w, kept = _link_response(trunk, states.xi, load.link_loads)
    g_links = links.gradient(w.reshape(-1, 6))
    pairs = g_links.reshape(B, n, 12)
    grad = np.zeros((B, n + 1, 6))
    grad[:, :-1] = pairs[:, :, :6]
    grad[:, 1:] += pairs[:, :, 6:]
    pieces = piece_tension = elongation = lever = None
    if load.cables:
        cables = trunk.cables
        offsets, d, length = cables.spans(x, R) if geometry is None else geometry.spans
        m = cables.piece_a.size
        piece_tension = load.piece_tension
        if piece_tension is not None:
            energy = energy + np.add.reduce(piece_tension * length.reshape(B, m), 1)
        if load.tendons is not None:
            tendon_cables, k, rest, shift = load.tendons
            lengths = length.reshape(B, m) @ _owner_incidence(trunk)
            elongation = lengths[:, tendon_cables] - rest + shift
            taut = np.maximum(elongation, 0.0)
            energy = energy + 0.5 * np.add.reduce(k * taut * taut, 1)
            tension = np.zeros((B, cables.n_cables))
            tension[:, tendon_cables] = k * taut
            tendon_pieces = tension.take(cables.owner, 1, mode="clip")
            piece_tension = tendon_pieces if piece_tension is None else tendon_pieces + piece_tension
        pieces = CablePieces.of_spans(offsets, d, length) if geometry is None else geometry.pieces
        forces = (piece_tension.reshape(-1)[:, None] * pieces.unit).reshape(B, 2 * m, 6)
        grad += (forces.reshape(B, -1) @ context.piece_ends()).reshape(B, -1, 6)
    if load.weight is not None:
        lever = (R @ trunk.frames.moment[:, :, None])[..., 0]
        energy = energy - np.add.reduce((trunk.frames.mass @ x + np.add.reduce(lever, 1)) * load.weight, 1)
        grad[:, :, :3] -= load.frame_weight
        grad[:, :, 3:] -= lever @ load.weight_hat
    if load.dead is not None:
        energy = energy - np.add.reduce((load.dead[:, :, :3] * x).reshape(B, -1), 1)
        grad -= load.dead
    return Evaluation(energy, grad, links, w, kept, g_links, pieces, piece_tension, elongation, lever, load)


def _owner_incidence(trunk) -> np.ndarray:
    cables = trunk.cables
    E = np.zeros((cables.piece_a.size, cables.n_cables))
    E[np.arange(cables.piece_a.size), cables.owner] = 1.0
    return E


def _material(context: _Context, ev: Evaluation, B: int) -> np.ndarray:
    """``∂²ψ/∂ξ²`` of every link as rows (B·n, 6, 6)."""
    trunk = context.trunk
    energies = trunk.links.energies
    xi = ev.links.xi.reshape(B, -1, 6)
    if len(energies) == 1:
        energy = energies[0]
        if not energy.fitted:
            return context.material(B, energy)
        return energy.material_tangent(xi, ev.load.link_loads[0], ev.kept[0])
    out = np.empty(xi.shape + (6,))
    for energy, prepared, kept in zip(energies, ev.load.link_loads, ev.kept):
        part = energy.material_tangent(xi[:, energy.links], prepared, kept)
        out[:, energy.links] = part if part.ndim == 3 else part.reshape(B, -1, 6, 6)
    return out.reshape(-1, 6, 6)


@dataclass
class Tangent:
    """The symmetric tangents of a batch: their lower bands (B, n, kd + 1)
    (:meth:`vertebra.solver.assembly.BandAssembler.symmetric_bands`) and, with stroke-driven tendons, their dense term ``U diag(d) Uᵀ`` beside the band (``U`` (B, n_dof,
    t) the tendons' ``∂L/∂q``, ``d`` (B, t) their spring rates where taut, 0 where slack) — the
    batch's :class:`vertebra.solver.assembly.Tangent`."""

    bands: np.ndarray
    U: np.ndarray | None = None
    d: np.ndarray | None = None

    def take(self, rows: np.ndarray) -> "Tangent":
        if rows.size == self.bands.shape[0] and np.array_equal(rows, np.arange(rows.size)):    # all, in order
            return self
        return Tangent(self.bands[rows], None if self.U is None else self.U[rows],
                       None if self.d is None else self.d[rows])

    def diagonal(self) -> np.ndarray:
        """The diagonal (B, n_dof), the dense term's included."""
        diagonal = self.bands[:, :, 0]
        if self.U is not None:
            diagonal = diagonal + np.add.reduce(self.U * self.U * self.d[:, None, :], 2)
        return diagonal

    def factor(self, shift: np.ndarray | None = None, scale: np.ndarray | None = None) -> "Factor":
        """The factor of every sample's tangent plus ``shift · diag(scale)`` (the band's Cholesky,
        updated by the dense term: Sherman–Morrison–Woodbury). The bands are copied: the tangent
        stays as it is."""
        bands = self.bands.copy()
        if shift is not None and np.any(shift):
            bands[:, :, 0] += shift[:, None] * scale
        return Factor(factor_cholesky_batch(bands), self.U, self.d)


class Factor:
    """A batch of factored tangents (:meth:`Tangent.factor`): ``ok`` where the band is positive
    definite; ``refused_with_tendons`` where it is not but taut tendons may make the whole so (the
    single solve's inertia test, :meth:`vertebra.solver.banded.LowRankFactor.definite`)."""

    def __init__(self, band, U: np.ndarray | None, d: np.ndarray | None):
        self.band, self.U, self.d = band, U, d
        self.ok = band.ok
        self.refused_with_tendons = np.zeros(self.ok.shape, bool)
        if U is not None:
            self.refused_with_tendons = ~band.ok & np.any(d > 0.0, 1)
            with np.errstate(all="ignore"):
                self.Z = band.solve(U)
                capacitance = np.eye(U.shape[2]) + d[:, :, None] * (U.mT @ self.Z)
            capacitance[~band.ok] = np.eye(U.shape[2])       # (a refused sample's numbers are meaningless)
            self.capacitance = capacitance

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``(A + U D Uᵀ)⁻¹ rhs`` per sample, ``rhs`` (B, n) or (B, n, k)."""
        y = self.band.solve(rhs)
        if self.U is None:
            return y
        single = y.ndim == 2
        Y = y[..., None] if single else y
        with np.errstate(all="ignore"):
            w = np.linalg.solve(self.capacitance, self.d[:, :, None] * (self.U.mT @ Y))
            out = Y - self.Z @ w
        return out[..., 0] if single else out


TANGENT_BLOCK_LINKS = 640     # links whose tangents are assembled together (see tangent)


def tangent(context: _Context, ev: Evaluation) -> Tangent:
    """The symmetric tangent of every sample (the terms of :func:`vertebra.solver.potential.tangent`).
    The samples are taken in blocks of about :data:`TANGENT_BLOCK_LINKS` links: a block's link and
    cable tangents and its band assembly (a dozen arrays of 12×12 and 6×6 blocks per link) stay in
    the processor's cache between the steps, where the whole batch's would not. A block of samples
    at the unstressed rest state (their strains the rest strains, no link force, no pressure) takes
    the links' tangent there, a model constant (``trunk.rest.link_tangent``), as the single solve
    does."""
    trunk = context.trunk
    assembler = trunk.assembler
    B = ev.gradient.shape[0]
    n = trunk.links.count
    material = _material(context, ev, B)
    w = ev.w.reshape(-1, 6)
    rest = ~np.any(ev.w.reshape(B, -1), 1)
    if rest.any():
        rest &= np.all(ev.links.xi.reshape(B, -1) == trunk.rest_state.strains.xi.reshape(-1), 1)
        rest &= ~np.any(ev.load.pressures, 1)
    tension = None if ev.pieces is None else ev.piece_tension.reshape(-1)
    weight = None
    if trunk.loads.has_gravity:
        weight = -ev.load.weight_hat[:, None] @ hat(ev.lever[:, 1:])
    size = max(1, TANGENT_BLOCK_LINKS // max(n, 1))
    bands = np.empty((B, assembler.n, assembler.kd + 1))
    for start in range(0, B, size):
        stop = min(B, start + size)
        if rest[start:stop].all():
            links = np.broadcast_to(trunk.rest.link_tangent, (stop - start,) + trunk.rest.link_tangent.shape)
        else:
            links = link_tangent(_samples(ev.links, start, stop, B), w[start * n:stop * n],
                                 material[start * n:stop * n], ev.link_gradient[start * n:stop * n])
        cables = None
        if ev.pieces is not None:
            m = tension.size // B
            cables = _samples(ev.pieces, start, stop, B).tangent(tension[start * m:stop * m],
                                                               context.groups(stop - start))
        bands[start:stop] = assembler.symmetric_bands(links, cables, None if weight is None else weight[start:stop])
    if ev.load.tendons is None:
        return Tangent(bands)
    tendon_cables, k = ev.load.tendons[:2]
    jacobian = _cable_jacobian(context, ev.pieces, B)[:, tendon_cables, 1:]
    U = np.ascontiguousarray(jacobian.reshape(B, tendon_cables.size, -1).mT)
    return Tangent(bands, U, k * (ev.elongation > 0.0))


def _cable_jacobian(context: _Context, pieces: CablePieces, B: int) -> np.ndarray:
    """``∂L/∂q`` (B, n_cables, n_frames, 6) of every cable of every sample
    (:meth:`vertebra.solver.cables.CableRouting.jacobian`'s two gathers, over the batch)."""
    trunk = context.trunk
    cables = trunk.cables
    ends = np.zeros((B, 2 * cables.piece_a.size + 1, 6))         # the piece ends' gradients, then a zero row
    ends[:, :-1] = pieces.unit.reshape(B, -1, 6)
    starting, ending = cables.jacobian_ends
    jacobian = ends.take(starting, 1, mode="clip")            # (indices made with the routing: no check)
    jacobian += ends.take(ending, 1, mode="clip")
    return jacobian.reshape(B, cables.n_cables, trunk.frames.count, 6)


# ----------------------------------------------------------------------------- rows of a batch
def _take(value, rows: np.ndarray, count: int):
    """The samples ``rows`` of a batch quantity of ``count`` samples: arrays whose first axis is
    the samples or their links/pieces (sample by sample), dataclasses and tuples of those."""
    if value is None or isinstance(value, (float, int)):
        return value
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return value
        if not len(rows):
            return value[:0]
        return value.reshape((count, -1) + value.shape[1:]).take(rows, 0).reshape((-1,) + value.shape[1:])
    if isinstance(value, tuple):
        return tuple(_take(v, rows, count) for v in value)
    return type(value)(**{f: _take(getattr(value, f), rows, count) for f in value.__dataclass_fields__})


def _samples(value, start: int, stop: int, count: int):
    """The samples ``start:stop`` of a batch quantity of ``count`` samples (:func:`_take`'s kinds
    of quantities: arrays whose first axis holds the samples or their links/pieces sample by
    sample, tuples and dataclasses of them), as views."""
    if value is None or isinstance(value, (float, int)):
        return value
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return value
        per = len(value) // count
        return value[start * per:stop * per]
    if isinstance(value, tuple):
        return tuple(_samples(v, start, stop, count) for v in value)
    return type(value)(**{f: _samples(getattr(value, f), start, stop, count) for f in value.__dataclass_fields__})


def _put(target, rows: np.ndarray, count: int, source) -> None:
    """Write ``source`` (the batch quantity of the samples ``rows``) into ``target`` (of ``count``
    samples), in place."""
    if target is None or isinstance(target, (float, int)):
        return
    if isinstance(target, np.ndarray):
        if target.ndim == 0 or not len(rows):
            return
        view = target.reshape((count, -1) + target.shape[1:])
        if not np.may_share_memory(view, target):
            raise ValueError("a batch array is not contiguous by sample")
        view[rows] = source.reshape((len(rows), -1) + target.shape[1:])
        return
    if isinstance(target, tuple):
        for t, s in zip(target, source):
            _put(t, rows, count, s)
        return
    for f in target.__dataclass_fields__:
        _put(getattr(target, f), rows, count, getattr(source, f))


def _subset(ev: Evaluation, rows: np.ndarray, count: int, load: Loads | None) -> Evaluation:
    """The evaluation of the samples ``rows`` (of ``count``) with the load cases ``load``."""
    if len(rows) == count:
        return ev if ev.load is load else dataclasses.replace(ev, load=load)
    taken = {f: _take(getattr(ev, f), rows, count) for f in ev.__dataclass_fields__ if f != "load"}
    return Evaluation(load=load, **taken)


def _put_evaluation(target: Evaluation, rows: np.ndarray, count: int, source: Evaluation) -> None:
    for f in target.__dataclass_fields__:
        if f != "load":
            _put(getattr(target, f), rows, count, getattr(source, f))


# ----------------------------------------------------------------------------- Newton
def _raise_shift(shift: np.ndarray, factor: float) -> np.ndarray:
    return np.maximum(SHIFT_START, factor * shift)


def _norm(gradient: np.ndarray, reference: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`vertebra.solver.newton.residual_norm` of every sample's free frames."""
    B = gradient.shape[0]
    return np.maximum.reduce(np.abs(gradient[:, 1:] * weights).reshape(B, -1), 1) / reference


def _force_scale(trunk, gradient: np.ndarray) -> np.ndarray:
    free = np.abs(gradient[:, 1:])
    B = gradient.shape[0]
    return np.maximum(np.maximum.reduce(free[:, :, :3].reshape(B, -1), 1, initial=0.0),
                      np.maximum.reduce(free[:, :, 3:].reshape(B, -1), 1, initial=0.0) / trunk.frames.length_scale)


def _strain_change(links: Links, dq: np.ndarray) -> np.ndarray:
    """The links' linearised strain change (B, n, 6) under free-frame increments ``dq`` (B, n_dof)."""
    B = dq.shape[0]
    return links.strain_change(np.concatenate([np.zeros((B, 1, 6)), dq.reshape(B, -1, 6)], 1)).reshape(B, -1, 6)


def _join(parts: list, counts: list, rows: list | None = None):
    """The batch quantities ``parts`` (of ``counts`` samples each) side by side, in order; with
    ``rows``, of each part only its samples ``rows[i]`` (None: all). One copy of each array (none
    for one part taken whole); an evaluation's load cases are left out (None)."""
    rows = rows or [None] * len(parts)
    first = parts[0]
    if first is None or isinstance(first, (float, int)):
        return first
    if isinstance(first, np.ndarray):
        if first.ndim == 0:
            return first
        if len(parts) == 1:
            return first if rows[0] is None else _take(first, rows[0], counts[0])
        views = [p.reshape((c, -1) + p.shape[1:]) for p, c in zip(parts, counts)]
        sizes = [c if r is None else len(r) for c, r in zip(counts, rows)]
        out = np.empty((sum(sizes),) + views[0].shape[1:])
        at = 0
        for view, r, k in zip(views, rows, sizes):
            if r is None:
                out[at:at + k] = view
            else:
                np.take(view, r, axis=0, out=out[at:at + k], mode="clip")
            at += k
        return out.reshape((-1,) + first.shape[1:])
    if isinstance(first, tuple):
        return tuple(_join([p[i] for p in parts], counts, rows) for i in range(len(first)))
    return type(first)(**{f: None if f == "load" else _join([getattr(p, f) for p in parts], counts, rows)
                          for f in first.__dataclass_fields__})


def _accepted(parts: list, count: int):
    """The accepted trials of one Newton iteration (``line_search``'s parts) as the next working
    set: (local rows, (states, evaluation, residual)). Usually the largest trial (the full step of
    every sample that had a factor) holds every sample that moved, some of them accepted only at a
    shorter step of a later trial: those are written into its arrays in place, and the working set
    keeps its order. Otherwise the accepted samples are gathered side by side (:func:`_join`)."""
    order = np.concatenate([p[0] for p in parts])
    host = max(range(len(parts)), key=lambda i: parts[i][5])
    where = parts[host][6]
    inside = np.zeros(count, bool)
    inside[where] = True
    if len(parts) > 1 and order.size == where.size and inside[order].all():
        position = np.empty(count, int)
        position[where] = np.arange(where.size)
        target = parts[host][1:4]
        try:
            for i, part in enumerate(parts):
                if i != host:
                    _put_rows(target, position[part[0]], where.size, part[1:4],
                              part[4] if part[4] is not None else slice(None), part[5])
        except ValueError:               # (an array of the host's that is not its own: gather instead)
            pass
        else:
            states, ev, residual = target
            return where, (states, dataclasses.replace(ev, load=None), residual)
    return order, _join([p[1:4] for p in parts], [p[5] for p in parts], [p[4] for p in parts])


def _put_rows(target, rows, count: int, source, source_rows, source_count: int) -> None:
    """Write the samples ``source_rows`` of ``source`` (a batch quantity of ``source_count``
    samples) over the samples ``rows`` of ``target`` (of ``count``), in place."""
    if target is None or isinstance(target, (float, int)):
        return
    if isinstance(target, np.ndarray):
        if target.ndim == 0:
            return
        view = target.reshape((count, -1) + target.shape[1:])
        if not np.may_share_memory(view, target) or not target.flags.writeable:
            raise ValueError("a batch array is not contiguous by sample")
        view[rows] = source.reshape((source_count, -1) + source.shape[1:])[source_rows]
        return
    if isinstance(target, tuple):
        for t, s in zip(target, source):
            _put_rows(t, rows, count, s, source_rows, source_count)
        return
    for f in target.__dataclass_fields__:
        if f != "load":
            _put_rows(getattr(target, f), rows, count, getattr(source, f), source_rows, source_count)


class _Run:
    """The per-sample bookkeeping of one chunk (what :class:`vertebra.solver.newton._Stage` and
    :func:`vertebra.solver.newton.solve` keep for one sample)."""

    def __init__(self, context: _Context, actuation: np.ndarray):
        trunk = context.trunk
        self.context, self.trunk = context, trunk
        B = actuation.shape[0]
        self.actuation = actuation
        n_cables = trunk.actuators.n_cables
        # the single solve evaluates a sample's cables when a tension-driven cable pulls or tendons exist
        self.cabled = np.zeros(B, bool)
        if n_cables:
            self.cabled = np.any(np.where(trunk.actuators.stroke_driven, 0.0, actuation[:, :n_cables]) != 0.0, 1)
            self.cabled |= bool(trunk.actuators.stroke_driven.any())
        self.single = np.zeros(B, bool)               # leaves the batch's path: the single solve redoes it
        self.why = [""] * B                           # … and why
        self.iterations = np.zeros(B, int)
        self.kinds = np.zeros(B, int)                 # 1: cholesky, 2: shifted
        self.shift = np.zeros(B)
        self.turn = np.zeros(B)
        self.stretching = np.ones(B, bool)
        self.history = [[] for _ in range(B)]
        self.weights = newton.residual_weights(trunk)
        self.axis, self.shortest = trunk.rest.axis, trunk.rest.shortest
        holes = trunk.cables.hole_set
        self.reach = float(np.sqrt(np.max(np.add.reduce(holes * holes, 1)))) if holes.size else 0.0   # max |s|

    def leave(self, rows: np.ndarray, why: str) -> None:
        """Samples ``rows`` leave the batch's path (the single solve redoes them), for ``why``."""
        fresh = rows[~self.single[rows]]
        self.single[fresh] = True
        for i in fresh.tolist():
            self.why[i] = why

    # -- checks of a state ------------------------------------------------------------
    def represented(self, rows: np.ndarray, states: States, ev: Evaluation) -> np.ndarray:
        """Which samples are representable (:meth:`vertebra.solver.newton._Stage.represented`);
        sets their largest turn."""
        turn = np.sqrt(states.turns2)
        self.turn[rows] = turn
        good = turn <= TURN_LIMIT
        if ev.pieces is not None:
            ratio = ev.pieces.length.reshape(len(rows), -1) / self.trunk.rest_piece_lengths
            good &= ~(self.cabled[rows] & (np.minimum.reduce(ratio, 1) < COLLAPSE_LIMIT))
        folding = self.stretching[rows]
        if folding.any():
            axial = np.add.reduce(states.xi[:, :, :3] * self.axis, 2)
            good &= ~(folding & (np.minimum.reduce(axial, 1) < FOLD_LIMIT))
        return good

    def step_limit(self, rows: np.ndarray, dq: np.ndarray, change: np.ndarray, pieces,
                   cap: float | None = None) -> np.ndarray:
        """:meth:`vertebra.solver.newton._Stage.step_limit` of every sample (``pieces``: the
        samples' cable pieces, ``rows``: their index in the run). With ``cap``, a limit is only
        needed up to ``cap`` (the caller takes ``min(cap, limit)``): the cable pieces of a sample
        whose frames move too little to halve any piece within ``cap`` steps are not examined
        (``|Δd| ≤ 2 (max |dx| + max |dφ| · max |s|)`` against the shortest piece)."""
        largest = np.maximum.reduce(np.abs(change), 1)                 # (B, 6)
        room = np.minimum(MAX_TURN, 0.5 * (math.pi - self.turn[rows]))
        stretch = SQRT3 * np.maximum.reduce(largest[:, :3], 1)
        self.stretching[rows] |= stretch > STRETCHING * self.shortest
        limit = np.minimum(room / np.maximum(SQRT3 * np.maximum.reduce(largest[:, 3:], 1), 1e-300),
                           MAX_STRETCH * self.shortest / np.maximum(stretch, 1e-300))
        if pieces is not None:
            B = dq.shape[0]
            need = self.cabled[rows]
            if cap is not None and need.any():
                frames = dq.reshape(B, -1, 6)
                moved = (np.sqrt(np.maximum.reduce(np.add.reduce(frames[:, :, :3] ** 2, 2), 1))
                         + np.sqrt(np.maximum.reduce(np.add.reduce(frames[:, :, 3:] ** 2, 2), 1)) * self.reach)
                need &= cap * 2.0 * moved > 0.49 * np.minimum.reduce(pieces.length.reshape(B, -1), 1)
            need = np.flatnonzero(need)
            if need.size:
                if need.size < B:
                    pieces, dq = _take(pieces, need, B), dq[need]
                k = need.size
                moves = np.zeros((k, self.trunk.frames.count, 6))
                moves[:, 1:] = dq.reshape(k, -1, 6)
                delta = pieces.change(moves.take(self.trunk.cables.ends, 1, mode="clip").reshape(-1, 12))
                along = np.add.reduce(pieces.d * delta, 1)
                squared = np.add.reduce(delta * delta, 1)
                discriminant = along * along - 0.75 * squared * pieces.length ** 2
                closing = (along < 0.0) & (discriminant > 0.0)
                if closing.any():
                    roots = np.full(closing.shape, np.inf)
                    roots[closing] = (-along[closing] - np.sqrt(discriminant[closing])) / squared[closing]
                    limit[need] = np.minimum(limit[need], np.minimum.reduce(roots.reshape(k, -1), 1))
        return limit

    def below_resolution(self, positions: np.ndarray, dq: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        B = dq.shape[0]
        extent = self.trunk.frames.length_scale + np.maximum.reduce(np.abs(positions).reshape(B, -1), 1)
        largest = np.maximum.reduce(np.abs(dq).reshape(B, -1, 6), 1)
        return alpha * np.maximum(np.maximum.reduce(largest[:, :3], 1) / extent,
                                  np.maximum.reduce(largest[:, 3:], 1)) <= RESOLUTION

    # -- one load stage --------------------------------------------------------------
    def stage(self, rows: np.ndarray, states: States, load: Loads, tolerance: np.ndarray, budget: np.ndarray,
              reference: np.ndarray, geometry: "Geometry | None" = None) -> tuple[np.ndarray, States]:
        """Newton at a fixed load factor per sample (:func:`vertebra.solver.newton._newton`) for the
        run's samples ``rows`` from ``states`` (``geometry``: their kinematics when known). Returns
        which converged (the others are marked for the single solve) and the states reached.

        The samples still iterating are kept compacted: their states and evaluation are the
        working set, taken again only when some finish or leave (no scatter back into the
        stage's arrays; a converged sample's state is written once)."""
        trunk, context = self.trunk, self.context
        k = len(rows)
        self.stretching[rows] = True
        done = np.zeros(k, bool)
        trusted = np.zeros(k, bool)
        taken = np.zeros(k, int)
        ev = evaluate(context, states, load, geometry)
        residual = _norm(ev.gradient, reference, self.weights)
        live = np.isfinite(residual + ev.energy)
        live &= self.represented(rows, states, ev)
        self.leave(rows[~live], "start state not finite or not representable")
        at = np.arange(k)                  # the working set: local rows of the samples iterating
        work, work_ev, work_load = states, ev, load

        def loads_of(where):
            return load if where.size == k and np.array_equal(where, at_start) else load.take(trunk, where)

        at_start = at
        while True:
            keep = np.flatnonzero(live)
            if keep.size < at.size:        # compact the working set
                work, work_ev = work.take(keep), _subset(work_ev, keep, at.size, None)
                at, residual = at[keep], residual[keep]
                work_load = work_ev.load = loads_of(at)
            if not at.size:
                break
            for i, value in zip(rows[at].tolist(), residual.tolist()):
                self.history[i].append(value)
            converged = residual <= tolerance[at]
            check = np.flatnonzero(converged & ~trusted[at])
            stable = np.flatnonzero(converged & trusted[at])
            if check.size:
                matrix = tangent(context, _subset(work_ev, check, at.size, loads_of(at[check])))
                factor = matrix.factor(np.full(check.size, NEUTRAL), np.abs(matrix.diagonal()) + 1e-300)
                self.leave(rows[at[check[factor.refused_with_tendons]]], "a band not positive definite with taut tendons")
                ok = factor.ok
                self.leave(rows[at[check[~ok]]], "an equilibrium whose tangent is not positive definite")
                stable = np.concatenate([stable, check[ok]])
            if stable.size:
                done[at[stable]] = True
                states.put(at[stable], work.take(stable))
            go = ~converged
            over = go & (taken[at] >= budget[at])
            self.leave(rows[at[over]], "the stage's iterations ran out")
            go &= ~over
            if not go.all():
                keep = np.flatnonzero(go)
                work, work_ev = work.take(keep), _subset(work_ev, keep, at.size, None)
                at, residual = at[keep], residual[keep]
                work_load = work_ev.load = loads_of(at)
            if not at.size:
                break
            taken[at] += 1
            self.iterations[rows[at]] += 1
            self.stretching[rows[at]] = False
            moved, new_states, new_ev, new_residual, cholesky = self.iterate(rows[at], work_ev, work, residual,
                                                                              work_load, reference[at])
            ok = at[moved]                 # (moved: the local rows of the moved samples, in their new order)
            if not ok.size:
                break
            trusted[ok] = cholesky[moved] & (residual[moved] <= TRUSTED_RESIDUAL)
            at, work, residual = ok, new_states, new_residual
            work_load = loads_of(at)
            work_ev = dataclasses.replace(new_ev, load=work_load)
            good = np.isfinite(new_residual) & self.represented(rows[ok], new_states, work_ev)
            self.leave(rows[ok[~good]], "a state not finite or not representable")
            live = good
        return done, states

    def iterate(self, rows: np.ndarray, ev: Evaluation, states: States, residual: np.ndarray, load: Loads,
                reference: np.ndarray):
        """One Newton iteration of every sample ``rows`` (the body of the single solve's loop, from
        the tangent to the accepted step). Returns (the local rows of the samples that moved, then
        for those in that order: their states, evaluation and residual; and (B,) whether the
        step's factor was the unshifted Cholesky). Samples not moved leave the batch's path
        (``single``)."""
        trunk, context = self.trunk, self.context
        B = len(rows)
        matrix = tangent(context, ev)
        scale = np.maximum(np.abs(matrix.diagonal()), trunk.rest.stiffness)
        r = -ev.gradient[:, 1:].reshape(B, -1)
        shift = self.shift[rows].copy()
        indefinite = np.zeros(B, bool)
        moved = np.zeros(B, bool)
        cholesky = np.zeros(B, bool)
        quality_of = np.zeros(B)
        bent = np.zeros(B, bool)            # the step tried is along negative curvature
        curved = np.zeros(B, bool)          # the step taken is
        accepted = []
        pending = np.arange(B)
        while pending.size:
            ceiling = shift[pending] > SHIFT_CEILING
            self.leave(rows[pending[ceiling]], "the shift passed its ceiling")
            pending = pending[~ceiling]
            if not pending.size:
                break
            factor = matrix.take(pending).factor(shift[pending], scale[pending])
            self.leave(rows[pending[factor.refused_with_tendons]], "a band not positive definite with taut tendons")
            refused = pending[~factor.ok & ~factor.refused_with_tendons]
            indefinite[refused] = True
            shift[refused] = _raise_shift(shift[refused], 10.0)
            retry = [refused]
            good = pending[factor.ok]
            if good.size:
                dq = factor.solve(r[pending])[factor.ok]
                rp = np.add.reduce(r[good] * dq, 1)
                descends = rp > 0.0                       # (an LU-free path: NaN does not descend)
                shift[good[~descends]] = _raise_shift(shift[good[~descends]], 10.0)
                retry.append(good[~descends])
                good, dq, rp = good[descends], dq[descends], rp[descends]
            if good.size:
                s = shift[good]
                curvature = np.where(s != 0.0, rp - s * np.add.reduce(dq * (scale[good] * dq), 1), rp)
                whole = good.size == B
                change = _strain_change(ev.links if whole else _take(ev.links, good, B), dq)
                pieces = ev.pieces if whole or ev.pieces is None else _take(ev.pieces, good, B)
                alpha = np.minimum(1.0, self.step_limit(rows[good], dq, change, pieces, cap=1.0))
                below = self.below_resolution(states.positions[good], dq, alpha)
                self.leave(rows[good[below]], "a step below the resolution of the poses")
                keep = ~below
                good, dq, rp, curvature, change, alpha, s = (v[keep] for v in (good, dq, rp, curvature, change, alpha, s))
                bending = np.flatnonzero(indefinite[good] & (s >= BEND_SHIFT))
                bent[good] = False
                if bending.size:
                    # a step along negative curvature where it promises more (globalise.bend)
                    at = good[bending]
                    found_bend = self.bend(rows[at], r[at], matrix.take(at).factor(shift[at], scale[at]), shift[at],
                                           scale[at], _take(ev.links, at, B), _take(ev.pieces, at, B))
                    use, bdq, bchange, brp, bcurvature, predicted = found_bend
                    a = alpha[bending]
                    use &= predicted > a * rp[bending] - 0.5 * a * a * curvature[bending]
                    which = bending[use]
                    dq[which], change[which], rp[which] = bdq[use], bchange[use], brp[use]
                    curvature[which], alpha[which] = bcurvature[use], 1.0
                    bent[good[which]] = True
            if good.size:
                found, quality, trials = self.line_search(rows, good, ev, states, residual, load, reference, change,
                                                          alpha, rp, curvature)
                ok = good[found]
                moved[ok] = True
                cholesky[ok] = (shift[ok] == 0.0) & ~bent[ok]
                curved[ok] = bent[ok]
                quality_of[ok] = quality[found]
                accepted.extend(trials)
                failed = good[~found]
                shift[failed] = _raise_shift(shift[failed], 10.0)
                retry.append(failed)
            pending = np.sort(np.concatenate(retry))
            pending = pending[~self.single[rows[pending]]]
        # the shift of the next iteration, from how well the model predicted the full step
        adapt = moved & ~curved
        q, s = quality_of[adapt], shift[adapt]
        shift[adapt] = np.where(q >= 0.75, np.where(s / 4.0 < SHIFT_FLOOR, 0.0, s / 4.0),
                                np.where(q < 0.25, _raise_shift(s, 4.0), s))
        self.shift[rows] = shift
        self.kinds[rows[moved]] |= np.where(curved[moved], 4, np.where(cholesky[moved], 1, 2))
        if not moved.any():
            return np.zeros(0, int), None, None, np.zeros(0), cholesky
        order, (new_states, new_ev, new_residual) = _accepted(accepted, B)
        return order, new_states, new_ev, new_residual, cholesky

    def bend(self, rows, r, factor, shift, scale, links, pieces):
        """:func:`vertebra.solver.globalise.bend` of every sample: (has one, dq, strain change, r·dq,
        dqᵀH dq, predicted decrease) along the direction of most negative curvature found by
        inverse iteration with the shifted factor (:func:`vertebra.solver.globalise.negative_curvature`)."""
        k, n = r.shape
        v = np.broadcast_to(np.random.default_rng(n).standard_normal(n), (k, n)).copy()   # the single solve's start
        has = factor.ok.copy()
        curvature = np.zeros(k)
        with np.errstate(all="ignore"):
            for _ in range(8):
                w = factor.solve(scale * v)
                norm = np.sqrt(np.add.reduce(w * (scale * w), 1))
                fine = (norm > 0.0) & np.isfinite(norm)
                has &= fine
                norm = np.where(fine, norm, 1.0)
                curvature = np.add.reduce(w * (scale * v), 1) / (norm * norm) - shift
                v = w / norm[:, None]
        has &= curvature < -NEUTRAL
        dq, change, rp = np.zeros((k, n)), np.zeros((k, links.xi.shape[0] // k, 6)), np.zeros(k)
        at = np.flatnonzero(has)
        if at.size:
            v = v[at]
            v = np.where((np.add.reduce(r[at] * v, 1) < 0.0)[:, None], -v, v)
            strains = _strain_change(_take(links, at, k), v)
            limit = self.step_limit(rows[at], v, strains, None if pieces is None else _take(pieces, at, k))
            dq[at], change[at] = limit[:, None] * v, limit[:, None, None] * strains
            curvature[at] = curvature[at] * limit * limit
            rp[at] = np.add.reduce(r[at] * dq[at], 1)
        return has, dq, change, rp, curvature, rp - 0.5 * curvature

    def line_search(self, rows, good, ev: Evaluation, states: States, residual, load: Loads, reference, change,
                    alpha, rp, curvature):
        """The backtracking line search (:func:`vertebra.solver.globalise.line_search`) of the samples
        ``good`` (local rows of ``ev``): returns (found, quality, [(local rows, states, evaluation,
        residual, the accepted among them (None: all), their count, the local rows tried), …] of the
        trials)."""
        trunk, context = self.trunk, self.context
        B = len(rows)
        energy = ev.energy[good]
        noise = ROUNDING * np.abs(energy)
        found = np.zeros(good.size, bool)
        quality = np.full(good.size, np.nan)
        trials = []
        searching = np.arange(good.size)
        alpha = alpha.copy()
        while searching.size:
            a = alpha[searching]
            where = good[searching]
            step = change[searching]
            strains = states.xi[where] + np.where((a == 1.0)[:, None, None], step, a[:, None, None] * step)
            trial, carried = compose(trunk, strains)
            if not carried.all():                  # the single solve evaluates such a state from its poses
                self.leave(rows[where[~carried]], "a trial state whose links turn beyond the carried strains")
                keep = carried
                searching, a, where = searching[keep], a[keep], where[keep]
                if not searching.size:
                    break
                trial = trial.take(np.flatnonzero(keep))
            sub_load = load if where.size == B else load.take(trunk, where)
            trial_ev = evaluate(context, trial, sub_load)
            trial_residual = _norm(trial_ev.gradient, reference[where], self.weights)
            predicted = a * rp[searching] - 0.5 * a * a * curvature[searching]
            decrease = energy[searching] - trial_ev.energy
            small = predicted <= noise[searching]
            with np.errstate(invalid="ignore", divide="ignore"):
                accept = np.where(small, trial_residual <= residual[where],
                                  decrease >= ARMIJO * predicted - noise[searching])
                ratio = np.where(small, 1.0, decrease / predicted)
            first = np.isnan(quality[searching])
            quality[searching[first]] = np.where(accept[first], ratio[first], 0.0)
            if accept.any():
                at = np.flatnonzero(accept)
                found[searching[at]] = True
                trials.append((where[at], trial, trial_ev, trial_residual, at if at.size < where.size else None,
                               where.size, where))
            alpha[searching] = a * 0.5
            searching = searching[~accept]
            searching = searching[alpha[searching] >= SEARCH_FLOOR]
        return found, quality, trials


# ----------------------------------------------------------------------------- results
@dataclass
class BatchResult:
    """The equilibria of a batch of actuations (:func:`solve_batch`), sample by sample.

    ``converged`` (B,); ``iterations`` (B,) Newton iterations (load stages summed); ``residual``
    (B,) scaled residual at the end; ``positions`` (B, n_frames, 3) and ``quaternions``
    (B, n_frames, 4) of every frame (nan where a sample failed without a state); ``strains``
    (B, n_links, 6) the link strains of the state reached; ``load_steps`` (B,) load stages;
    ``factorization`` the factor kinds used per sample (as in :class:`StaticResult`);
    ``largest_turn`` (B,) rad; ``messages`` why a sample did not converge ("" when it did);
    ``single`` (B,) the sample left the batch's path and was solved by the single solve;
    ``out_of_range``/``bound_violations``: per sample, as a :class:`StaticResult` reports them."""

    actuation: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    strains: np.ndarray
    load_steps: np.ndarray
    factorization: list
    largest_turn: np.ndarray
    messages: list
    single: np.ndarray
    why: list                  # why a sample left the batch's path ("" when it did not)
    errors: list               # the error's name where a sample failed ("ConvergenceError", …; "" when converged)
    histories: list
    out_of_range: list
    bound_violations: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    results: dict = field(default_factory=dict, repr=False)   # the single solve's StaticResult by sample
    rest: object = field(default=None, repr=False)            # the trunk's rest state (its base pose)

    def __len__(self) -> int:
        return len(self.converged)

    def state(self, i: int):
        """The state sample ``i`` reached, composed from its link strains (it carries them)."""
        if i in self.results:
            return self.results[i].state
        return compose_state(self.rest.quaternions[0], self.rest.positions[0], self.strains[i].copy())

    def result(self, i: int):
        """Sample ``i`` as the :class:`StaticResult` the single solve returns."""
        if i in self.results:
            return self.results[i]
        return newton.StaticResult(bool(self.converged[i]), int(self.iterations[i]), float(self.residual[i]),
                                   self.state(i), self.actuation[i], list(self.histories[i]),
                                   int(self.load_steps[i]), self.factorization[i], {},
                                   largest_turn=float(self.largest_turn[i]), message=self.messages[i],
                                   out_of_range=self.out_of_range[i],
                                   bound_violations=self.bound_violations[i] if self.bound_violations else ())


_KINDS = {bits: "+".join(name for bit, name in ((1, "cholesky"), (4, "curvature"), (2, "shifted")) if bits & bit)
          or "none" for bits in range(8)}


def chunk_size(trunk, budget: int = MEMORY_BUDGET, extra: int = 0) -> int:
    """Samples per chunk whose working arrays stay within ``budget`` bytes: per sample, about
    1,600 numbers per link (kinematics, tangents, their temporaries), 120 per cable piece, 900 per
    pair of frames joined by cables and 650 per block of the band (the terms, the blocks, the
    factor and its copies), and ``extra`` numbers of the caller's own."""
    assembler = trunk.assembler
    numbers = (1600 * trunk.links.count + 120 * trunk.cables.piece_a.size + 900 * assembler.n_pairs
               + 650 * assembler.n_blocks * (assembler.span + 1) + 200 + extra)
    return int(max(1, min(4096, budget // (8 * numbers))))


def _solve_chunk(context: _Context, actuation: np.ndarray, start: np.ndarray | None, warm: np.ndarray,
                 tolerance: float, max_iterations: int, load_steps: int) -> dict:
    """The batch's path for one chunk: returns per-sample arrays and which samples need the single solve."""
    trunk = context.trunk
    B = actuation.shape[0]
    run = _Run(context, actuation)
    rest_xi = trunk.rest_state.strains.xi
    full = Loads.of(trunk, actuation, np.ones(B))
    rest_states, rest_geometry = context.rest(B)
    with np.errstate(all="ignore"):
        reference = _force_scale(trunk, evaluate(context, rest_states, full, rest_geometry).gradient)
    # zero or non-finite references, dead moments and follower loads (LU factors): the single
    # solve's own cases
    run.leave(np.flatnonzero(~(reference > 0.0) | ~np.isfinite(reference)), "no load at rest, or not finite")
    if trunk.loads.unsymmetric:
        run.leave(np.arange(B), "dead moments or follower loads (an unsymmetric tangent: LU factors)")
    if np.any(trunk.actuators.friction):
        run.leave(np.arange(B), "cable friction (a fixed point of the capstan law over Newton solves)")
    if trunk.contact is not None:
        run.leave(np.arange(B), "contacts (the sequential-QP step on the gaps)")
    xi = np.broadcast_to(rest_xi, (B,) + rest_xi.shape).copy()
    if start is not None:
        given = warm & np.all(np.isfinite(start.reshape(B, -1)), 1)
        run.leave(np.flatnonzero(warm & ~given), "a start state given by its poses only")
        xi[given] = start[given]
    if start is None:                  # every sample from rest: the rest state composed once (a copy: stages write it)
        states, carried = rest_states.take(np.arange(B)), np.ones(B, bool)
    else:
        states, carried = compose(trunk, xi)
    run.leave(np.flatnonzero(~carried), "a start state whose links turn beyond the carried strains")
    scale = np.zeros(B)
    increment = np.where(warm, 1.0, 1.0 / load_steps)
    stages = np.zeros(B, int)
    converged = np.zeros(B, bool)
    residual_of = np.full(B, np.nan)
    active = ~run.single
    while active.any():
        rows = np.flatnonzero(active)
        target = np.minimum(1.0, scale[rows] + increment[rows])
        tolerances = np.where(target >= 1.0, tolerance, max(tolerance, 1e-6))
        budget = np.minimum(max_iterations, BUDGET * max_iterations - run.iterations[rows])
        load = Loads.of(trunk, actuation[rows], target)
        with np.errstate(all="ignore"):
            geometry = None            # the first stage from rest: the rest state's kinematics, kept
            if start is None and not stages[rows].any():
                geometry = rest_geometry if rows.size == B else _take(rest_geometry, rows, B)
            done, reached = run.stage(rows, states.take(rows) if rows.size < B else states, load, tolerances,
                                      budget, reference[rows] * np.maximum(target, 1e-300), geometry)
        stages[rows] += 1
        ok = rows[done]
        states.put(ok, reached.take(np.flatnonzero(done)))
        scale[ok] = target[done]
        finished = ok[scale[ok] >= 1.0]
        converged[finished] = True
        residual_of[finished] = [run.history[i][-1] for i in finished.tolist()]
        going = ok[scale[ok] < 1.0]
        increment[going] = np.minimum(2.0 * increment[going], 1.0 - scale[going])
        active = ~run.single & ~converged
    return {"run": run, "states": states, "converged": converged, "stages": stages, "residual": residual_of}


def solve_batch(model, actuation: np.ndarray, initial=None, *, tolerance: float, max_iterations: int,
                load_steps: int, chunk: int | None = None, progress=None) -> BatchResult:
    """The equilibria of the actuations ``actuation`` (B, n_act) (see the module docstring).
    ``initial``: None (every sample from rest, the load stepped in ``load_steps`` stages), or start
    states — a (B, n_links, 6) array of link strains (rows of nan: from rest), a sequence of
    :class:`~vertebra.solver.state.State` (None entries: from rest) or one State for all; a warm
    sample tries the full load first, as the single solve does. ``chunk``: samples advanced
    together (default :func:`chunk_size`). ``progress(k)`` is called as ``k`` more samples are done."""
    with kept_heap():
        return _solve_batch(model, actuation, initial, tolerance, max_iterations, load_steps, chunk, progress)


def _solve_batch(model, actuation, initial, tolerance, max_iterations, load_steps, chunk, progress) -> BatchResult:
    start_time = time.perf_counter()
    trunk = model.trunk
    actuation = np.asarray(actuation, dtype=float)
    B = actuation.shape[0]
    n, N = trunk.links.count, trunk.frames.count
    start, warm, states_given = _starts(trunk, initial, B)
    context = _Context(trunk)
    chunk = chunk or chunk_size(trunk)
    out = BatchResult(actuation, np.zeros(B, bool), np.zeros(B, int), np.full(B, np.nan), np.full((B, N, 3), np.nan),
                      np.full((B, N, 4), np.nan), np.full((B, n, 6), np.nan), np.zeros(B, int), ["none"] * B,
                      np.zeros(B), [""] * B, np.zeros(B, bool), [""] * B, [""] * B, [[] for _ in range(B)], [()] * B,
                      rest=trunk.rest_state)
    for begin in range(0, B, chunk):
        part = slice(begin, min(B, begin + chunk))
        found = _solve_chunk(context, actuation[part], None if start is None else start[part], warm[part],
                             tolerance, max_iterations, load_steps)
        run, states = found["run"], found["states"]
        rows = np.arange(part.start, part.stop)
        good = found["converged"] & ~run.single
        at = rows[good]
        out.converged[at] = True
        out.residual[at] = found["residual"][good]
        out.positions[at], out.quaternions[at] = states.positions[good], states.quaternions[good]
        out.strains[at] = states.xi[good]
        out.largest_turn[at] = np.sqrt(states.turns2[good])
        out.iterations[rows] = run.iterations
        out.load_steps[rows] = found["stages"]
        for j, i in enumerate(rows.tolist()):
            out.factorization[i] = _KINDS[int(run.kinds[j])]
            out.histories[i] = run.history[j]
        for j in np.flatnonzero(run.single).tolist():           # the single solve, from the sample's own start
            i = rows[j]
            out.single[i] = True
            out.why[i] = run.why[j]
            initial_state = states_given[i] if states_given is not None else None
            try:
                result = model.solve(actuation[i], initial_state, tolerance=tolerance, max_iterations=max_iterations,
                                     load_steps=load_steps, raise_on_failure=False)
            except _FAILURES as error:
                out.messages[i] = str(error) or type(error).__name__
                out.errors[i] = type(error).__name__
                out.iterations[i] = getattr(getattr(error, "result", None), "iterations", 0) or 0
                continue
            out.results[i] = result
            out.converged[i] = result.converged
            out.iterations[i], out.residual[i], out.load_steps[i] = result.iterations, result.residual, result.load_steps
            out.positions[i], out.quaternions[i] = result.state.positions, result.state.quaternions
            record = result.state.carried_strains()
            if record is not None:
                out.strains[i] = record.xi
            out.factorization[i], out.largest_turn[i], out.messages[i] = (result.factorization, result.largest_turn,
                                                                         result.message)
            out.histories[i] = result.residual_history
            out.out_of_range[i] = result.out_of_range
            out.errors[i] = "" if result.converged else "ConvergenceError"
        if trunk.links.fitted:
            for i in at.tolist():
                out.out_of_range[i] = out_of_range(trunk, out.strains[i], model.loads(actuation[i], 1.0))
        if progress is not None:
            progress(len(rows))
    out.timings["solve_s"] = time.perf_counter() - start_time
    return out


def _starts(trunk, initial, B: int):
    """(link strains (B, n, 6) or None, warm (B,), the State objects given or None) of ``initial``."""
    n = trunk.links.count
    if initial is None:
        return None, np.zeros(B, bool), None
    if isinstance(initial, np.ndarray):
        start = np.asarray(initial, dtype=float).reshape(B, n, 6)
        warm = np.all(np.isfinite(start.reshape(B, -1)), 1)
        return start, warm, _LazyStates(trunk, start, warm)
    states = [initial] * B if hasattr(initial, "positions") else list(initial)
    if len(states) != B:
        raise ValueError(f"{len(states)} start states for {B} actuations")
    start = np.full((B, n, 6), np.nan)
    warm = np.zeros(B, bool)
    for i, state in enumerate(states):
        if state is None:
            continue
        record = state.carried_strains()
        warm[i] = True
        if record is not None:
            start[i] = record.xi
    return start, warm, states


class _LazyStates:
    """The start states of link strains given as an array, composed when the single solve needs one."""

    def __init__(self, trunk, start, warm):
        self.trunk, self.start, self.warm = trunk, start, warm

    def __getitem__(self, i):
        if not self.warm[i]:
            return None
        base = self.trunk.rest_state
        return compose_state(base.quaternions[0], base.positions[0], self.start[i].copy())


def bound_violations(model, result: BatchResult) -> list:
    """Every sample's :func:`vertebra.solver.bounds.bound_violations` (empty tuples at once when
    the actuations lie within their bounds and the scene bounds nothing a state makes)."""
    actuators = model.trunk.actuators
    lower, upper = actuators.bounds
    dlo, dhi = actuators.displacement_bounds
    inside = np.all((result.actuation >= lower) & (result.actuation <= upper), 1)
    on_state = bool(np.any(np.isfinite(dlo)) or np.any(np.isfinite(dhi)))
    driven = actuators.stroke_driven
    tendons = driven.any() and any(math.isfinite(c.max_tension) or c.min_tension > 0.0
                                   for c, s in zip(model.scene.cables, driven.tolist()) if s)
    found = []
    for i in range(len(result)):
        if inside[i] and not on_state and not tendons:
            found.append(())
        elif i in result.results:
            found.append(result.results[i].bound_violations or
                         bounds.bound_violations(model, result.results[i].state, result.actuation[i]))
        elif not np.all(np.isfinite(result.strains[i])):
            found.append(())
        else:
            found.append(bounds.bound_violations(model, result.state(i), result.actuation[i]))
    return found


# ----------------------------------------------------------------------------- path tangents
LINEARISATION_SHIFTS = (0.0, 1e-8, 1e-6, 1e-4)   # μ tried when a tangent is singular (outputs.linearise's)


def path_tangents(model, strains: np.ndarray, actuation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangents ``dq/dλ = K⁻¹ B`` (B, n_dof, n_act) of the equilibrium paths through the
    equilibria of link strains ``strains`` (B, n, 6) under ``actuation`` (B, n_act) — what
    ``model.linearise(state, λ)``'s ``solve(actuator_forces)`` gives for one (the tangent's
    factor with the same shifts when it is singular, the actuator forces of cables, tendons and
    chambers) — and which samples have one (a tangent that no shift factors has none). Taken in
    chunks of :func:`chunk_size` samples."""
    paths, has, _ = _chunked_paths(model, strains, actuation, False)
    return paths, has


def strain_paths(model, strains: np.ndarray, actuation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The path tangents of :func:`path_tangents` in strain space: ``dξ/dλ = G K⁻¹ B``
    (B, n, 6, n_act), the links' linearised strain change (``Links.strain_change``) along each
    actuator's path tangent, and which samples have one. The Euler predictor of an equilibrium
    ``ξ`` under an actuation change ``Δλ`` is then ``ξ + dξ/dλ Δλ`` (:func:`predicted_strains`'s
    retraction, one small product per child instead of composing the parent's chain again)."""
    _, has, paths = _chunked_paths(model, strains, actuation, True)
    return paths, has


def _chunked_paths(model, strains, actuation, in_strains: bool):
    size = chunk_size(model.trunk)
    if strains.shape[0] > size:
        parts = [_path_tangents(model, strains[k:k + size], actuation[k:k + size], in_strains)
                 for k in range(0, strains.shape[0], size)]
        paths, has, xi_paths = (np.concatenate([p[i] for p in parts]) if parts[0][i] is not None else None
                                for i in range(3))
        return paths, has, xi_paths
    return _path_tangents(model, strains, actuation, in_strains)


def _path_tangents(model, strains: np.ndarray, actuation: np.ndarray, in_strains: bool = False):
    trunk = model.trunk
    context = _Context(trunk)
    B = strains.shape[0]
    states, carried = compose(trunk, strains)
    load = Loads.of(trunk, actuation, np.ones(B))
    with np.errstate(all="ignore"):
        ev = evaluate(context, states, load)
        matrix = tangent(context, ev)
        scale = np.abs(matrix.diagonal()) + 1e-300
        forces = actuator_forces(context, states, ev)                  # (B, n_act, n_dof)
        paths = np.zeros(forces.shape[:1] + forces.shape[2:] + forces.shape[1:2])
        has = np.zeros(B, bool)
        pending = np.flatnonzero(carried & np.isfinite(ev.energy))
        for shift in LINEARISATION_SHIFTS:
            if not pending.size:
                break
            factor = matrix.take(pending).factor(np.full(pending.size, shift), scale[pending])
            if factor.ok.any():
                done = pending[factor.ok]
                paths[done] = factor.solve(forces[pending].mT)[factor.ok]
                has[done] = True
            pending = pending[~factor.ok]
        has &= np.all(np.isfinite(paths.reshape(B, -1)), 1)
        xi_paths = None
        if in_strains:                 # G [P_a; P_b] per link, the base frame fixed (its rows zero)
            n_act = paths.shape[2]
            frames = np.zeros((B, trunk.frames.count, 6, n_act))
            frames[:, 1:] = paths.reshape(B, -1, 6, n_act)
            pairs = np.concatenate([frames[:, :-1], frames[:, 1:]], 2).reshape(-1, 12, n_act)
            xi_paths = (ev.links.G @ pairs).reshape(B, -1, 6, n_act)
    return paths, has, xi_paths


def actuator_forces(context: _Context, states: States, ev: Evaluation) -> np.ndarray:
    """``∂r/∂λ`` (B, n_act, n_dof) of every sample (:func:`vertebra.solver.outputs.linearise`'s
    actuator forces): a cable's ``−∂L/∂q``, a tendon's ``−k ∂L/∂q`` while taut, a chamber's
    ``(∂ξ/∂q)ᵀ(−∂²ψ/∂ξ∂p)``."""
    return actuator_jacobians(context, states, ev)[1]


def actuator_jacobians(context: _Context, states: States, ev: Evaluation) -> tuple[np.ndarray, np.ndarray]:
    """The actuators' Jacobians (B, n_act, n_dof) of every sample — ``∂L/∂q`` of the cables, the
    chambers' volume growth ``∂ΔV/∂q`` — and the actuator forces ``∂r/∂λ`` made of them
    (:func:`actuator_forces`): −1, −k (taut tendon) or 0 (slack tendon) times a cable's row, a
    chamber's as it is (:func:`vertebra.solver.outputs.linearise`'s ``actuator_jacobian`` and
    ``actuator_forces``)."""
    trunk = context.trunk
    B = len(states)
    actuators = trunk.actuators
    n_cables, n_chambers = actuators.n_cables, actuators.n_chambers
    N = trunk.frames.count
    jacobian = np.zeros((B, n_cables + n_chambers, N, 6))
    scale = np.ones((B, n_cables + n_chambers))
    if n_cables:
        pieces = ev.pieces
        if pieces is None:
            pieces = CablePieces.of_spans(*trunk.cables.spans(states.positions, states.rotations))
        jacobian[:, :n_cables] = _cable_jacobian(context, pieces, B)
        scale[:, :n_cables] = -1.0
        if ev.load.tendons is not None:
            cables, k = ev.load.tendons[:2]
            scale[:, cables] = -k * (ev.elongation > 0.0)
    if n_chambers:
        xi = states.xi
        per_link = np.empty((B, trunk.links.count, n_chambers, 6))
        for energy, prepared, kept in zip(trunk.links.energies, ev.load.link_loads, ev.kept):
            per_link[:, energy.links] = energy.chamber_forces(xi[:, energy.links], prepared, kept)
        g = ev.links.gradient(per_link.reshape(-1, n_chambers, 6)).reshape(B, -1, n_chambers, 12)
        chambers = jacobian[:, n_cables:]
        chambers[:, :, :-1] += np.moveaxis(g[..., :6], 2, 1)
        chambers[:, :, 1:] += np.moveaxis(g[..., 6:], 2, 1)
    jacobian = jacobian[:, :, 1:].reshape(B, n_cables + n_chambers, trunk.n_dof)
    return jacobian, jacobian * scale[:, :, None]


def effector_jacobian(trunk, rotations: np.ndarray) -> np.ndarray:
    """``∂(effector positions)/∂q`` (B, 3·n_effectors, n_dof) at frame rotations (B, N, 3, 3)
    (:func:`vertebra.solver.outputs.linearise`'s ``effector_jacobian``: a point's ``dx_f − (R r)^ dφ_f``,
    an axis's ``−(R a)^ dφ_f``)."""
    effectors = trunk.effectors
    B, n_eff = rotations.shape[0], len(effectors.names)
    jacobian = np.broadcast_to(effectors.translation_jacobian, (B,) + effectors.translation_jacobian.shape).copy()
    for k in range(n_eff):
        turned = rotations[:, effectors.frames[k]] @ effectors.offsets[k]
        jacobian[:, k, :, effectors.frames[k], 3:] = -hat(turned)
    return jacobian.reshape(B, 3 * n_eff, trunk.frames.count, 6)[:, :, 1:].reshape(B, 3 * n_eff, trunk.n_dof)


def predicted_strains(model, strains: np.ndarray, paths: np.ndarray, change: np.ndarray) -> np.ndarray:
    """Link strains (B, n, 6) of the equilibria ``strains`` moved along their path tangents
    ``paths`` (B, n_dof, n_act) by the actuation changes ``change`` (B, n_act): the Euler
    predictor ``q ⊕ K⁻¹B Δλ`` with the strain-space retraction (``model.step``). Taken in chunks
    of :func:`chunk_size` samples."""
    size = chunk_size(model.trunk)
    if strains.shape[0] > size:
        return np.concatenate([predicted_strains(model, strains[k:k + size], paths[k:k + size], change[k:k + size])
                               for k in range(0, strains.shape[0], size)])
    trunk = model.trunk
    states, _ = compose(trunk, strains)
    links = _links(states)
    dq = (paths @ change[:, :, None])[:, :, 0]
    return strains + _strain_change(links, dq)


def actuation_sensitivities(model, result: BatchResult) -> dict:
    """Per-sample derivatives with respect to the actuation at the equilibria of a batch, from
    the batched factors (:func:`path_tangents`): ``dq`` (B, n_dof, n_act) — what
    ``model.sensitivities(state, λ, wrt=("actuation",)).dq`` gives for one — and
    ``effector_positions`` (B, 3·n_effectors, n_act); ``has`` (B,) marks the samples that have
    them (converged, with a tangent some shift factors: the path tangents of the workspace's
    predictor). Every parameter group and output, each sample's ``model.sensitivities`` to
    rounding: :func:`vertebra.solver.sensitivity.batch_sensitivities`."""
    trunk = model.trunk
    B = len(result)
    n_act = result.actuation.shape[1]
    dq = np.full((B, trunk.n_dof, n_act), np.nan)
    has = np.zeros(B, bool)
    rows = np.flatnonzero(result.converged & np.all(np.isfinite(result.strains.reshape(B, -1)), 1))
    if rows.size:
        dq[rows], has[rows] = path_tangents(model, result.strains[rows], result.actuation[rows])
    rotations = np.zeros((B, trunk.frames.count, 3, 3))
    if rows.size:
        rotations[rows] = compose(trunk, result.strains[rows])[0].rotations
    jacobian = effector_jacobian(trunk, rotations)
    return {"dq": dq, "effector_positions": jacobian @ np.nan_to_num(dq) * np.where(has, 1.0, np.nan)[:, None, None],
            "has": has}
