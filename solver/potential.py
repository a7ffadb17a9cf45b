"""The trunk's total potential, its gradient and its tangent at a state (paper eq. 9).

The potential is the sum of the links' energies ``Σ ψ(ξ, p)`` (:mod:`vertebra.solver.kinds`),
the cables' ``Σ τ L``, the weight ``−Σ m g · (x + R s)`` and the dead forces ``−F · x``; dead
moments are not conservative in 3D and enter the gradient only (as ``−M``), and so do follower
loads (a force ``f`` and moment ``m`` fixed in a frame's axes: ``−[R f; R m]``, whose turning
with the frame, ``+[R f]ˣ`` and ``+[R m]ˣ`` on its rotation, makes the tangent unsymmetric).
The gradient is taken along the solver's chart (``x + dx``, ``exp(dφ) R``, world axes), so the
residual of equilibrium is ``−gradient`` on the free frames.

Everything here is a function of its arguments: :func:`evaluate` returns an :class:`Evaluation`
that carries what :func:`tangent` (and a later evaluation of the same state) reuses — the
kinematics, the link responses, the cable spans. Nothing is remembered elsewhere: a caller that
wants reuse hands back the evaluation (or the :class:`Trial` of :func:`potential`) it holds as
``previous``. Model constants (the unstressed tangent, the stiffness scale) are computed once by
:func:`rest_constants`. :func:`evaluate` computes only what the scene uses (no cables → no cable
terms, and so on).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vertebra.solver.assembly import Tangent
from vertebra.solver.cables import CablePieces
from vertebra.core.lie import hat, qmatrix
from vertebra.solver.links import Links, link_tangent


@dataclass(slots=True)
class LoadCase:
    """What an actuation and a load factor make of the loads (computed once per Newton stage;
    not modified once made, except that the forward solve fills in ``reference`` once)."""

    actuation: np.ndarray
    scale: float
    pressures: np.ndarray                 # scaled chamber pressures
    link_loads: tuple                     # what each link energy prepared of the pressures
    piece_tension: np.ndarray | None      # tension of every piece of a tension-driven cable (None: all slack)
    tendons: "Tendons | None"             # the stroke-driven tendons (None: there are none)
    weight: np.ndarray | None             # scaled gravity vector
    weight_hat: np.ndarray | None
    frame_weight: np.ndarray | None       # (n_frames, 3) m g
    dead: np.ndarray | None               # (n_frames, 6) scaled dead loads
    dead_forces: np.ndarray | None        # (n_frames, 3), contiguous
    follower: np.ndarray | None = None    # (k, 6) scaled follower wrenches (frame axes) at frames ``followed``
    followed: np.ndarray | None = None    # (k,) the frames that carry follower loads
    reference: float | None = None        # the forward solve's force scale (newton.reference_force)

    @classmethod
    def of(cls, trunk, actuation: np.ndarray, scale: float, previous: "LoadCase | None" = None) -> "LoadCase":
        """The load case of ``actuation`` at load factor ``scale``; the weight and dead loads of a
        ``previous`` case at the same factor are taken as they are."""
        actuators = trunk.actuators
        n_cables = actuators.n_cables
        tensions = scale * actuation[:n_cables]
        pressures = scale * actuation[n_cables:]
        link_loads = tuple(e.prepare(pressures) for e in trunk.links.energies)
        tendons = None
        if n_cables and actuators.tendons.size:
            tendons = Tendons.of(trunk, tensions, scale)       # (the stroke-driven values are strokes)
            tensions = np.where(actuators.stroke_driven, 0.0, tensions)
        piece_tension = tensions.take(trunk.cables.owner, mode="clip") if n_cables and tensions.any() else None
        if previous is not None and previous.scale == scale:
            return cls(actuation, scale, pressures, link_loads, piece_tension, tendons, previous.weight,
                       previous.weight_hat, previous.frame_weight, previous.dead, previous.dead_forces,
                       previous.follower, previous.followed)
        loads = trunk.loads
        weight = weight_hat = frame_weight = dead = dead_forces = None
        if loads.has_gravity:
            weight = scale * loads.gravity
            weight_hat = hat(weight)
            frame_weight = trunk.frames.mass[:, None] * weight
        if loads.has_dead_forces or loads.has_dead_moments:
            dead = scale * loads.dead
            dead_forces = np.ascontiguousarray(dead[:, :3])
        follower = followed = None
        if loads.has_follower:
            followed = 1 + np.flatnonzero(np.any(loads.follower[1:], axis=1))     # (the base is clamped)
            follower = scale * loads.follower[followed]
        return cls(actuation, scale, pressures, link_loads, piece_tension, tendons, weight, weight_hat, frame_weight,
                   dead, dead_forces, follower, followed)

    @property
    def cables(self) -> bool:
        """Are the cables evaluated (some tension-driven cable pulls, or there are tendons)?"""
        return self.piece_tension is not None or self.tendons is not None


@dataclass(frozen=True, slots=True)
class Tendons:
    """The stroke-driven tendons of a load case. A tendon's elongation is
    ``e = L(q) − L₀ + s + T₀/k`` (``L``: its length through the holes, ``s``: the servo's stroke,
    ``T₀``: its pretension at zero stroke, ``k``: its spring rate) and its tension ``k·max(0, e)``:
    its potential ``½ k max(0, e)²`` is C¹ with a kink in its curvature where it goes slack, which
    the Newton iteration meets with the one-sided tangent and a line search on the energy."""

    cables: np.ndarray        # (t,) cable index of each tendon
    stiffness: np.ndarray     # (t,) k, N/m
    rest: np.ndarray          # (t,) L₀, the rest lengths
    shift: np.ndarray         # (t,) s + T₀/k at the load factor (the elongation at rest)
    # with friction (solver/friction.py) a tendon is split into units — runs of pieces joined by
    # sliding holes — whose length is Σ g L over their pieces (g: the capstan factors of the
    # run) and whose piece tensions are g times the unit's; None: every tendon is one unit of
    # its whole cable with g = 1
    units: np.ndarray | None = None     # (m,) unit of every piece (t: a piece of no unit)
    weights: np.ndarray | None = None   # (m,) g of every piece in its unit

    def lengths(self, cables, piece_lengths: np.ndarray) -> np.ndarray:
        """The length of every unit from the pieces' lengths (a whole tendon's: its cable's)."""
        if self.units is None:
            return np.bincount(cables.owner, piece_lengths, minlength=cables.n_cables)[self.cables]
        return np.bincount(self.units, self.weights * piece_lengths, minlength=self.cables.size + 1)[:-1]

    def piece_tension(self, cables, tension: np.ndarray) -> np.ndarray:
        """The tension of every piece from the units' ``tension`` (0 on the other cables' pieces)."""
        if self.units is None:
            full = np.zeros(cables.n_cables)
            full[self.cables] = tension
            return full[cables.owner]
        full = np.zeros(self.cables.size + 1)
        full[:-1] = tension
        return self.weights * full[self.units]

    def jacobian(self, cables, pieces: CablePieces) -> np.ndarray:
        """``∂(unit length)/∂q`` (t, n_frames, 6) of every unit."""
        if self.units is None:
            return cables.jacobian(pieces)[self.cables]
        rows = np.repeat(self.units, 2) * cables.n_frames + cables.ends
        out = np.zeros(((self.cables.size + 1) * cables.n_frames, 6))
        np.add.at(out, rows, (self.weights[:, None] * pieces.unit).reshape(-1, 6))
        return out.reshape(-1, cables.n_frames, 6)[:-1]

    @classmethod
    def of(cls, trunk, values: np.ndarray, scale: float) -> "Tendons":
        """From the cables' values at load factor ``scale`` (``values``: already scaled; the
        tendons' are strokes), the pretension scaled alike."""
        actuators = trunk.actuators
        cables = actuators.tendons
        k = actuators.cable_stiffness[cables]
        return cls(cables, k, trunk.rest_cable_lengths[cables],
                   values[cables] + scale * actuators.pretension[cables] / k)

    def elongation(self, lengths: np.ndarray) -> np.ndarray:
        """``e`` of every unit from its length (:meth:`lengths`)."""
        return lengths - self.rest + self.shift

    def tension(self, elongation: np.ndarray) -> np.ndarray:
        """``k·max(0, e)``: a tendon never pushes."""
        return self.stiffness * np.maximum(elongation, 0.0)


