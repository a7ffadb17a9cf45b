"""The compiled trunk: a scene turned once into arrays (frames, links, cables, chambers, loads,
effectors) and the band index maps, validated and read-only.

Vertebra 0 is the clamped base frame. Each repetition of a segment adds ``elements`` links and
ends at a vertebra frame. Each segment's links are made by its link kind
(:mod:`vertebra.solver.kinds`); links whose kinds share an energy class are compiled into one
batch. A link's mass is lumped on its two frames by the lever rule along its axis (lateral
offsets kept, so gravity also makes moments).
"""

from __future__ import annotations

import functools
import math
import dataclasses
from dataclasses import dataclass, fields

import numpy as np

from vertebra.solver.assembly import BandAssembler
from vertebra.solver.cables import CableRouting
from vertebra.solver.contact import ContactModel, check_rest, compile_contact, coupled_frames
from vertebra.solver.potential import RestConstants, rest_constants
from vertebra.solver.kinds import CompiledLinks, kind_for
from vertebra.core.energy import rest_strain
from vertebra.core.lie import qmatrix
from vertebra.solver.state import State, compose
from vertebra.core.errors import SceneError


def _read_only(value):
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    return value


class _Frozen:
    """Frozen dataclasses whose arrays are made read-only once validated."""

    def __post_init__(self):
        self.validate()
        for f in fields(self):
            _read_only(getattr(self, f.name))

    def validate(self) -> None:
        pass


@dataclass(frozen=True)
class Frames(_Frozen):
    """The frames: vertebrae and the internal frames of multi-link repetitions."""

    count: int
    vertebra: np.ndarray          # (n_vertebrae,) frame of each vertebra
    mass: np.ndarray              # (count,) lumped mass
    moment: np.ndarray            # (count, 3) first moment of the lumped mass, frame axes
    base_quaternion: np.ndarray
    base_position: np.ndarray
    length_scale: float           # Σ |d0| over the links: the trunk's length

    def validate(self):
        if self.mass.shape != (self.count,) or self.moment.shape != (self.count, 3):
            raise ValueError(f"frames: {self.count} frames but masses {self.mass.shape}, moments {self.moment.shape}")


@dataclass(frozen=True)
class LinkSet(_Frozen):
    """Every link (link k joins frames k and k + 1) and the energy batches that evaluate them."""

    rest: np.ndarray              # (n, 6) rest strains ξ₀
    rest_quaternion: np.ndarray   # (n, 4) rest rotation of b in a
    rest_translation: np.ndarray  # (n, 3) rest translation d0 of b in a
    energies: tuple               # LinkEnergy batches covering the links once
    segment: np.ndarray           # (n,) the scene segment of each link

    def validate(self):
        covered = np.sort(np.concatenate([e.links for e in self.energies])) if self.energies else np.zeros(0, int)
        if not np.array_equal(covered, np.arange(self.rest.shape[0])):
            raise ValueError("link energies must cover every link exactly once")

    @property
    def count(self) -> int:
        return self.rest.shape[0]

    @functools.cached_property
    def fitted(self) -> bool:
        """Is any link energy fitted on a range (can a state leave it)?"""
        return any(energy.fitted for energy in self.energies)


