"""The compiled trunk: frames joined by compliance links, with cables, chambers, loads,
gravity and effectors, and its quasi-static Newton solver (paper eq. 9).

``build_model(scene)`` compiles a :class:`~solver.scene.Scene` once into a
:class:`TrunkModel`; ``model.solve(actuation)`` then runs many times without
re-parsing or re-allocating the structure. Only what the scene uses is evaluated in
the hot path: no cables → no cable terms, no gravity → no gravity terms, and so on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.banded import BandLayout, factor_cholesky, factor_lu
from vertebra.solver.beam import timoshenko_compliance
from vertebra.solver.elements import CablePieces
from vertebra.solver.links import Chain, Links, chain_poses, link_forces, link_tangent
from vertebra.solver.rotations import hat, qmatrix, qrotate, se3_log
from vertebra.store.errors import CatalogueError, ConvergenceError, SceneError


@dataclass
class State:
    """Pose of every frame; frame 0 is the clamped base.

    States made by the solver also carry the link strains they were composed from
    (``strains``): evaluations then use the strains as they are instead of taking logarithms
    of rounded poses (docs/solver.md, "Convergence measure"). Their arrays are read-only;
    ``copy()`` gives writeable ones, and a copy whose poses no longer match the record is
    evaluated from its poses."""

    positions: np.ndarray     # (n_frames, 3) world
    quaternions: np.ndarray   # (n_frames, 4) [w, x, y, z]
    strains: "StrainRecord | None" = field(default=None, repr=False, compare=False)

    def copy(self) -> "State":
        return State(self.positions.copy(), self.quaternions.copy(), self.strains)

    def carried_strains(self) -> "StrainRecord | None":
        """The strain record when it still describes these poses, else None. The solver's own
        states hold the record's (read-only) arrays themselves; copies are compared by value."""
        record = self.strains
        if record is None:
            return None
        if record.positions is self.positions and record.quaternions is self.quaternions:
            return record
        if np.array_equal(record.positions, self.positions) and np.array_equal(record.quaternions, self.quaternions):
            return record
        return None


@dataclass
class StrainRecord:
    """Link strains ``ξ`` of a composed state, the chain products, and the poses they gave."""

    xi: np.ndarray
    chain: Chain
    positions: np.ndarray
    quaternions: np.ndarray


@dataclass
class StaticResult:
    """Outcome of a forward solve, with its diagnostics."""

    converged: bool
    iterations: int
    residual: float
    state: State
    actuation: np.ndarray
    residual_history: list = field(default_factory=list)
    load_steps: int = 1
    factorization: str = "cholesky"
    timings: dict = field(default_factory=dict)
    rounding_limited: bool = False   # stopped because the Newton correction fell below the
                                     # floating-point resolution of the poses (residual is rounding)


@dataclass
class Linearisation:
    """Tangent of the equilibrium at a state (paper eqs. 10–12); see docs/solver-api.md."""

    residual: np.ndarray
    factor: object
    actuator_forces: np.ndarray
    actuator_jacobian: np.ndarray
    effector_jacobian: np.ndarray
    effector_positions: np.ndarray
    actuator_displacements: np.ndarray

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``K⁻¹ rhs`` with the banded factor (one or many right-hand sides)."""
        return self.factor.solve(np.asarray(rhs, dtype=float))


@dataclass
class _Loads:
    xi_rest: np.ndarray
    piece_tension: np.ndarray | None = None
    weight: np.ndarray | None = None
    weight_hat: np.ndarray | None = None
    frame_weight: np.ndarray | None = None
    dead: np.ndarray | None = None
    dead_forces: np.ndarray | None = None


@dataclass
class _Evaluation:
    gradient: np.ndarray          # (n_frames, 6) of the potential, dead moments included (as −M)
    energy: float                 # potential (dead moments excluded: not conservative)
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    context: tuple = ()           # what the gradient computed that the tangent reuses
    link_tangents: np.ndarray | None = None   # (n_links·144 + 1,) the links' tangents and a zero
    extra: np.ndarray | None = None   # cable and gravity blocks (BandLayout.new_storage) or None


def _rest_twist(quaternion, translation):
    xi, Jl_inv = se3_log(np.asarray(quaternion, float), np.asarray(translation, float))
    return xi, Jl_inv


def _strain_map(quaternion, translation):
    """``A = ∂ξ/∂δ`` at rest: δ = [Δx; Δθ] of b in a's axes (DESIGN §2) → link strain."""
    xi0, Jl_inv = _rest_twist(quaternion, translation)
    shift = np.eye(6)
    shift[:3, 3:] = hat(np.asarray(translation, float))   # ζ = [Δx − Δθ × d0; Δθ]
    return xi0, Jl_inv @ shift


def _carried_links(record: StrainRecord, positions: np.ndarray) -> Links:
    """Link kinematics of a composed state from the strains it carries (no logarithms)."""
    return Links.of_strains(record.chain.rotations[:-1], record.xi, positions[1:] - positions[:-1],
                            record.chain.link_coefficients)