class LoadCases:
    """The load cases of the last two (actuation, load factor) pairs asked for, most recent
    first: repeated solves and linearisations at one actuation make theirs once, a control
    tick's two actuations (linearised at one, stepped to the other) alternate without remaking
    them, and a new actuation at the same load factor keeps the weight and dead loads."""

    def __init__(self, trunk):
        self._trunk = trunk
        self._kept = [(None, None, None), (None, None, None)]

    def __call__(self, actuation: np.ndarray, scale: float = 1.0) -> LoadCase:
        """The load case of ``actuation`` at load factor ``scale``."""
        key = actuation.tobytes()
        kept = self._kept
        for k, (last_key, last_scale, load) in enumerate(kept):
            if last_key == key and last_scale == scale:
                if k:
                    kept.reverse()
                return load
        load = LoadCase.of(self._trunk, actuation, scale, kept[0][2])
        kept[1], kept[0] = kept[0], (key, scale, load)
        return load

    def link_loads(self, pressures: np.ndarray) -> tuple:
        """What the link energies prepared of the chamber ``pressures`` (a kept load case's when
        one has these pressures)."""
        for _, _, load in self._kept:
            if load is not None and np.array_equal(load.pressures, pressures):
                return load.link_loads
        return tuple(e.prepare(pressures) for e in self._trunk.links.energies)