@dataclass(frozen=True)
class Actuators(_Frozen):
    """Cables (first, in scene order) then chambers: names, forward values and bounds."""

    names: tuple
    n_cables: int
    n_chambers: int
    default: np.ndarray           # the scene's tensions and pressures
    bounds: tuple                 # (lower, upper) on λ
    displacement_bounds: tuple    # (lower, upper) on strokes and volume growths
    chamber_rest_volumes: np.ndarray
    max_change: np.ndarray        # largest change of each actuator per control tick (inf: none)
    stroke_driven: np.ndarray     # (n_cables,) bool: the cable's value is a servo stroke (m), not a tension
    cable_stiffness: np.ndarray   # (n_cables,) N/m spring rate of the stroke-driven tendons (0: tension-driven)
    pretension: np.ndarray        # (n_cables,) N of the stroke-driven tendons at zero stroke, at rest
    friction: np.ndarray          # (n_cables,) μ of the capstan law at the cable's holes (0: frictionless)

    @functools.cached_property
    def tendons(self) -> np.ndarray:
        """Indices of the stroke-driven cables (read-only)."""
        return _read_only(np.flatnonzero(self.stroke_driven))

    @functools.cached_property
    def state_bounded(self) -> bool:
        """Has any stroke or volume growth a bound (checked at a solved state: solver.bounds)?"""
        lower, upper = self.displacement_bounds
        return bool(np.maximum.reduce(lower, initial=-math.inf) > -math.inf
                    or np.minimum.reduce(upper, initial=math.inf) < math.inf)

    @functools.cached_property
    def frictional(self) -> bool:
        """Does any cable have friction at its holes?"""
        return bool(np.any(self.friction))

    def validate(self):
        if self.default.shape != (self.n_cables + self.n_chambers,):
            raise ValueError(f"actuators: {len(self.names)} names but {self.default.shape} values")
        for array in (*self.bounds, *self.displacement_bounds, self.max_change):
            _read_only(array)


@dataclass(frozen=True)
class Loads(_Frozen):
    """Dead loads, follower loads and gravity."""

    dead: np.ndarray              # (n_frames, 6) world forces and moments
    gravity: np.ndarray | None    # (3,) or None
    has_dead_forces: bool
    has_dead_moments: bool        # not conservative in 3D: the tangent is unsymmetric
    has_gravity: bool
    follower: np.ndarray          # (n_frames, 6) forces and moments in each frame's own axes
    has_follower: bool            # not conservative: the tangent is unsymmetric

    @classmethod
    def of(cls, dead: np.ndarray, gravity: np.ndarray | None, follower: np.ndarray, masses: bool) -> "Loads":
        """From the wrenches and gravity (None: none); ``masses``: some frame has a mass."""
        return cls(dead, gravity, bool(np.any(dead[:, :3])), bool(np.any(dead[:, 3:])),
                   gravity is not None and masses, follower, bool(np.any(follower)))

    @property
    def unsymmetric(self) -> bool:
        """Do loads that have no potential act (dead moments, follower loads): the tangent is then
        unsymmetric (banded LU, an energy-like merit)."""
        return self.has_dead_moments or self.has_follower

    @property
    def turning(self) -> bool:
        """Does the tangent have blocks of frame-fixed loads turning with their frame (the
        weight's lever arms, follower loads)?"""
        return self.has_gravity or self.has_follower


@dataclass(frozen=True)
class Effectors(_Frozen):
    """Points on vertebrae (offset in the frame) and axes (a unit direction fixed in the frame)."""

    names: tuple
    frames: np.ndarray            # (n,) frame of each effector
    is_axis: np.ndarray           # (n,) bool
    offsets: np.ndarray           # (n, 3) offset or axis in the frame
    targets: np.ndarray           # (n, 3) world (nan where none)
    weights: np.ndarray           # (n,)
    point_mask: np.ndarray        # (n, 1) 1 for points (which move with their frame's translation)
    translation_jacobian: np.ndarray   # (n, 3, n_frames, 6): the Jacobian's constant translation part

    @functools.cached_property
    def at_origins(self) -> np.ndarray | None:
        """When every effector is a point at its frame's origin (no offset: ``R r = 0``), the
        read-only zeros (n, 3) of their turned offsets; else None."""
        if self.offsets.any():        # (an axis effector's offset is its unit axis)
            return None
        return _read_only(np.zeros(self.offsets.shape))

    @functools.cached_property
    def free_jacobian(self) -> tuple:
        """What the linearisation's effector Jacobian (3n, n_dof: the free frames' columns) is made
        of: its constant translation part (read-only), the flat indices (k, 9) in it of the turning
        blocks ``−[R r]ˣ`` of the k effectors whose frame turns (not the clamped base) and those
        effectors (None: all of them)."""
        n, _, n_frames, _ = self.translation_jacobian.shape
        n_dof = 6 * (n_frames - 1)
        free = _read_only(self.translation_jacobian[:, :, 1:].reshape(3 * n, n_dof).copy())
        turning = np.flatnonzero(self.frames > 0)
        rows = 3 * turning[:, None, None] + np.arange(3)[:, None]
        columns = 6 * (self.frames[turning] - 1)[:, None, None] + 3 + np.arange(3)
        where = _read_only((rows * n_dof + columns).reshape(-1, 9))
        return free, where, (None if turning.size == n else _read_only(turning))