def _incidence(rows, n_rows):
    """(n_rows, len(rows)) matrix with a 1 at (rows[k], k): ``E @ v`` sums the rows of ``v`` into
    their targets. Dense while small (one BLAS call), sparse beyond."""
    if n_rows * rows.size <= 200_000:
        E = np.zeros((n_rows, rows.size))
        E[rows, np.arange(rows.size)] = 1.0
        return E
    from scipy.sparse import csr_matrix
    return csr_matrix((np.ones(rows.size), (rows, np.arange(rows.size))), shape=(n_rows, rows.size))


def build_model(scene, entries: dict | None = None) -> "TrunkModel":
    """Compile a scene. ``entries`` maps entry names to ``SegmentEntry`` objects; when
    omitted, the entries the scene names (and only those) are read from its catalogue."""
    needed = sorted({s.entry for s in scene.segments if s.type == "entry"})
    entries = dict(entries or {})
    missing = [name for name in needed if name not in entries]
    if missing:
        from vertebra.store import catalogue  # lazy: beam-only scenes never touch HDF5
        with catalogue.open_catalogue(scene.catalogue) as cat:
            for name in missing:
                try:
                    entries[name] = cat.load(name)
                except CatalogueError as error:
                    index = next(i for i, s in enumerate(scene.segments) if s.type == "entry" and s.entry == name)
                    raise CatalogueError(f"{scene.source}: segment[{index}].entry: {error}") from error
    return TrunkModel(scene, entries)