@dataclass(slots=True)
class Evaluation:
    """Potential and gradient at a state, with what the tangent reuses."""

    energy: float                 # total potential (dead moments excluded: not conservative)
    gradient: np.ndarray          # (n_frames, 6), dead moments included (as −M)
    links: Links                  # kinematics of the links
    w: np.ndarray                 # (n_links, 6) ∂ψ/∂ξ of every link
    kept: tuple                   # what each link energy's response kept for its derivatives
    link_gradient: np.ndarray     # (n_links, 12) the links' gradient on their two frames
    pieces: CablePieces | None    # cable kinematics (None when every cable is slack)
    lever: np.ndarray | None      # (n_frames, 3) R s, the first mass moments in world axes (gravity)
    load: LoadCase
    at_rest: bool                 # evaluated at the trunk's rest state
    record: object = None         # the StrainRecord of the state (None: evaluated from its poses)
    parts: "PotentialParts | None" = None
    follower: np.ndarray | None = None    # (k, 6) the follower loads in world axes at load.followed


@dataclass(slots=True)
class Trial:
    """The potential at a state without its gradient (:func:`potential`), with what it computed
    on the way: an :func:`evaluate` of the same state under the same load case, handed this as
    ``previous``, reuses it (a control tick judges the state that the next tick linearises)."""

    energy: float
    record: object                # the StrainRecord of the state
    load: LoadCase
    parts: "PotentialParts"


@dataclass(frozen=True, slots=True)
class RestConstants:
    """What the unstressed rest state gives once per trunk (:func:`rest_constants`)."""

    link_tangent: np.ndarray      # (n_links, 12, 12) the links' tangent at the unstressed rest state
    stiffness: np.ndarray         # (n_dof,) its diagonal: the stiffness of every DoF in its own units
    axis: np.ndarray              # (n_links, 3) ρ₀/|ρ₀|²: a link's axial stretch is ρ · axis
    shortest: float               # the shortest |ρ₀|