@dataclass(frozen=True)
class Trunk:
    """A compiled scene (build with :func:`compile_trunk`)."""

    scene: object
    frames: Frames
    links: LinkSet
    cables: CableRouting
    actuators: Actuators
    loads: Loads
    effectors: Effectors
    assembler: BandAssembler
    rest_state: State
    rest_cable_lengths: np.ndarray
    rest_piece_lengths: np.ndarray     # (m,) length of every cable piece at rest
    rest: RestConstants | None = None  # what the unstressed rest state gives (set by compile_trunk)
    compiled: "Trunk | None" = None    # the trunk compiled from the scene (None: this is it); see parameters.py
    contact: ContactModel | None = None   # discs, capsule segments, obstacles (None: no contact code runs)

    def __post_init__(self):
        if self.links.count != self.frames.count - 1:
            raise ValueError(f"{self.frames.count} frames need {self.frames.count - 1} links, got {self.links.count}")
        if self.assembler.n_blocks != self.links.count:
            raise ValueError("band layout does not match the frames")
        _read_only(self.rest_cable_lengths)
        _read_only(self.rest_piece_lengths)

    @property
    def n_dof(self) -> int:
        return 6 * (self.frames.count - 1)

    @functools.cached_property
    def rest_routing(self) -> tuple:
        """The cable pieces at the rest state and the rotations of their ends (2m, 3, 3), made
        when first asked for (a re-parameterised trunk makes its own: its holes may differ)."""
        rotations = qmatrix(self.rest_state.quaternions)
        return self.cables.pieces(self.rest_state.positions, rotations), rotations.take(self.cables.ends, 0)


def compile_trunk(scene, entries: dict) -> Trunk:
    """Compile a scene whose catalogue entries (by name) are in ``entries``."""
    frames, links, rest_volumes = _compile_links(scene, entries)
    cables = CableRouting.of(scene.cables, frames.vertebra, frames.count)
    rest_state = compose(frames.base_quaternion, frames.base_position, links.rest)
    rest_pieces = cables.pieces(rest_state.positions, qmatrix(rest_state.quaternions))
    loads = _loads(scene, frames)
    contact = compile_contact(scene, frames, links.segment)
    if contact is not None:
        check_rest(contact, rest_state, scene.source)
    assembler = BandAssembler(frames.count - 1, cables.span, cables.piece_a, cables.piece_b, loads.turning,
                              coupled_frames(contact))
    rest_lengths = cables.lengths(rest_pieces)
    trunk = Trunk(scene, frames, links, cables, _actuators(scene, rest_volumes, rest_lengths), loads,
                  _effectors(scene, frames), assembler, rest_state, rest_lengths, rest_pieces.length,
                  contact=contact)
    object.__setattr__(trunk, "rest", rest_constants(trunk))      # (needs the trunk it belongs to)
    return trunk


def reassemble(trunk: Trunk, changes: dict) -> Trunk:
    """``trunk`` with some parts replaced (:func:`~vertebra.solver.parameters.reparameterise`):
    what depends on them is made again — the cables' rest lengths (new holes), the band layout
    (gravity appearing or gone), the rest constants (scaled link energies)."""
    compiled = trunk.compiled or trunk
    cables = changes.get("cables", trunk.cables)
    if "cables" in changes:
        pieces = cables.pieces(trunk.rest_state.positions, qmatrix(trunk.rest_state.quaternions))
        changes["rest_cable_lengths"] = cables.lengths(pieces)
        changes["rest_piece_lengths"] = pieces.length
    loads = changes.get("loads", trunk.loads)
    if loads.turning != trunk.assembler.turning:
        changes["assembler"] = BandAssembler(trunk.frames.count - 1, cables.span, cables.piece_a, cables.piece_b,
                                             loads.turning, coupled_frames(trunk.contact))
    new = dataclasses.replace(trunk, compiled=compiled, **changes)
    if "links" in changes or "assembler" in changes:
        object.__setattr__(new, "rest", rest_constants(new))
    return new