class TrunkModel:
    """A compiled trunk. Build with :func:`build_model`."""

    def __init__(self, scene, entries: dict):
        self.scene = scene
        self._compile_links(scene, entries)
        self._compile_actuators(scene)
        self._compile_loads(scene)
        self.layout = BandLayout(self.n_frames - 1, self.span)
        self.rest_state = self._rest_state(scene)
        self.rest_cable_lengths = self.cable_lengths(self.rest_state)
        self._reference_cache = (None, None)
        self._geometry_cache = (None, None)
        self._loads_cache = (None, None, None)
        self._rest_cache = [None, None]       # rest-state Links and unstressed link tangent

    # ------------------------------------------------------------------ compile
    def _compile_links(self, scene, entries):
        K, xi0, S, quats, trans, Vs = [], [], [], [], [], []
        frame_mass, frame_moment = [0.0], [np.zeros(3)]
        vertebra_frames = [0]
        chambers = scene.chambers
        rest_volumes = np.zeros(len(chambers))
        for seg_index, seg in enumerate(scene.segments):
            if seg.type == "beam":
                l = seg.length / seg.elements
                try:
                    C = timoshenko_compliance(l, seg.youngs_modulus, seg.shear_modulus, seg.section)
                except (OverflowError, ZeroDivisionError):
                    C = np.full((6, 6), np.inf)          # reported below with the segment's name
                q0, d0 = np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, l])
                G, V, volumes = np.zeros((6, 0)), np.zeros((0, 0)), np.zeros(0)
                link_mass, com = seg.density * seg.section.area * l, np.array([0.0, 0.0, 0.5 * l])
            else:
                entry = entries[seg.entry]
                C, G, V, volumes = entry.C, entry.G, entry.V, entry.cavity_volumes
                q0, d0 = entry.rest_quaternion, entry.rest_translation
                link_mass, com = entry.mass, entry.center_of_mass
            xi_rest, A = _strain_map(q0, d0)
            with np.errstate(all="ignore"):
                K_xi = np.linalg.inv(A @ C @ A.T)
            K_xi = 0.5 * (K_xi + K_xi.T)
            if not (np.all(np.isfinite(K_xi)) and np.all(np.isfinite(C)) and np.all(np.diag(K_xi) > 0)):
                raise SceneError("length, section and moduli give a compliance that is not finite and positive "
                                 "in double precision", file=scene.source, field=f"segment[{seg_index}]")
            for _ in range(seg.count):
                vertebra_index = len(vertebra_frames)
                for _ in range(seg.elements):
                    K.append(K_xi), xi0.append(xi_rest), quats.append(q0), trans.append(d0)
                    # which chambers act through this link's cavities (DESIGN §3: one per segment)
                    P = np.zeros((6, len(chambers)))
                    cover = np.zeros(len(chambers), bool)
                    for j, ch in enumerate(chambers):
                        if ch.first <= vertebra_index <= ch.last:
                            if ch.cavity >= G.shape[1]:
                                raise SceneError(
                                    f"segment {seg_index} ending at vertebra {vertebra_index} has "
                                    f"{G.shape[1]} cavities; chamber {ch.name!r} uses cavity {ch.cavity}",
                                    file=scene.source, field=f"chamber[{j}].cavity")
                            P[:, j] = A @ G[:, ch.cavity]
                            cover[j] = True
                            rest_volumes[j] += volumes[ch.cavity]
                    S.append(P)
                    Vc = np.zeros((len(chambers), len(chambers)))
                    idx = [j for j in range(len(chambers)) if cover[j]]
                    for j in idx:
                        for k in idx:
                            Vc[j, k] = V[chambers[j].cavity, chambers[k].cavity]
                    Vs.append(Vc)
                    # segment mass lumped on the link's end frames by the lever rule along its axis
                    t = float(np.clip(com[2] / d0[2], 0.0, 1.0)) if d0[2] != 0 else 0.5
                    lateral = np.array([com[0], com[1], 0.0])
                    frame_mass[-1] += (1 - t) * link_mass
                    frame_moment[-1] = frame_moment[-1] + (1 - t) * link_mass * lateral
                    frame_mass.append(t * link_mass)
                    frame_moment.append(t * link_mass * lateral)
                vertebra_frames.append(len(frame_mass) - 1)
                frame_mass[-1] += seg.vertebra.mass
                frame_moment[-1] = frame_moment[-1] + seg.vertebra.mass * np.asarray(seg.vertebra.center_of_mass)
        self.n_frames = len(frame_mass)
        self.n_links = self.n_frames - 1
        self.link_stiffness = np.array(K)
        self.link_rest = np.array(xi0)
        self.link_rest_quaternion = np.array(quats)
        self.link_rest_translation = np.array(trans)
        self.link_pressure_map = np.array(S).reshape(self.n_links, 6, len(chambers))
        # K A G per link and chamber (n, chamber, 6): the strain-space force of a unit pressure
        self._pressure_stiffness = np.einsum("nij,njk->nki", self.link_stiffness, self.link_pressure_map)
        self.chamber_volume_compliance = np.sum(Vs, axis=0) if Vs else np.zeros((0, 0))
        self.frame_mass = np.array(frame_mass)
        self.frame_moment = np.array(frame_moment)
        self.vertebra_frames = np.array(vertebra_frames)
        self.length_scale = float(np.sum(np.linalg.norm(self.link_rest_translation, axis=1)))
        self._residual_weights = np.array([1.0] * 3 + [1.0 / self.length_scale] * 3)
        self._resolution_weights = np.ones(6)
        self.chamber_rest_volumes = rest_volumes
        for j, ch in enumerate(chambers):
            if not np.any(self.link_pressure_map[:, :, j]):
                raise SceneError(f"chamber {ch.name!r} covers no segment with cavities (vertebrae {ch.first}..{ch.last})",
                                 file=scene.source, field=f"chamber[{j}]")

    def _compile_actuators(self, scene):
        pa, pb, ha, hb, owner = [], [], [], [], []
        for c, cable in enumerate(scene.cables):
            hole = cable.radius * np.array([math.cos(cable.angle), math.sin(cable.angle), 0.0])
            route = [self.vertebra_frames[v] for v in range(cable.first - 1, cable.last + 1)]
            for f_a, f_b in zip(route[:-1], route[1:]):
                pa.append(f_a), pb.append(f_b), ha.append(hole), hb.append(hole), owner.append(c)
        # pieces grouped by the pair of frames they join (the tangent is summed per pair)
        order = np.lexsort((np.array(pb, int), np.array(pa, int)))
        self.cable_piece_a = np.array(pa, int)[order]
        self.cable_piece_b = np.array(pb, int)[order]
        self.cable_hole_a = np.array(ha).reshape(-1, 3)[order]
        self.cable_hole_b = np.array(hb).reshape(-1, 3)[order]
        self.cable_piece_owner = np.array(owner, int)[order]
        # links couple neighbouring frames (block offset 1); a cable piece couples the frames of two
        # consecutive vertebrae, `elements` links apart: the band is as wide as the widest coupling
        self.span = int(max(1, np.max(self.cable_piece_b - self.cable_piece_a, initial=1)))
        a, b = self.cable_piece_a, self.cable_piece_b
        self._cable_ends = np.stack([a, b], 1).reshape(-1)                    # a₀ b₀ a₁ b₁ …
        self._cable_holes = np.stack([self.cable_hole_a, self.cable_hole_b], 1).reshape(-1, 3, 1)
        self._cable_to_frames = _incidence(np.stack([a, b], 1).reshape(-1), self.n_frames)
        owner2 = np.repeat(self.cable_piece_owner, 2)
        self._cable_to_jacobian = _incidence(owner2 * self.n_frames + np.stack([a, b], 1).reshape(-1),
                                             len(scene.cables) * self.n_frames)
        first = np.flatnonzero(np.r_[a.size > 0, (a[1:] != a[:-1]) | (b[1:] != b[:-1])])
        self._pair_starts, self._pair_a, self._pair_b = first, a[first], b[first]
        self._pair_free = self._pair_a > 0
        self._pair_offset = (self._pair_b - self._pair_a)[self._pair_free]
        pairs_are_chains = (np.unique(self._pair_a).size == first.size and np.unique(self._pair_b).size == first.size)
        self._cable_scatter = None if pairs_are_chains else self._cable_band_map(a, b)
        self.n_cables = len(scene.cables)
        self.n_chambers = len(scene.chambers)
        self.actuator_names = [c.name for c in scene.cables] + [c.name for c in scene.chambers]
        self.default_actuation = np.array([c.tension for c in scene.cables] + [c.pressure for c in scene.chambers])
        self.actuator_bounds = (
            np.array([c.min_tension for c in scene.cables] + [c.min_pressure for c in scene.chambers]),
            np.array([c.max_tension for c in scene.cables] + [c.max_pressure for c in scene.chambers]))
        self.displacement_bounds = (
            np.array([c.min_stroke for c in scene.cables] + [c.min_volume_growth for c in scene.chambers]),
            np.array([c.max_stroke for c in scene.cables] + [c.max_volume_growth for c in scene.chambers]))

    def _cable_band_map(self, a, b):
        """Where the 144 tangent entries of each cable piece go in the stacked [lower, upper]
        block bands, sorted by destination so that one ``add.reduceat`` sums the pieces that share
        a block: (source indices, segment starts, unique destinations)."""
        n_offsets = self.span + 1
        n_band = (self.n_frames - 1) * n_offsets
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

    def _compile_loads(self, scene):
        dead = np.zeros((self.n_frames, 6))
        for load in scene.loads:
            frame = self.vertebra_frames[load.vertebra]
            dead[frame, :3] += load.force
            dead[frame, 3:] += load.moment
        self.dead_loads = dead
        self.has_dead_forces = bool(np.any(dead[:, :3]))
        self.has_dead_moments = bool(np.any(dead[:, 3:]))
        self.gravity = None if scene.gravity is None or not any(scene.gravity) else np.array(scene.gravity)
        self.has_gravity = self.gravity is not None and bool(np.any(self.frame_mass))
        self.effector_names = [e.name for e in scene.effectors]
        self.effector_frames = np.array([self.vertebra_frames[e.vertebra] for e in scene.effectors], int)
        # point effectors: offset in the frame; axis effectors: the unit axis (no translation part)
        self.effector_is_axis = np.array([e.axis is not None for e in scene.effectors], bool)
        self.effector_offsets = np.array([e.axis if e.axis is not None else e.offset for e in scene.effectors],
                                         float).reshape(-1, 3)
        self.effector_targets = np.array([e.target if e.target is not None else (np.nan,) * 3
                                          for e in scene.effectors], float).reshape(-1, 3)
        self.effector_weights = np.array([e.weight for e in scene.effectors], float)
        self._all_effectors = np.arange(len(scene.effectors))
        self._point_mask = (~self.effector_is_axis).astype(float)[:, None]
        # the effector Jacobian's translation part (a direction does not move with translations)
        self._effector_template = np.zeros((len(scene.effectors), 3, self.n_frames, 6))
        points = np.flatnonzero(~self.effector_is_axis)
        self._effector_template[points, :, self.effector_frames[points], :3] = np.eye(3)

    def _rest_state(self, scene) -> State:
        """The stress-free pose: the chain composed from the rest strains, which it carries."""
        base_q = np.asarray(scene.base_quaternion, float)
        base_x = np.asarray(scene.base_position, float)
        return self._composed(base_q, base_x, self.link_rest)

    def _composed(self, base_q, base_x, xi) -> State:
        """The state composed from the base pose and link strains ``ξ`` (carrying them when
        every link turns less than π)."""
        chain = chain_poses(base_q, base_x, xi)
        chain.quaternions[0], chain.positions[0] = base_q, base_x
        record = None
        if chain.link_coefficients is not None:
            # every link turns less than π: the logarithm of the composed poses returns ξ again
            # (to rounding), so the state carries ξ and evaluations take it as it is; the poses
            # are frozen so that they cannot drift from the record (State.copy() thaws them)
            chain.positions.flags.writeable = False
            chain.quaternions.flags.writeable = False
            record = StrainRecord(xi, chain, chain.positions, chain.quaternions)
        return State(chain.positions, chain.quaternions, record)

    # ------------------------------------------------------------------ physics
    @property
    def n_dof(self) -> int:
        return 6 * (self.n_frames - 1)

    def _actuation(self, actuation) -> np.ndarray:
        if actuation is None:
            return self.default_actuation.copy()
        actuation = np.asarray(actuation, dtype=float).reshape(-1)
        if actuation.shape != self.default_actuation.shape:
            raise ValueError(f"actuation has {actuation.size} values, the model has "
                             f"{self.default_actuation.size} actuators ({', '.join(self.actuator_names)})")
        return actuation

    def _link_rest(self, pressures):
        if self.n_chambers == 0 or not np.any(pressures):
            return self.link_rest
        return self.link_rest + self.link_pressure_map @ pressures   # pressure shifts the rest pose: G p

    def _rest_links(self) -> Links:
        """Link kinematics of the rest state (computed once)."""
        if self._rest_cache[0] is None:
            self._rest_cache[0] = _carried_links(self.rest_state.strains, self.rest_state.positions)
        return self._rest_cache[0]

    def _loads(self, actuation: np.ndarray, scale: float) -> "_Loads":
        """What the actuation and the load factor make of the loads, computed once per Newton
        stage (the last one is kept: same actuation values and factor → same loads)."""
        key = actuation.tobytes()
        cached = self._loads_cache
        if cached[0] == key and cached[1] == scale:
            return cached[2]
        tensions = scale * actuation[:self.n_cables]
        loads = _Loads(
            xi_rest=self._link_rest(scale * actuation[self.n_cables:]),
            piece_tension=tensions[self.cable_piece_owner] if self.n_cables and np.any(tensions) else None)
        if self.has_gravity:
            loads.weight = scale * self.gravity
            loads.weight_hat = hat(loads.weight)
            loads.frame_weight = self.frame_mass[:, None] * loads.weight
        if self.has_dead_forces or self.has_dead_moments:
            loads.dead = scale * self.dead_loads
            loads.dead_forces = np.ascontiguousarray(loads.dead[:, :3])
        self._loads_cache = (key, scale, loads)
        return loads

    def _evaluate(self, state: State, actuation: np.ndarray, scale: float, tangent: bool) -> _Evaluation:
        """Gradient and energy at ``state``; the tangent too when asked, or later (only if Newton
        needs it) by :meth:`_add_tangent`, which reuses what the gradient computed."""
        x, q = state.positions, state.quaternions
        grad = np.zeros((self.n_frames, 6))
        loads = self._loads(actuation, scale)
        record = state.carried_strains()
        if record is not None and record is self.rest_state.strains:
            links, rotations = self._rest_links(), record.chain.rotations   # a model constant
        elif record is not None:                         # a state made by step(): its strains are known
            links, rotations = _carried_links(record, x), record.chain.rotations
        else:
            links = Links.of(q[:-1], x[:-1], q[1:], x[1:])
            rotations = qmatrix(q) if self.n_cables or self.has_gravity else None
        self._geometry_cache = (state, links)            # reused by step() from this state
        g_links, total, w, _ = link_forces(links, self.link_stiffness, loads.xi_rest)
        grad[:-1] = g_links[:, :6]
        grad[1:] += g_links[:, 6:]

        pieces = piece_tension = None
        if loads.piece_tension is not None:
            pieces = self._cable_pieces(x, rotations)
            piece_tension = loads.piece_tension
            grad += self._cable_to_frames @ (piece_tension[:, None] * pieces.unit).reshape(-1, 6)
            total += float(piece_tension @ pieces.length)

        weight = lever = None
        if loads.weight is not None:
            weight = loads.weight
            lever = (rotations @ self.frame_moment[:, :, None])[:, :, 0]   # R s: first moment in world axes
            grad[:, :3] -= loads.frame_weight
            grad[:, 3:] -= lever @ loads.weight_hat               # moment (R s) × m g at the frame
            total -= float((self.frame_mass @ x + lever.sum(0)) @ weight)

        if loads.dead is not None:
            grad -= loads.dead
            total -= float(np.vdot(loads.dead_forces, x))
        ev = _Evaluation(grad, total, context=(links, w, g_links, pieces, piece_tension,
                                               None if weight is None else loads.weight_hat, lever))
        if tangent:
            self._add_tangent(ev)
        return ev

    def _add_tangent(self, ev: _Evaluation) -> None:
        """Compute the tangent of an evaluation (once): the links' tangents side by side (their
        symmetric band is gathered straight from them) and, when cables or gravity act, their
        blocks in block-band storage."""
        if ev.link_tangents is not None:
            return
        links, w, g_links, pieces, piece_tension, weight_hat, lever = ev.context
        flat = np.empty(self.n_links * 144 + 1)
        flat[-1] = 0.0                                               # the gathers' zero
        self._link_tangent(links, w, g_links, flat[:-1].reshape(self.n_links, 12, 12))
        ev.link_tangents = flat
        if pieces is None and weight_hat is None:
            return
        storage, band_blocks = self.layout.new_storage()            # [lower, upper] block bands
        lower, upper = band_blocks[0], band_blocks[1]
        if pieces is not None:
            H = pieces.tangent(piece_tension)
            if self._cable_scatter is None:
                # pieces between the same two frames summed first; every pair has its own frames
                # a and b (consecutive vertebrae), so each block below is written once per pair
                H = np.add.reduceat(H, self._pair_starts, axis=0)
                free, fa = self._pair_free, self._pair_a[self._pair_free] - 1
                lower[self._pair_b - 1, 0] += H[:, 6:, 6:]
                lower[fa, 0] += H[free, :6, :6]
                lower[fa, self._pair_offset] += H[free, 6:, :6]
                upper[fa, self._pair_offset] += H[free, :6, 6:]
            else:   # a general routing: one gather-sum-scatter (shared blocks add up)
                source, starts, target = self._cable_scatter
                band_blocks.reshape(-1)[target] += np.add.reduceat(H.reshape(-1).take(source), starts)
        if weight_hat is not None:
            lower[:, 0, 3:, 3:] -= weight_hat @ hat(lever[1:])       # −ĝ l̂: the moment arm turns
        ev.extra = storage

    def _blocks(self, ev: _Evaluation):
        """The whole tangent as [lower, upper] block bands (for LU and shifted factors)."""
        self._add_tangent(ev)
        if ev.lower is None:
            storage, band_blocks = self.layout.new_storage()
            if ev.extra is not None:
                storage[:] = ev.extra
            lower, upper = band_blocks[0], band_blocks[1]
            H = ev.link_tangents[:-1].reshape(self.n_links, 12, 12)
            lower[:, 0] += H[:, 6:, 6:]
            lower[:-1, 0] += H[1:, :6, :6]
            lower[:-1, 1] += H[1:, 6:, :6]
            upper[:-1, 1] += H[1:, :6, 6:]
            ev.lower, ev.upper = lower, upper
        return ev.lower, ev.upper

    def _symmetric_band(self, ev: _Evaluation) -> np.ndarray:
        """LAPACK lower band of the tangent's symmetric part."""
        self._add_tangent(ev)
        links = self.layout.symmetric_from_links(ev.link_tangents)
        if links.shape[0] == self.layout.kd + 1 and ev.extra is None:
            return links
        band = (self.layout.symmetric_from_storage(ev.extra) if ev.extra is not None
                else np.zeros((self.layout.kd + 1, self.layout.n)))
        band[:links.shape[0]] += links
        return band

    def _link_tangent(self, links: Links, w: np.ndarray, g_links: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Tangent of the links into ``out``; at the unstressed rest state (w = 0) a model constant."""
        if links is self._rest_cache[0] and not w.any():
            if self._rest_cache[1] is None:
                self._rest_cache[1] = link_tangent(links, self.link_stiffness, w, g_links)
            out[:] = self._rest_cache[1]
            return out
        return link_tangent(links, self.link_stiffness, w, g_links, out=out)

    def _factor(self, ev: _Evaluation, shift: float = 0.0):
        """Factor the tangent: banded Cholesky of its symmetric part when it is exact to use
        it (no dead moments), banded LU otherwise; ``shift`` adds μ·diag."""
        if not shift and not self.has_dead_moments:
            factor = factor_cholesky(self._symmetric_band(ev))
            if factor is not None:
                return factor, "cholesky"
        lower, upper = self._blocks(ev)
        if shift:
            lower = lower.copy()
            diag = np.einsum("cii->ci", lower[:, 0])
            scale = np.abs(diag) + 1e-300
            lower[:, 0] += shift * np.einsum("ci,ij->cij", scale, np.eye(6))
            if not self.has_dead_moments:
                factor = factor_cholesky(self.layout.symmetric_band(lower, upper))
                if factor is not None:
                    return factor, "shifted"
        factor = factor_lu(self.layout.general_band(lower, upper), self.layout.kd)
        return factor, ("shifted-lu" if shift else "lu") if factor is not None else None

    def step(self, state: State, dq: np.ndarray) -> State:
        """Retraction in strain space: each link's twist ``ξ = log(T_a⁻¹ T_b)`` moves by its
        linearised change ``J_l⁻¹ ζ(dq)`` and the chain is rebuilt from the base by composing
        ``exp(ξ)`` (a parallel prefix product, O(log n) numpy calls). To first order this is the
        update ``x + dx``, ``exp(dφ) R`` (so Newton keeps its quadratic convergence), but a step
        that predicts no stretch of a link creates none: stiff axial and shear links no longer
        absorb spurious strain when frames rotate (FIELD-NOTES' trap, taken to its end)."""
        d = np.zeros((self.n_frames, 6))
        d[1:] = np.asarray(dq).reshape(-1, 6)
        q, x = state.quaternions, state.positions
        cached_state, links = self._geometry_cache
        if cached_state is not state:
            links = Links.of(q[:-1], x[:-1], q[1:], x[1:])
        return self._composed(q[0], x[0], links.xi + links.strain_change(links.zeta(d)))

    def _reference_force(self, actuation) -> float:
        """Force scale of the problem: the out-of-balance load at the rest pose (full load).
        Residuals are measured relative to it, so tolerances are unit-scale invariant."""
        key = actuation.tobytes()
        if self._reference_cache[0] == key:
            return self._reference_cache[1]
        r0 = self._evaluate(self.rest_state, actuation, 1.0, tangent=False).gradient[1:]
        value = max(np.max(np.abs(r0[:, :3]), initial=0.0), np.max(np.abs(r0[:, 3:]), initial=0.0) / self.length_scale)
        self._reference_cache = (key, value)
        return value

    def _residual_norm(self, r: np.ndarray, reference: float) -> float:
        """max(|force|, |moment| / length scale) / reference over the frames."""
        return float(np.abs(r.reshape(-1, 6) * self._residual_weights).max() / reference)

    # ------------------------------------------------------------------ solve
    def solve(self, actuation=None, initial: State | None = None, *, tolerance=None,
              max_iterations=None, load_steps=None, raise_on_failure=True) -> StaticResult:
        """Quasi-static equilibrium (paper eq. 9) by Newton with line search and automatic load
        stepping. Raises :class:`ConvergenceError` (with the partial result) on failure."""
        start = time.perf_counter()
        settings = self.scene.solver
        tol = settings.tolerance if tolerance is None else tolerance
        max_iter = settings.max_iterations if max_iterations is None else max_iterations
        steps = settings.load_steps if load_steps is None else load_steps
        actuation = self._actuation(actuation)
        if initial is None and self._unloaded(actuation):
            # no cable tension, pressure, load or weight: the rest pose is the equilibrium exactly
            # (links are stress-free there by definition; se3 round-off would read ~1e-16 strain)
            return StaticResult(True, 0, 0.0, self.rest_state.copy(), actuation, [0.0], 1, "none",
                                {"solve_s": time.perf_counter() - start})
        reference = self._reference_force(actuation)
        history, kinds = [], set()
        if reference == 0.0:
            state = (initial or self.rest_state).copy()
            ev = self._evaluate(state, actuation, 1.0, tangent=False)
            if not np.any(ev.gradient[1:]):
                return StaticResult(True, 0, 0.0, state, actuation, [0.0], 1, "none",
                                    {"solve_s": time.perf_counter() - start})
            reference = max(np.max(np.abs(ev.gradient[1:, :3])), np.max(np.abs(ev.gradient[1:, 3:])) / self.length_scale)

        state = (initial or self.rest_state).copy()
        scale, increment = 0.0, 1.0 / steps
        if initial is not None:
            scale, increment = 0.0, 1.0   # warm start: try the full load from the given pose first
        iterations, stages = 0, 0
        last_good = state
        converged = False
        residual = math.inf
        while True:
            target = min(1.0, scale + increment)
            stage_tol = tol if target >= 1.0 else max(tol, 1e-6)
            ok, state_new, its, residual = self._newton(last_good, actuation, target, stage_tol,
                                                        max_iter, reference, history, kinds)
            iterations += its
            stages += 1
            if ok:
                last_good, scale = state_new, target
                if scale >= 1.0:
                    converged = True
                    break
                increment = min(2.0 * increment, 1.0 - scale)
            else:
                if initial is not None and scale == 0.0 and last_good is not self.rest_state and stages == 1:
                    last_good = self.rest_state.copy()   # warm start failed: step the load from rest
                    increment = 1.0 / steps
                    continue
                increment *= 0.5
                if increment < 1e-4 or iterations > 50 * max_iter:
                    break
        limited = "rounding-limited" in kinds
        saddles = "unstable" in kinds
        kinds -= {"rounding-limited", "unstable"}
        result = StaticResult(converged, iterations, float(residual), last_good if converged else state_new,
                              actuation, history, stages, "+".join(sorted(kinds)) or "none",
                              {"solve_s": time.perf_counter() - start}, rounding_limited=limited and converged)
        if not converged and raise_on_failure:
            raise ConvergenceError(
                f"Newton did not converge: scaled residual {residual:.3g} > {tol:g} after {iterations} "
                f"iterations and {stages} load stages (reached load factor {scale:.4g})"
                + ("; equilibria found on the way were unstable (indefinite tangent) and refused" if saddles else ""),
                result)
        return result

    def _unloaded(self, actuation: np.ndarray) -> bool:
        return not (actuation.any() or self.has_dead_forces or self.has_dead_moments or self.has_gravity)

    def _below_resolution(self, state: State, dq: np.ndarray) -> bool:
        """Is every translation below 1e-13 of the extent and every rotation below 1e-13 rad?"""
        weights = self._resolution_weights
        weights[:3] = 1.0 / (self.length_scale + float(np.abs(state.positions).max()))
        return float(np.abs(dq.reshape(-1, 6) * weights).max()) <= 1e-13

    def _newton(self, state, actuation, scale, tol, max_iter, reference, history, kinds):
        """Newton iterations at a fixed load factor. Returns (ok, state, iterations, residual).

        The tangent is assembled only where a Newton step is taken (not at the converged state).
        An equilibrium reached through indefinite tangents is accepted only when its own tangent
        is positive definite (conservative loads): a saddle is not a quasi-static answer, and the
        caller then steps the load from the last stable state instead."""
        ev = self._evaluate(state, actuation, scale, tangent=False)
        r = -ev.gradient[1:].reshape(-1)
        residual = self._residual_norm(r, reference * max(scale, 1e-300))
        moments = scale * self.dead_loads[1:, 3:].reshape(-1) if self.has_dead_moments else None
        best, best_at = residual, 0
        last_kind = "cholesky"
        for iteration in range(max_iter + 1):
            history.append(residual)
            if not math.isfinite(residual):
                return False, state, iteration, residual
            if residual <= tol:
                if last_kind != "cholesky" and not self._stable(ev):
                    kinds.add("unstable")
                    return False, state, iteration, residual
                return True, state, iteration, residual
            if residual < 0.5 * best:
                best, best_at = residual, iteration
            if iteration == max_iter or iteration - best_at > 20:
                break     # out of iterations, or no progress for 20 iterations: smaller load step
            accepted = False
            for shift in (0.0, 1e-8, 1e-6, 1e-4, 1e-2, 1.0):
                factor, kind = self._factor(ev, shift)
                if factor is None:
                    continue
                dq = factor.solve(r)
                if self._below_resolution(state, dq):
                    # the correction is below the floating-point resolution of the poses: the
                    # residual left is rounding, not error; stop here and report it as it is
                    if kind != "cholesky" and not self._stable(ev):
                        kinds.add("unstable")
                        return False, state, iteration, residual
                    kinds.add(kind)
                    kinds.add("rounding-limited")
                    return True, state, iteration, residual
                slope = -float(r @ dq)
                if slope >= 0.0 and shift == 0.0 and kind != "cholesky":
                    continue      # indefinite tangent: the pure Newton step is no descent direction
                alpha = 1.0
                while alpha > 1e-3:
                    trial = self.step(state, dq if alpha == 1.0 else alpha * dq)
                    ev_trial = self._evaluate(trial, actuation, scale, tangent=False)
                    r_trial = -ev_trial.gradient[1:].reshape(-1)
                    res_trial = self._residual_norm(r_trial, reference * max(scale, 1e-300))
                    work = 0.0 if moments is None else alpha * float(moments @ dq.reshape(-1, 6)[:, 3:].reshape(-1))
                    merit_ok = (ev_trial.energy - work <= ev.energy + 1e-4 * alpha * slope
                                + 1e-12 * abs(ev.energy))
                    if math.isfinite(res_trial) and merit_ok:
                        accepted = True
                        break
                    alpha *= 0.5
                if accepted:
                    kinds.add(kind)
                    last_kind = kind
                    break
            if not accepted:
                return False, state, iteration + 1, residual
            state, ev, r, residual = trial, ev_trial, r_trial, res_trial
        return False, state, iteration, residual

    def _stable(self, ev: _Evaluation) -> bool:
        """Is the equilibrium of ``ev`` stable: is its tangent positive definite? Only decidable
        for conservative loads (dead moments make the tangent unsymmetric): then assumed so."""
        if self.has_dead_moments:
            return True
        return self._factor(ev)[1] == "cholesky"

    # ------------------------------------------------------------------ outputs
    def _cable_pieces(self, x: np.ndarray, rotations: np.ndarray) -> CablePieces:
        ends = self._cable_ends
        return CablePieces.of_pairs(rotations.take(ends, 0), x.take(ends, 0), self._cable_holes)

    def cable_lengths(self, state: State, pieces: CablePieces | None = None) -> np.ndarray:
        if not self.n_cables:
            return np.zeros(0)
        if pieces is None:
            pieces = self._cable_pieces(state.positions, qmatrix(state.quaternions))
        return np.bincount(self.cable_piece_owner, pieces.length, minlength=self.n_cables)

    def chamber_volume_growth(self, state: State, pressures: np.ndarray, links: Links | None = None) -> np.ndarray:
        """ΔV_j = Σ_links (A G_j)ᵀ K e + V p (DESIGN §2: reciprocity gives the Gᵀ row)."""
        if not self.n_chambers:
            return np.zeros(0)
        if links is None:
            x, q = state.positions, state.quaternions
            links = Links.of(q[:-1], x[:-1], q[1:], x[1:])
        e = links.xi - self._link_rest(pressures)
        w = np.einsum("nij,nj->ni", self.link_stiffness, e)
        return np.einsum("nij,ni->j", self.link_pressure_map, w) + self.chamber_volume_compliance @ pressures

    def actuator_displacements(self, state: State, actuation=None, *, links: Links | None = None,
                               pieces: CablePieces | None = None) -> np.ndarray:
        actuation = self._actuation(actuation)
        strokes = self.cable_lengths(state, pieces) - self.rest_cable_lengths
        if not self.n_chambers:
            return strokes
        return np.concatenate([strokes, self.chamber_volume_growth(state, actuation[self.n_cables:], links)])

    def effector_positions(self, state: State) -> np.ndarray:
        """World position of each point effector; world unit direction of each axis effector."""
        return self._effector_points(state)[1]

    def _effector_points(self, state: State):
        """World offsets (``R r``: lever arms, or the axes) and positions of the effectors."""
        f = self.effector_frames
        record = state.carried_strains()
        if record is not None:                # the chain's rotation matrices, no quaternion algebra
            turned = (record.chain.rotations[f] @ self.effector_offsets[:, :, None])[:, :, 0]
        else:
            turned = qrotate(state.quaternions[f], self.effector_offsets)
        return turned, state.positions[f] * self._point_mask + turned

    def linearise(self, state: State, actuation=None) -> Linearisation:
        """Tangent stiffness factor, actuator and effector Jacobians at ``state``."""
        actuation = self._actuation(actuation)
        ev = self._evaluate(state, actuation, 1.0, tangent=True)
        factor = None
        for shift in (0.0, 1e-8, 1e-6, 1e-4):
            factor, _ = self._factor(ev, shift)
            if factor is not None:
                break
        if factor is None:
            raise ConvergenceError("tangent stiffness is singular at this state")
        x, q = state.positions, state.quaternions
        links, pieces = ev.context[0], ev.context[3]      # what the evaluation computed, reused
        n_act = self.n_cables + self.n_chambers
        jac = np.zeros((n_act, self.n_frames, 6))
        if self.n_cables:
            if pieces is None:                            # slack cables: not evaluated for the forces
                pieces = self._cable_pieces(x, qmatrix(q))
            jac[:self.n_cables] = (self._cable_to_jacobian @ pieces.unit.reshape(-1, 6)).reshape(
                self.n_cables, self.n_frames, 6)
        forces = -jac                                     # cable: −τ ∂L/∂q
        if self.n_chambers:
            g = links.generalised_force(links.transport(self._pressure_stiffness))        # (n, chamber, 12)
            chamber_jac = np.zeros((self.n_chambers, self.n_frames, 6))
            chamber_jac[:, :-1] += np.moveaxis(g[..., :6], 1, 0)
            chamber_jac[:, 1:] += np.moveaxis(g[..., 6:], 1, 0)
            jac[self.n_cables:] = chamber_jac
            forces[self.n_cables:] = chamber_jac       # ∂r/∂p = (∂e/∂q)ᵀ K A G = Jaᵀ
        n_eff = len(self.effector_names)
        Je = self._effector_template.copy()          # translation part: a model constant
        turned, effector_positions = self._effector_points(state)
        Je[self._all_effectors, :, self.effector_frames, 3:] = -hat(turned)
        Je = Je.reshape(3 * n_eff, self.n_frames, 6)
        return Linearisation(
            residual=-ev.gradient[1:].reshape(-1), factor=factor,
            actuator_forces=forces[:, 1:].reshape(n_act, self.n_dof).T.copy(),
            actuator_jacobian=jac[:, 1:].reshape(n_act, self.n_dof),
            effector_jacobian=Je[:, 1:].reshape(3 * n_eff, self.n_dof),
            effector_positions=effector_positions,
            actuator_displacements=self.actuator_displacements(state, actuation, links=links, pieces=pieces))