def evaluate(trunk, state, load: LoadCase, previous: "Evaluation | Trial | None" = None) -> Evaluation:
    """Potential and gradient at ``state`` under ``load``. ``previous``: an evaluation (or trial)
    the caller holds; what it computed for the same state (kinematics) and load (link
    responses, cable spans, lever arms) is reused."""
    x = state.positions
    record = state.carried_strains()
    if record is not None:
        links = record.links
        rotations = record.chain.rotations
    else:
        q = state.quaternions
        links = Links.of(q[:-1], x[:-1], q[1:], x[1:])
        rotations = qmatrix(q) if load.cables or load.weight is not None or load.follower is not None else None
    parts = energy = None
    if previous is not None and record is not None and previous.record is record and previous.load is load:
        parts, energy = previous.parts, previous.energy
    if parts is None:
        parts = _potential_parts(trunk, x, rotations, links.xi, load)
        energy = _total(trunk, x, parts, load)
    _, w, kept = parts.response
    g_links = links.gradient(w)
    grad = np.zeros((x.shape[0], 6))
    grad[:-1] = g_links[:, :6]
    grad[1:] += g_links[:, 6:]

    pieces = None
    if load.cables:
        pieces = CablePieces.of_spans(*parts.spans)
        grad += trunk.cables.frame_forces(pieces, parts.piece_tension)

    lever = parts.lever
    if load.weight is not None:
        grad[:, :3] -= load.frame_weight
        grad[:, 3:] -= lever.dot(load.weight_hat)                 # moment (R s) × m g at the frame

    if load.dead is not None:
        grad -= load.dead
    follower = None
    if load.follower is not None:
        follower = follower_wrenches(rotations, load)
        grad[load.followed] -= follower
    return Evaluation(energy, grad, links, w, kept, g_links, pieces, lever, load,
                      record is not None and record is trunk.rest_state.strains, record, parts, follower)


def follower_wrenches(rotations: np.ndarray, load: LoadCase) -> np.ndarray:
    """The follower loads of ``load`` in world axes, ``[R f; R m]`` (k, 6), at the frames
    ``load.followed`` whose rotations are ``rotations[load.followed]``."""
    R = rotations[load.followed]
    return np.concatenate([R @ load.follower[:, :3, None], R @ load.follower[:, 3:, None]], axis=1)[:, :, 0]


def nonpotential_forces(trunk, state, load: LoadCase) -> np.ndarray | None:
    """The generalised forces (n_dof,) on the free frames that have no potential — the dead
    moments and the follower loads at ``state`` — or None when there are none: a step ``dq``
    from ``state`` does their linearised work ``f · dq``, which an energy-like merit (the
    potential minus that work) counts as a decrease."""
    if not trunk.loads.unsymmetric:
        return None
    forces = np.zeros((trunk.frames.count, 6))
    if load.dead is not None:
        forces[:, 3:] = load.dead[:, 3:]
    if load.follower is not None:
        record = state.carried_strains()
        rotations = record.chain.rotations if record is not None else qmatrix(state.quaternions)
        forces[load.followed] += follower_wrenches(rotations, load)
    return forces[1:].reshape(-1)


def potential(trunk, state, load: LoadCase) -> "Trial | Evaluation":
    """The total potential at ``state`` under ``load`` without its gradient (the same terms as
    :func:`evaluate`): what judging a step needs. A state that carries its strains needs no
    link kinematics: the :class:`Trial` returned keeps what it computed for an evaluation of
    the same state and load; a state given by its poses is evaluated in full. Either way
    ``.energy`` is the potential."""
    record = state.carried_strains()
    if record is None:
        return evaluate(trunk, state, load)
    x = state.positions
    parts = _potential_parts(trunk, x, record.chain.rotations, record.xi, load)
    return Trial(_total(trunk, x, parts, load), record, load, parts)


@dataclass(slots=True)
class PotentialParts:
    """What the potential at a state computes on the way that its gradient needs too."""

    response: tuple                 # link_response(): (Σ ψ, w, kept)
    spans: tuple | None             # the cable pieces' CableRouting.spans() (None: all slack)
    lever: np.ndarray | None        # (n_frames, 3) R s, the first mass moments in world axes (gravity)
    piece_tension: np.ndarray | None = None   # tension of every piece, the tendons' included
    elongation: np.ndarray | None = None      # (t,) the tendons' elongation e (tension k·max(0, e))


def _potential_parts(trunk, x: np.ndarray, rotations, xi: np.ndarray, load: LoadCase) -> PotentialParts:
    spans = trunk.cables.spans(x, rotations) if load.cables else None
    lever = (rotations @ trunk.frames.moment[:, :, None])[:, :, 0] if load.weight is not None else None
    parts = PotentialParts(link_response(trunk, xi, load.link_loads), spans, lever, load.piece_tension)
    tendons = load.tendons
    if tendons is not None:
        cables = trunk.cables
        parts.elongation = tendons.elongation(tendons.lengths(cables, spans[2]))
        pieces = tendons.piece_tension(cables, tendons.tension(parts.elongation))
        parts.piece_tension = pieces if load.piece_tension is None else pieces + load.piece_tension
    return parts