def _compile_links(scene, entries):
    chambers = scene.chambers
    sources, kinds, source_of_link, vertebra_of_link = [], [], [], []
    vertebra = 1
    for index, segment in enumerate(scene.segments):
        entry = entries[segment.entry] if segment.type == "entry" else None
        kind = kind_for(segment, entry)
        sources.append(kind.source(segment, entry))
        kinds.append(kind)
        source_of_link.append(np.full(segment.count * segment.elements, index))
        vertebra_of_link.append(vertebra + np.repeat(np.arange(segment.count), segment.elements))
        vertebra += segment.count
    source_of_link = np.concatenate(source_of_link)
    vertebra_of_link = np.concatenate(vertebra_of_link)
    n = source_of_link.size
    # the stress-free strain of each source and A = ∂ξ/∂δ (δ = [Δx; Δθ] of b in a's axes)
    q0 = np.array([s.rest_quaternion for s in sources])
    d0 = np.array([s.rest_translation for s in sources])
    rest, strain_map = rest_strain(d0, q0)

    cavity = np.full((n, len(chambers)), -1)
    rest_volumes = np.zeros(len(chambers))
    n_cavities = np.array([s.cavity_volumes.size for s in sources])
    for j, chamber in enumerate(chambers):
        covered = np.flatnonzero((vertebra_of_link >= chamber.first) & (vertebra_of_link <= chamber.last))
        short = covered[n_cavities[source_of_link[covered]] <= chamber.cavity]
        if short.size:
            k = short[0]
            raise SceneError(f"segment {source_of_link[k]} ending at vertebra {vertebra_of_link[k]} has "
                             f"{n_cavities[source_of_link[k]]} cavities; chamber {chamber.name!r} uses cavity "
                             f"{chamber.cavity}", file=scene.source, field=f"chamber[{j}].cavity")
        cavity[covered, j] = chamber.cavity
        volume = np.array([v.cavity_volumes[chamber.cavity] if v.cavity_volumes.size > chamber.cavity else 0.0
                           for v in sources])
        rest_volumes[j] = np.cumsum(volume[source_of_link[covered]])[-1]
    compiled = CompiledLinks(sources, rest, strain_map, source_of_link, cavity, vertebra_of_link,
                             [f"segment[{i}]" for i in range(len(sources))], scene.source)
    energies = []
    for energy in dict.fromkeys(kind.energy for kind in kinds):
        made = [s for s, kind in enumerate(kinds) if kind.energy is energy]
        energies.append(energy.compile(np.flatnonzero(np.isin(source_of_link, made)), compiled))
    links = LinkSet(rest[source_of_link], q0[source_of_link], d0[source_of_link], tuple(energies), source_of_link)

    # masses: each link's on its end frames by the lever rule along its axis, then the vertebrae's
    mass = np.array([s.mass for s in sources])
    com = np.array([s.center_of_mass for s in sources])
    with np.errstate(all="ignore"):
        t = np.where(d0[:, 2] != 0, np.clip(com[:, 2] / d0[:, 2], 0.0, 1.0), 0.5)
    lateral = com * np.array([1.0, 1.0, 0.0])
    m_link, t_link, lateral_link = mass[source_of_link], t[source_of_link], lateral[source_of_link]
    vertebra_frames = np.r_[0, np.flatnonzero(np.diff(np.r_[vertebra_of_link, -1])) + 1]
    vertebrae = [segment.vertebra for segment in scene.segments for _ in range(segment.count)]
    frame_mass, frame_moment = np.zeros(n + 1), np.zeros((n + 1, 3))
    frame_mass[1:] += t_link * m_link
    frame_moment[1:] += (t_link * m_link)[:, None] * lateral_link
    frame_mass[vertebra_frames[1:]] += [v.mass for v in vertebrae]
    frame_moment[vertebra_frames[1:]] += np.array([v.mass * np.asarray(v.center_of_mass) for v in vertebrae]).reshape(-1, 3)
    frame_mass[:-1] += (1 - t_link) * m_link
    frame_moment[:-1] += ((1 - t_link) * m_link)[:, None] * lateral_link
    frames = Frames(n + 1, vertebra_frames, frame_mass, frame_moment, np.asarray(scene.base_quaternion, float),
                    np.asarray(scene.base_position, float), float(np.sum(np.linalg.norm(links.rest_translation, axis=1))))
    return frames, links, rest_volumes