def _total(trunk, x: np.ndarray, parts: PotentialParts, load: LoadCase) -> float:
    """The total potential (dead moments excluded) at positions ``x`` from its ``parts``: the
    links' energies, the cables' ``τ L``, the weight's ``−Σ m g · (x + R s)`` and ``−F · x``."""
    total = parts.response[0]
    if load.piece_tension is not None:
        total += float(load.piece_tension @ parts.spans[2])
    if parts.elongation is not None:
        taut = np.maximum(parts.elongation, 0.0)
        total += 0.5 * float(load.tendons.stiffness @ (taut * taut))
    if parts.lever is not None:
        total -= float((trunk.frames.mass @ x + np.add.reduce(parts.lever)) @ load.weight)
    if load.dead is not None:
        total -= float(np.vdot(load.dead_forces, x))
    return total


def link_response(trunk, xi: np.ndarray, link_loads: tuple) -> tuple[float, np.ndarray, tuple]:
    """``(Σ ψ, w = ∂ψ/∂ξ (n, 6), kept)`` over the link energies; ``kept`` holds, per energy, what
    its response kept for the derivatives (:class:`~vertebra.solver.kinds.LinkEnergy`)."""
    energies = trunk.links.energies
    if len(energies) == 1:
        total, w, kept = energies[0].response(xi, link_loads[0])
        return total, w, (kept,)
    w = np.empty_like(xi)
    total = 0.0
    kept = []
    for energy, prepared in zip(energies, link_loads):
        part, w[energy.links], values = energy.response(xi[energy.links], prepared)
        total += part
        kept.append(values)
    return total, w, tuple(kept)


def out_of_range(trunk, xi: np.ndarray, load: LoadCase) -> tuple:
    """Every quantity of the link strains ``xi`` under ``load`` that lies outside the range its
    energy was fitted on (:class:`~vertebra.solver.kinds.RangeExcess`, link order); empty when
    no link energy is fitted."""
    found = []
    for energy, prepared in zip(trunk.links.energies, load.link_loads):
        found.extend(energy.out_of_range(xi[energy.links], prepared))
    return tuple(sorted(found, key=lambda excess: excess.link))


def _per_link(trunk, ev: Evaluation, method: str, shape: tuple) -> np.ndarray:
    """A per-link quantity of every link energy (``method``: ``material_tangent`` or
    ``chamber_forces``), side by side in link order."""
    energies, xi = trunk.links.energies, ev.links.xi
    if len(energies) == 1:
        return getattr(energies[0], method)(xi, ev.load.link_loads[0], ev.kept[0])
    out = np.empty((xi.shape[0],) + shape)
    for energy, prepared, kept in zip(energies, ev.load.link_loads, ev.kept):
        out[energy.links] = getattr(energy, method)(xi[energy.links], prepared, kept)
    return out


def chamber_forces(trunk, ev: Evaluation) -> np.ndarray:
    """``−∂²ψ/∂ξ∂p`` (n_links, n_chambers, 6): the strain-space force per unit pressure."""
    return _per_link(trunk, ev, "chamber_forces", (trunk.actuators.n_chambers, 6))


def volume_growth(trunk, links: Links, pressures: np.ndarray, link_loads: tuple) -> np.ndarray:
    """``−∂ψ/∂p`` (n_chambers,): the chambers' volume growth (``link_loads``: what the link
    energies prepared of ``pressures``)."""
    total = np.zeros(trunk.actuators.n_chambers)
    for energy, prepared in zip(trunk.links.energies, link_loads):
        total += energy.volume_growth(links.xi[energy.links], prepared, pressures)
    return total


def link_tangents(trunk, ev: Evaluation, out: np.ndarray) -> np.ndarray:
    """The links' tangents (n_links, 12, 12) into ``out``."""
    energies = trunk.links.energies
    material = (energies[0].material_tangent(ev.links.xi, ev.load.link_loads[0], ev.kept[0]) if len(energies) == 1
                else _per_link(trunk, ev, "material_tangent", (6, 6)))
    return link_tangent(ev.links, ev.w, material, ev.link_gradient, out=out)


def tangent(trunk, ev: Evaluation) -> Tangent:
    """Tangent of the gradient at the state of ``ev``: its terms side by side — the links',
    the cables' (summed per pair of frames) and the turning of frame-fixed loads (the weight's
    lever arms, follower loads) — from which the assembler gathers the bands. At the unstressed
    rest state the links' part is a model constant (``trunk.rest.link_tangent``)."""
    assembler = trunk.assembler
    terms, links, cables, turning = assembler.new_terms()
    if ev.at_rest and not ev.w.any() and not ev.load.pressures.any():
        links[:] = trunk.rest.link_tangent
    else:
        link_tangents(trunk, ev, links)
    if ev.pieces is not None:
        ev.pieces.tangent(ev.parts.piece_tension, assembler.cable_groups, out=cables)
    else:
        cables[:] = 0.0
    if turning is not None:
        turning[:] = 0.0
        if ev.load.weight is not None:                      # (the lever arms were evaluated)
            np.matmul(-ev.load.weight_hat, hat(ev.lever[1:]), out=turning[:, 3:])   # −ĝ l̂: the arm turns
        if ev.follower is not None:                         # −R f turns to −(R f + dφ × R f): +[R f]ˣ
            turning[ev.load.followed - 1] += hat(ev.follower.reshape(-1, 3)).reshape(-1, 6, 3)
    return Tangent(assembler, terms, tendon_stiffness(trunk, ev))


def tendon_stiffness(trunk, ev: Evaluation) -> tuple | None:
    """The taut tendons' ``k ∂L/∂q (∂L/∂q)ᵀ`` as ``(U, d)``: the columns ``∂L/∂q`` over the free
    frames (n_dof, r) and the spring rates (r,); None when every tendon is slack (or there are
    none)."""
    tendons = ev.load.tendons
    if tendons is None:
        return None
    taut = ev.parts.elongation > 0.0
    if not taut.any():
        return None
    jacobian = tendons.jacobian(trunk.cables, ev.pieces)[taut, 1:]
    return np.ascontiguousarray(jacobian.reshape(-1, trunk.n_dof).T), tendons.stiffness[taut]


def cable_tensions(trunk, ev: Evaluation) -> np.ndarray:
    """The tension of every cable at the state of ``ev`` (the tendons' from their elongation)."""
    n_cables = trunk.actuators.n_cables
    tensions = ev.load.scale * ev.load.actuation[:n_cables]
    tendons = ev.load.tendons
    if tendons is None:
        return tensions
    tensions = tensions.copy()
    tensions[tendons.cables] = tendons.tension(ev.parts.elongation)
    return tensions


def rest_constants(trunk) -> RestConstants:
    """The links' tangent at the unstressed rest state, its diagonal (the stiffness scale of
    every DoF: positive, every free frame has a link) and the links' rest axes."""
    unloaded = LoadCase.of(trunk, np.zeros(trunk.actuators.default.size), 0.0)
    ev = evaluate(trunk, trunk.rest_state, unloaded)
    link_tangent = link_tangents(trunk, ev, np.empty((trunk.links.count, 12, 12)))
    stiffness = Tangent(trunk.assembler, _links_only_terms(trunk.assembler, link_tangent)).diagonal().copy()
    rest = trunk.links.rest[:, :3]
    squared = np.einsum("ij,ij->i", rest, rest)
    axis = rest / squared[:, None]
    for array in (link_tangent, stiffness, axis):
        array.flags.writeable = False
    return RestConstants(link_tangent, stiffness, axis, float(np.sqrt(squared.min())))


def _links_only_terms(assembler, link_tangent: np.ndarray) -> np.ndarray:
    terms, links, cables, turning = assembler.new_terms()
    links[:] = link_tangent
    cables[:] = 0.0
    if turning is not None:
        turning[:] = 0.0
    return terms