CHANGE_FRACTION = 0.25    # default per-tick change of an actuator: this fraction of its range


def _actuators(scene, rest_volumes, rest_lengths: np.ndarray) -> Actuators:
    """Cables then chambers. A tension-driven cable's value is its tension (bounded by
    ``min/max_tension``, its stroke by ``min/max_stroke``); a stroke-driven tendon's value is its
    servo stroke (bounded by ``min/max_stroke``; its tension follows from the state)."""
    cables, chambers = scene.cables, scene.chambers
    by_stroke = [c.stroke_driven for c in cables]
    lower = np.array([c.min_stroke if s else c.min_tension for c, s in zip(cables, by_stroke)]
                     + [c.min_pressure for c in chambers], float)
    upper = np.array([c.max_stroke if s else c.max_tension for c, s in zip(cables, by_stroke)]
                     + [c.max_pressure for c in chambers], float)
    given = ([c.max_stroke_change if s else c.max_tension_change for c, s in zip(cables, by_stroke)]
             + [c.max_pressure_change for c in chambers])
    derived = CHANGE_FRACTION * (upper - lower)            # inf when a bound is
    max_change = np.array([d if g is None else g for g, d in zip(given, derived)], float)
    free = ~np.array(by_stroke, bool)
    stiffness = np.array([0.0 if not s else c.stiffness if c.stiffness is not None
                          else c.axial_stiffness / (length + c.free_length)
                          for c, s, length in zip(cables, by_stroke, rest_lengths)], float)
    return Actuators(
        tuple(c.name for c in cables) + tuple(c.name for c in chambers), len(cables), len(chambers),
        np.array([c.stroke if s else c.tension for c, s in zip(cables, by_stroke)] + [c.pressure for c in chambers],
                 float), (lower, upper),
        (np.array([c.min_stroke if f else -np.inf for c, f in zip(cables, free)]
                  + [c.min_volume_growth for c in chambers], float),
         np.array([c.max_stroke if f else np.inf for c, f in zip(cables, free)]
                  + [c.max_volume_growth for c in chambers], float)),
        rest_volumes, max_change, np.array(by_stroke, bool).reshape(-1), stiffness,
        np.array([c.pretension for c in cables], float).reshape(-1),
        np.array([c.friction for c in cables], float).reshape(-1))


def _loads(scene, frames: Frames) -> Loads:
    dead, follower = np.zeros((frames.count, 6)), np.zeros((frames.count, 6))
    for load in scene.loads:
        frame = frames.vertebra[load.vertebra]
        wrench = follower if load.follower else dead
        wrench[frame, :3] += load.force
        wrench[frame, 3:] += load.moment
    gravity = None if scene.gravity is None or not any(scene.gravity) else np.array(scene.gravity, float)
    return Loads.of(dead, gravity, follower, bool(np.any(frames.mass)))


def _effectors(scene, frames: Frames) -> Effectors:
    effectors = scene.effectors
    frame = np.array([frames.vertebra[e.vertebra] for e in effectors], int)
    is_axis = np.array([e.axis is not None for e in effectors], bool)
    template = np.zeros((len(effectors), 3, frames.count, 6))
    points = np.flatnonzero(~is_axis)
    template[points, :, frame[points], :3] = np.eye(3)     # a direction does not move with translations
    return Effectors(
        tuple(e.name for e in effectors), frame, is_axis,
        np.array([e.axis if e.axis is not None else e.offset for e in effectors], float).reshape(-1, 3),
        np.array([e.target if e.target is not None else (np.nan,) * 3 for e in effectors], float).reshape(-1, 3),
        np.array([e.weight for e in effectors], float), (~is_axis).astype(float)[:, None], template)
