"""Unilateral contact (docs/contact.md): vertebra discs touching each other, and discs and
capsule-shaped segments touching the scene's obstacles.

The model is a set of gaps ``g_i(q) ≥ 0`` with contact forces ``λ_i ≥ 0`` and ``g_i λ_i = 0``.
Equilibrium minimises the potential ``E`` subject to the gaps: its Lagrangian is ``E − λᵀg``
and ``∇E = Gᵀλ`` with ``G = ∂g/∂q``. The forward solve (:mod:`vertebra.solver.newton`) takes
sequential-QP steps: at a state with residual ``r = −∇E`` and the banded factor of the
(shifted) tangent ``K``, the step minimises ``−rᵀp + ½ pᵀKp`` subject to the linearised gaps
``g + Gp ≥ 0``. Condensed on the contacts (the paper's compliance projection onto the contact
directions), that is the linear complementarity problem

    ``w = g + G K⁻¹ r + W λ ≥ 0,  λ ≥ 0,  wᵀλ = 0,   W = G K⁻¹ Gᵀ``

(the Delassus operator: one back-substitution of the banded factor per candidate contact),
solved exactly by principal pivoting (:func:`complementarity`); then ``p = K⁻¹(r + Gᵀλ)``.
The line search judges steps on the Lagrangian ``E − λᵀg`` at the new multipliers, along
which ``p`` descends (``−(r + Gᵀλ)ᵀp = −pᵀKp``).

Shapes. A vertebra with ``disc_radius > 0`` carries a disc of that radius and
``disc_thickness`` centred on its frame in the frame's x–y plane. Between discs it is a puck
(a flat disk swept by a ball of half the thickness, :func:`_puck_gap`): adjacent discs are
always candidates, any two others once their bounding spheres come near each other (a k-d
tree of the discs' centres at each state, :func:`fold_pairs`: a trunk folding onto itself).
A disc meets obstacles through its two faces: the closest point of each
rim circle, or against a box or a convex mesh the face's flat disk by the pairing of features
that holds it apart (:mod:`~vertebra.solver.contact_features`: face, edge, vertex or the disc's
own face; signed and smooth through contact at an edge). A segment with ``contact_radius`` is a chain of capsules along the
chords between its frames: its frames are balls of that radius, and a chord's interior meets
an obstacle where it is closer than both ends. The closest point of a rim or a chord to an
obstacle is closed-form for planes and spheres and found by bisection on the distance's
derivative along it for the other types; its gap's derivative is that of the closest point held fixed on the body (the
envelope theorem).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import SceneError
from vertebra.core.lie import qmatrix
from vertebra.solver.contact_features import (_cross, disk_mesh, disk_polyhedron, mesh_near_segments,
                                              segment_polyhedron)
from vertebra.solver.obstacles import Mesh, Plane, Sphere

RIM, BALL, CHORD, PAIR, FOLD = 0, 1, 2, 3, 4   # kinds of contact (PAIR: adjacent discs, FOLD: any other two)
TANGENTIAL = 16              # kinds from here on: the tangential rows of frictional contacts (contact_friction)
KIND_NAMES = ("disc", "frame", "segment", "disc", "disc")
DISCS = (PAIR, FOLD)         # the kinds between two discs
SAMPLES = 16                 # starting samples of the search for a rim's nearest point
CHORD_SAMPLES = 8            # … and a chord's
BISECTIONS = 52              # of a rim's angle (the bracket 2·2π/16) or a chord's parameter (2/8) to its rounding
FACE_POINTS = 8              # points on each rim of two discs lying face to face (fixed angles in the disc's frame) …
FACE_REACH = 2.0             # … while their gap is below this × the sum of their thicknesses
DIFFERENCE = 1e-6            # the step (rad; × the disc radius in m) of the disc pairs' curvature by central differences
JUMP = 1e-3                  # a pucks' nearest point moved on its body by this × the radius by those steps has jumped
MARGIN = 0.25                # candidate contacts: a gap below this share of the trunk's length …
FOLD_REACH = 1.0             # … and, for non-adjacent discs, bounding spheres apart by less than this × the sum of their radii
GAP_TOLERANCE = 1e-10        # a converged state's deepest penetration, per trunk length
ACTIVE_GAP = 1e-12           # a pressed contact's gap at convergence, per trunk length
REGULARISATION = 1e-12       # of the largest diagonal of W: redundant contacts stay solvable
STABILITY_SPRING = 1e6       # the springs (× the stiffness along the contact) that judge a constrained
                             # equilibrium's stability …
STEP_SPRING = 10.0           # … and that convexify a Newton step's model (augmented Lagrangian), first …
SPRING_GROWTH = 100.0        # … then this many times stiffer, up to STABILITY_SPRING, while not convex
PIVOTS = 200                 # principal pivoting steps per contact before the QP is refused
BLOCK_TRIES = 3              # block pivots in a row that do not lower the wrong indices, before single pivots
SINGLE_PIVOTS = 2            # single pivots per contact before the Dantzig–Cottle path is tried
PATH_PIVOTS = 4              # … which gives up after this many pivots per contact


_SWAP = np.r_[6:12, 0:6]       # a 12×12 block's two frames swapped


@dataclass(frozen=True, eq=False)
class ContactModel:
    """What a trunk can touch: discs, capsule segments and obstacles (compiled once)."""

    obstacles: tuple
    disc_frame: np.ndarray        # (d,) frame of each disc
    disc_vertebra: np.ndarray     # (d,) its vertebra
    disc_radius: np.ndarray       # (d,)
    disc_thickness: np.ndarray    # (d,)
    pair: np.ndarray              # (p, 2) discs (rim disc, face disc) of adjacent vertebrae
    pair_side: np.ndarray         # (p, 2) ±1: the side (along z) of each disc that faces the other
    ball_frame: np.ndarray        # (b,) frames of capsule segments
    ball_radius: np.ndarray       # (b,)
    chord: np.ndarray             # (c,) links of capsule segments (link k joins frames k, k + 1)
    chord_radius: np.ndarray      # (c,)
    length: float                 # the trunk's length: the scale of gaps
    vertebra_of_frame: np.ndarray # (n_frames,) the vertebra a frame belongs to (its repetition's end)

    @property
    def margin(self) -> float:
        return MARGIN * self.length


@dataclass
class ContactSet:
    """Contacts at one state (``m`` of them): which bodies, where, how far apart."""

    key: np.ndarray               # (m, 3) kind, feature, obstacle (−1 for disc pairs)
    gap: np.ndarray               # (m,) signed distance (m); < 0 penetrates
    point: np.ndarray             # (m, 3) the contact point on the body (world)
    normal: np.ndarray            # (m, 3) unit normal pushing the body away (world)
    frames: np.ndarray            # (m, 2) frames the gap depends on (−1: none)
    rows: np.ndarray              # (m, 2, 6) ∂g/∂q of those frames ([dx; dφ], world axes)
    origin: np.ndarray            # (m, 2, 3) the positions of those frames (world)
    slide: np.ndarray             # (m, 2, 3) the body point's first and second derivatives along
                                  # the rim's angle or the chord's parameter (zero for a ball)

    @property
    def count(self) -> int:
        return self.gap.size

    def jacobian(self, n_frames: int) -> np.ndarray:
        """``G = ∂g/∂q`` (m, 6·(n_frames − 1)) on the free frames (frame 0 is clamped)."""
        G = np.zeros((self.count, n_frames, 6))
        for side in range(2):
            frame = self.frames[:, side]
            used = frame > 0
            G[np.flatnonzero(used), frame[used]] += self.rows[used, side]     # (one frame per row and side)
        return G[:, 1:].reshape(self.count, 6 * (n_frames - 1))

    def forces(self, multipliers: np.ndarray, n_frames: int) -> np.ndarray:
        """The contact forces' generalised forces ``Gᵀλ`` (n_frames, 6) on every frame."""
        out = np.zeros((n_frames, 6))
        for side in range(2):
            frame = self.frames[:, side]
            used = frame >= 0
            np.add.at(out, frame[used], multipliers[used, None] * self.rows[used, side])
        return out

    def select(self, keys: np.ndarray) -> "ContactSet":
        """The contacts with the given keys, in their order (each must be present)."""
        index = {tuple(k): i for i, k in enumerate(self.key.tolist())}
        return self.take(np.array([index[tuple(k)] for k in keys.tolist()], int))

    def take(self, index: np.ndarray) -> "ContactSet":
        """The contacts at positions ``index``, in its order."""
        return ContactSet(self.key[index], self.gap[index], self.point[index], self.normal[index], self.frames[index],
                          self.rows[index], self.origin[index], self.slide[index])


# ---------------------------------------------------------------------------------------------
# compiling a scene's contact shapes


def compile_contact(scene, frames, links_segment: np.ndarray) -> ContactModel | None:
    """The contact model of a scene (None when it declares no disc, capsule or obstacle: the
    solve then runs without any contact code)."""
    vertebrae = [segment.vertebra for segment in scene.segments for _ in range(segment.count)]
    base = getattr(scene, "base_disc", (0.0, 0.0))
    radius = np.array([base[0]] + [v.disc_radius for v in vertebrae], float)
    thickness = np.array([base[1]] + [v.disc_thickness for v in vertebrae], float)
    capsule = np.array([segment.contact_radius if segment.contact_radius is not None else -1.0
                        for segment in scene.segments], float)
    obstacles = tuple(getattr(scene, "obstacles", ()))
    if not (np.any(radius > 0.0) or np.any(capsule >= 0.0) or obstacles):
        return None
    has_disc = np.flatnonzero(radius > 0.0)
    disc_frame = np.asarray(frames.vertebra)[has_disc]
    position = np.searchsorted(has_disc, has_disc)
    adjacent = np.flatnonzero(np.diff(has_disc) == 1)
    # the smaller disc's rim meets the larger one's face (the upper one's rim when equal)
    lower, upper = position[adjacent], position[adjacent + 1]
    upper_rim = radius[has_disc][upper] <= radius[has_disc][lower]
    pair = np.stack([np.where(upper_rim, upper, lower), np.where(upper_rim, lower, upper)], 1).reshape(-1, 2)
    pair_side = np.stack([np.where(upper_rim, -1.0, 1.0), np.where(upper_rim, 1.0, -1.0)], 1).reshape(-1, 2)
    chord = np.flatnonzero(capsule[links_segment] >= 0.0)
    chord_radius = capsule[links_segment][chord]
    ball_radius = np.full(frames.count, -1.0)
    np.maximum.at(ball_radius, chord, chord_radius)
    np.maximum.at(ball_radius, chord + 1, chord_radius)
    ball_frame = np.flatnonzero(ball_radius >= 0.0)
    vertebra_of_frame = np.searchsorted(np.asarray(frames.vertebra), np.arange(frames.count))
    model = ContactModel(obstacles, disc_frame, has_disc, radius[has_disc], thickness[has_disc], pair, pair_side,
                         ball_frame, ball_radius[ball_frame], chord, chord_radius, float(frames.length_scale),
                         vertebra_of_frame)
    for array in (model.disc_frame, model.disc_vertebra, model.disc_radius, model.disc_thickness, model.pair,
                  model.pair_side, model.ball_frame, model.ball_radius, model.chord, model.chord_radius,
                  model.vertebra_of_frame):
        array.flags.writeable = False
    return model


def coupled_frames(model: ContactModel | None) -> np.ndarray:
    """The pairs of frames (k, 2), lower first, that adjacent discs couple more than one link
    apart: the band gives their contacts' tangent blocks a slot (:class:`~vertebra.solver.assembly.BandAssembler`)."""
    if model is None or not model.pair.size:
        return np.zeros((0, 2), int)
    frames = np.sort(model.disc_frame[model.pair], 1)
    return frames[frames[:, 1] - frames[:, 0] > 1]


def check_rest(model: ContactModel, state, source: str) -> None:
    """Refuse a scene whose discs overlap, or whose trunk is inside an obstacle, at rest."""
    found = evaluate(model, state)
    tolerance = GAP_TOLERANCE * model.length
    bad = np.flatnonzero(found.gap < -tolerance)
    if bad.size:
        k = bad[int(np.argmin(found.gap[bad]))]
        raise SceneError(f"at rest {describe(model, found.key[k])} overlap by {-found.gap[k]:.3g} m: the contact "
                         "model needs a state without penetration to start from (check disc_thickness against the "
                         "vertebra spacing, and the obstacles' placement)", file=source,
                         field="segment" if found.key[k, 0] in DISCS else "obstacle")


def interpenetration(model: ContactModel, contacts: ContactSet) -> tuple[float, int]:
    """How far the disc pairs of ``contacts`` (the candidates at a state) have gone into each
    other, as a share of the depth :func:`interpenetrating` refuses (half the sum of their half
    thicknesses), and the deepest pair's index in ``contacts`` ((0, −1) without disc pairs)."""
    pair = np.flatnonzero(np.isin(contacts.key[:, 0], DISCS))
    if not pair.size:
        return 0.0, -1
    first, second = pair_discs(model, contacts.key[pair])
    depth = -contacts.gap[pair] / (0.25 * (model.disc_thickness[first] + model.disc_thickness[second]))
    worst = int(np.argmax(depth))
    return float(depth[worst]), int(pair[worst])


def interpenetrating(model: ContactModel, contacts: ContactSet) -> np.ndarray | None:
    """The key of a disc pair of ``contacts`` (the candidates at a state) that has gone more than
    half their thickness into each other (half the sum of their half thicknesses: half way to
    where the pucks' flat cores meet, the gap's floor, and its direction is lost) — beyond what a
    Newton iterate's penetration can be — or None."""
    depth, worst = interpenetration(model, contacts)
    return contacts.key[worst] if depth > 1.0 else None


def fold_pairs(model: ContactModel, x: np.ndarray, reach: float = FOLD_REACH) -> tuple[np.ndarray, np.ndarray]:
    """The broad phase of discs that are not neighbours (frame positions ``x``): the pairs
    (first, second; first < second) whose bounding spheres (the outer radius about the frame)
    come within ``reach`` × the sum of their radii of each other — the pairs of a k-d tree of the
    discs' centres within the widest such distance, then each pair's own: near-linear in the discs."""
    count = model.disc_frame.size
    none = np.zeros(0, int), np.zeros(0, int)
    if count < 3:
        return none
    from scipy.spatial import cKDTree

    centre = x[model.disc_frame]
    pairs = cKDTree(centre).query_pairs(2.0 * (1.0 + reach) * float(model.disc_radius.max()), output_type="ndarray")
    if not pairs.size:
        return none
    first, second = pairs.min(1), pairs.max(1)
    apart = np.sqrt(np.add.reduce((centre[first] - centre[second]) ** 2, 1))
    near = apart < (1.0 + reach) * (model.disc_radius[first] + model.disc_radius[second])
    code = first * count + second
    adjacent = np.sort(model.pair, 1) @ np.array([count, 1]) if model.pair.size else np.zeros(0, int)
    keep = near & ~np.isin(code, adjacent)
    order = np.argsort(code[keep], kind="stable")
    return first[keep][order], second[keep][order]


def overlapping(model: ContactModel, state) -> tuple[int, int, float] | None:
    """The deepest overlap of two non-adjacent discs at ``state`` — (vertebra, vertebra, depth in
    m) — or None: the safety net behind their contacts (a state in which two discs overlap that
    the contacts did not hold apart is not an equilibrium). Pairs whose bounding spheres meet
    get the exact gap."""
    first, second = fold_pairs(model, state.positions, 0.0)
    if not first.size:
        return None
    gap = disc_gaps(model, state, first, second)
    k = int(np.argmin(gap))
    if gap[k] >= -GAP_TOLERANCE * model.length:
        return None
    return int(model.disc_vertebra[first[k]]), int(model.disc_vertebra[second[k]]), float(-gap[k])


def describe(model: ContactModel, key) -> str:
    """The bodies of a contact in words."""
    kind, feature, obstacle = (int(v) for v in key)
    if kind in DISCS:
        a, b = (int(model.disc_vertebra[d[0]]) for d in pair_discs(model, np.array([key], int)))
        return f"the discs of vertebrae {min(a, b)} and {max(a, b)}"
    if kind == RIM:
        body = f"the disc of vertebra {int(model.disc_vertebra[feature // 2])}"
    elif kind == BALL:
        body = f"frame {int(model.ball_frame[feature])} (vertebra {int(model.vertebra_of_frame[model.ball_frame[feature]])})"
    else:
        body = f"link {int(model.chord[feature])}"
    return f"{body} and obstacle {obstacle} ({model.obstacles[obstacle].type})"


def bodies(model: ContactModel, key) -> tuple[str, str]:
    """The two bodies of a contact as short labels (JSON)."""
    kind, feature, obstacle = (int(v) for v in key)
    if kind in DISCS:
        a, b = sorted(int(model.disc_vertebra[d[0]]) for d in pair_discs(model, np.array([key], int)))
        return f"vertebra {a} disc", f"vertebra {b} disc"
    if kind == RIM:
        body = f"vertebra {int(model.disc_vertebra[feature // 2])} disc"
    elif kind == BALL:
        body = f"frame {int(model.ball_frame[feature])}"
    else:
        body = f"link {int(model.chord[feature])}"
    return body, f"obstacle {obstacle} ({model.obstacles[obstacle].type})"


# ---------------------------------------------------------------------------------------------
# gaps at a state


def _least(slope, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The minimiser of each distance (batched) in ``[low, high]`` by bisection on the sign of its
    derivative ``slope(s)`` (the obstacle's normal at the point along the point's motion), to the
    rounding of ``s``. A search on the distance's value (golden section) ends at √ε of the
    bracket — the value is flat at its least — and a nearest point off by that moves the
    contact's lever arm: a chord's force split between its frames by 1e-8 of itself, a
    residual floor above the solve's tolerance."""
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        falling = slope(middle) < 0.0
        low, high = np.where(falling, middle, low), np.where(falling, high, middle)
    return 0.5 * (low + high)


def _rim_points(center, e1, e2, radius, angle):
    return center + radius[:, None] * (np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2)


def _lowest_on_rim(center, axis, e1, radius, direction):
    """The rim point farthest along ``−direction`` (a plane's normal projected on the disc)."""
    inplane = direction - np.add.reduce(direction * axis, -1)[:, None] * axis
    norm = np.sqrt(np.add.reduce(inplane * inplane, -1))
    u = np.where((norm > 1e-12)[:, None], inplane / np.maximum(norm, 1e-300)[:, None], e1)
    return center - radius[:, None] * u


def _convex(obstacle):
    """The obstacle's polyhedron when it is a convex one (a box, a convex mesh), else None."""
    polyhedron = getattr(obstacle, "polyhedron", None)
    return polyhedron if polyhedron is not None and polyhedron.convex else None


def _disk_gap(obstacle):
    """The closed-form gap of a disc's face against the obstacle (a function of the frame and the
    face's disk, :mod:`~vertebra.solver.contact_features`): a triangle mesh's by the features near the
    disk (convex or not), a box's by the separating axes; None for the other types."""
    if isinstance(obstacle, Mesh):
        return lambda *disk, second=False: disk_mesh(obstacle, *disk, second=second)
    polyhedron = _convex(obstacle)
    if polyhedron is not None:
        return lambda *disk, second=False: disk_polyhedron(polyhedron, *disk, second=second)
    return None


def _faces_of(model, R, x, features):
    """The disk of each disc face (feature 2d: the lower face of disc d, 2d + 1 its upper face):
    frame, centre, in-plane axes, axis, radius."""
    disc = features // 2
    side = np.where(features % 2, 0.5, -0.5)
    frame = model.disc_frame[disc]
    axes = R[frame]
    e1, e2, axis = axes[:, :, 0], axes[:, :, 1], axes[:, :, 2]
    center = x[frame] + (side * model.disc_thickness[disc])[:, None] * axis
    return frame, center, e1, e2, axis, model.disc_radius[disc]


def _polyhedron_rims(model, state, features, obstacle) -> np.ndarray:
    """``∂²g`` (k, 6, 6) of disc faces ``features`` against a convex polyhedron at ``state``: the
    derivative of the gap's row on the disc's frame, closed form (:func:`disk_polyhedron`)."""
    x, R = state.positions, qmatrix(state.quaternions)
    frame, center, e1, e2, axis, radius = _faces_of(model, R, x, features)
    return _disk_gap(obstacle)(x[frame], center, axis, e1, e2, radius, second=True)[4]


def _rims(model, R, x, features, obstacle):
    """Closest points of disc rims (feature 2d: the lower face of disc d, 2d + 1 its upper face)."""
    frame, center, e1, e2, axis, radius = _faces_of(model, R, x, features)
    gap = _disk_gap(obstacle)
    if gap is not None:
        # a box or a mesh: the face's disk against its faces, edges and vertices (contact_features)
        distance, point, normal, _ = gap(x[frame], center, axis, e1, e2, radius)
        rows = np.zeros((features.size, 2, 6))
        rows[:, 0, :3] = normal
        rows[:, 0, 3:] = _cross(point - x[frame], normal)
        return (distance, point, normal, np.stack([frame, np.full(frame.size, -1)], 1), rows,
                np.zeros((features.size, 2, 3)))      # (its curvature: :func:`_polyhedron_rims`)
    if isinstance(obstacle, Plane):
        point = _lowest_on_rim(center, axis, e1, radius, np.broadcast_to(obstacle.normal, center.shape))
    elif isinstance(obstacle, Sphere):
        point = _lowest_on_rim(center, axis, e1, radius, center - obstacle.center)
    else:
        samples = 2.0 * math.pi * np.arange(SAMPLES) / SAMPLES
        trial = _rim_points(np.repeat(center, SAMPLES, 0), np.repeat(e1, SAMPLES, 0), np.repeat(e2, SAMPLES, 0),
                            np.repeat(radius, SAMPLES), np.tile(samples, center.shape[0]))
        start = samples[np.argmin(obstacle.closest(trial)[0].reshape(-1, SAMPLES), 1)]
        width = 2.0 * math.pi / SAMPLES
        def slope(s):
            along = radius[:, None] * (np.cos(s)[:, None] * e2 - np.sin(s)[:, None] * e1)
            return np.add.reduce(obstacle.closest(_rim_points(center, e1, e2, radius, s))[1] * along, -1)

        angle = _least(slope, start - width, start + width)
        point = _rim_points(center, e1, e2, radius, angle)
    distance, normal, _ = obstacle.closest(point)
    rows = np.zeros((features.size, 2, 6))
    rows[:, 0, :3] = normal
    rows[:, 0, 3:] = _cross(point - x[frame], normal)
    return (distance, point, normal, np.stack([frame, np.full(frame.size, -1)], 1), rows,
            np.stack([_cross(axis, point - center), center - point], 1))


def _balls(model, R, x, features, obstacle):
    frame = model.ball_frame[features]
    distance, normal, _ = obstacle.closest(x[frame])
    radius = model.ball_radius[features]
    rows = np.zeros((features.size, 2, 6))
    rows[:, 0, :3] = normal
    return (distance - radius, x[frame] - radius[:, None] * normal, normal,
            np.stack([frame, np.full(frame.size, -1)], 1), rows, np.zeros((features.size, 2, 3)))


def _chords(model, R, x, features, obstacle, ends=False):
    """Closest interior points of chords (where the ends are farther: a ball covers an end; an
    end found is kept only with ``ends``: a contact followed from one state to the next)."""
    link = model.chord[features]
    a, b = x[link], x[link + 1]
    if isinstance(obstacle, Plane):
        t = np.zeros(link.size)          # a plane is closest at an end
    elif isinstance(obstacle, Sphere):
        ab = b - a
        t = np.clip(np.add.reduce((obstacle.center - a) * ab, -1) / np.maximum(np.add.reduce(ab * ab, -1), 1e-300),
                    0.0, 1.0)
    else:
        polyhedron = _convex(obstacle)
        t, search = np.zeros(link.size), np.ones(link.size, bool)
        if polyhedron is not None:
            # a convex polyhedron: outside it the distance along the chord is smooth and convex, its
            # pieces a face's (linear), an edge's or a vertex's, so its least is at an end, a
            # vertex's projection or the chord's nearest point to an edge's line (one query)
            near = (lambda a, b: mesh_near_segments(obstacle, a, b)) if isinstance(obstacle, Mesh) else None
            t, distance = segment_polyhedron(polyhedron, obstacle.closest, a, b, near)
            search = distance <= 0.0             # (through it: the least is inside, where faces' planes meet)
        if search.any():
            a_s, b_s = a[search], b[search]
            samples = np.linspace(0.0, 1.0, CHORD_SAMPLES + 1)
            trial = a_s[:, None] + samples[None, :, None] * (b_s - a_s)[:, None]
            sampled = obstacle.closest(trial.reshape(-1, 3))[0].reshape(a_s.shape[0], -1)
            start = samples[np.argmin(sampled, 1)]
            width = 1.0 / CHORD_SAMPLES
            least = _least(lambda s: np.add.reduce(obstacle.closest(a_s + s[:, None] * (b_s - a_s))[1]
                                                   * (b_s - a_s), -1),
                           np.maximum(start - width, 0.0), np.minimum(start + width, 1.0))
            # an interior point no nearer than an end (the distance flat along the chord: lying on a
            # face) is the end's, whose ball covers it
            nearer = obstacle.closest(a_s + least[:, None] * (b_s - a_s))[0] < np.minimum(sampled[:, 0], sampled[:, -1])
            t[search] = np.where(nearer, least, np.where(sampled[:, 0] <= sampled[:, -1], 0.0, 1.0))
    interior = (t > 1e-9) & (t < 1.0 - 1e-9)
    point = a + t[:, None] * (b - a)
    distance, normal, _ = obstacle.closest(point)
    radius = model.chord_radius[features]
    rows = np.zeros((features.size, 2, 6))
    rows[:, 0, :3] = (1.0 - t)[:, None] * normal
    rows[:, 1, :3] = t[:, None] * normal
    gap = distance - radius if ends else np.where(interior, distance - radius, np.inf)
    return (gap, point - radius[:, None] * normal, normal, np.stack([link, link + 1], 1), rows,
            np.stack([b - a, np.zeros_like(a)], 1))


def _to_disk(p, center, axis, radius):
    """The point of each flat disk (``center``, unit ``axis``, ``radius``) nearest ``p``."""
    v = p - center
    w = v - np.add.reduce(v * axis, -1)[..., None] * axis
    rho = np.sqrt(np.add.reduce(w * w, -1))
    return center + np.minimum(1.0, radius / np.maximum(rho, 1e-300))[..., None] * w


def _rim_to_disk(center, e1, e2, radius, other_center, other_axis, other_radius):
    """The point of each rim circle (``center``, in-plane axes ``e1``, ``e2``, ``radius``) nearest
    the flat disk ``other_*``: 16 samples, then bisection on the derivative of the squared
    distance (``(p − q)·∂p/∂s``, continuous: the distance to a convex set is smooth outside it)
    to the rounding of the angle. Returns (distance, p, q)."""
    def at(s):
        c, sn = np.cos(s)[..., None], np.sin(s)[..., None]
        p = center + radius[..., None] * (c * e1 + sn * e2)
        q = _to_disk(p, other_center, other_axis, other_radius)
        return p, q, radius[..., None] * (c * e2 - sn * e1)

    samples = 2.0 * math.pi * np.arange(SAMPLES) / SAMPLES
    n = center.shape[0]
    p, q, _ = at(np.broadcast_to(samples, (n, SAMPLES)).T)           # (SAMPLES, n, 3)
    d2 = np.add.reduce((p - q) ** 2, -1)
    width = 2.0 * math.pi / SAMPLES
    low = samples[np.argmin(d2, 0)] - width
    high = low + 2.0 * width
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        p, q, tau = at(middle)
        falling = np.add.reduce((p - q) * tau, -1) < 0.0
        low, high = np.where(falling, middle, low), np.where(falling, high, middle)
    p, q, _ = at(0.5 * (low + high))
    return np.sqrt(np.add.reduce((p - q) ** 2, -1)), p, q


def _disc_pairs(model, R, x, first, second, point=None):
    """Disc ``first`` against disc ``second`` (index arrays). Each disc is a puck: the flat disk of
    radius ``R − t/2`` in its frame's x–y plane swept by a ball of radius ``t/2`` (thickness
    ``t``, outer radius ``R``, a rounded rim). The gap is the distance between the two flat
    disks less the two half thicknesses: the nearer of each rim against the other's disk (the
    distance between two convex sets has a nearest point on a rim of one of them). Rim against
    face, rim against rim and the discs folded past each other's rim are the same smooth gap.
    ``point`` (default −1: the gap) ``≥ 0`` takes instead a rim point at a fixed angle against
    the other's disk (:func:`_face_point`, :func:`_rim_point_gap`)."""
    fa, fb = model.disc_frame[first], model.disc_frame[second]
    ha, hb = 0.5 * model.disc_thickness[first], 0.5 * model.disc_thickness[second]
    ra, rb = model.disc_radius[first] - ha, model.disc_radius[second] - hb
    if point is None:
        return _puck_gap(x[fa], R[fa], ra, ha, x[fb], R[fb], rb, hb) + (np.stack([fa, fb], 1),)
    return _pair_gap(x[fa], R[fa], ra, ha, x[fb], R[fb], rb, hb, point >= 0, *_face_point(np.maximum(point, 0))) + (
        np.stack([fa, fb], 1),)


def _pair_gap(xa, Ra, ra, ha, xb, Rb, rb, hb, fixed, second=None, angle=None):
    """:func:`_puck_gap`, and where ``fixed`` the gap of a rim point held on its disc
    (:func:`_rim_point_gap`: on the second's rim where ``second``, at ``angle`` in its frame)."""
    if not np.any(fixed):
        return _puck_gap(xa, Ra, ra, ha, xb, Rb, rb, hb)
    out = _rim_point_gap(xa, Ra, ra, ha, xb, Rb, rb, hb, second, angle)
    exact = ~fixed
    if exact.any():
        found = _puck_gap(xa[exact], Ra[exact], ra[exact], ha[exact], xb[exact], Rb[exact], rb[exact], hb[exact])
        for whole, part in zip(out, found):
            whole[exact] = part
    return out


def _rim_point_gap(xa, Ra, ra, ha, xb, Rb, rb, hb, second, angle):
    """(gap, point on the first puck, unit normal pushing it away, rows (k, 2, 6)) of a point held
    on one puck's rim against the other puck: on the second core's rim where ``second``, else on
    the first's, at ``angle`` in its frame; the gap is its distance to the other flat disk less the
    two half thicknesses (at least the pucks' gap)."""
    c, sn = np.cos(angle)[..., None], np.sin(angle)[..., None]
    own_x, own_R, own_r = (np.where(second[..., None], xb, xa), np.where(second[..., None, None], Rb, Ra),
                           np.where(second, rb, ra))
    other_x, other_R, other_r = (np.where(second[..., None], xa, xb), np.where(second[..., None, None], Ra, Rb),
                                 np.where(second, ra, rb))
    on_rim = own_x + own_r[..., None] * (c * own_R[..., 0] + sn * own_R[..., 1])
    on_disk = _to_disk(on_rim, other_x, other_R[..., 2], other_r)
    p = np.where(second[..., None], on_disk, on_rim)                # on the first core, on the second
    q = np.where(second[..., None], on_rim, on_disk)
    return _core_gap(p, q, np.sqrt(np.add.reduce((p - q) ** 2, -1)), xa, ha, xb, hb)


def _face_point(point):
    """The rim and angle of face point ``point`` (:func:`_face_points`): ``k < FACE_POINTS`` is the
    first disc's rim at ``2πk/FACE_POINTS`` in its frame, ``FACE_POINTS + k`` the second's."""
    return point >= FACE_POINTS, 2.0 * math.pi * (point % FACE_POINTS) / FACE_POINTS


def _nearest_rim_point(xa, Ra, ra, xb, Rb, rb):
    """Where the pucks' gap (:func:`_puck_gap`) has its nearest point: on the second's rim or the
    first's, and its angle in that disc's frame."""
    da, pa, _ = _rim_to_disk(xa, Ra[..., 0], Ra[..., 1], ra, xb, Rb[..., 2], rb)
    db, pb, _ = _rim_to_disk(xb, Rb[..., 0], Rb[..., 1], rb, xa, Ra[..., 2], ra)
    second = db < da
    v = np.where(second[..., None], pb - xb, pa - xa)
    own = np.where(second[..., None, None], Rb, Ra)
    return second, np.arctan2(np.add.reduce(v * own[..., 1], -1), np.add.reduce(v * own[..., 0], -1))


def _facing(model, R, first, second) -> np.ndarray:
    """Do discs ``first`` and ``second`` lie face to face: their faces so nearly parallel (either
    way) that across the wider disc the tilt moves the rim by less than the sum of their
    thicknesses (``2 R sin θ < t₁ + t₂``)? Discs touching at their rims as a trunk bends are
    tilted by far more (their far sides open by about twice the spacing less the thickness)."""
    cosine = np.add.reduce(R[model.disc_frame[first], :, 2] * R[model.disc_frame[second], :, 2], -1)
    tilt = np.sqrt(np.maximum(0.0, 1.0 - cosine * cosine))
    return (2.0 * np.maximum(model.disc_radius[first], model.disc_radius[second]) * tilt
            < model.disc_thickness[first] + model.disc_thickness[second])


def _face_points(model, R, key, gap):
    """The keys of the face points of the disc pairs ``key`` (gaps ``gap``) that lie face to face
    (:func:`_facing`) with a gap below :data:`FACE_REACH` × the sum of their thicknesses:
    :data:`FACE_POINTS` points held at fixed angles on each disc's rim (:func:`_face_point`), each
    against the other's disk (:func:`_rim_point_gap`). A point's key is its pair's with
    ``−2 − point`` in the obstacle's place. Two discs lying face to face touch over an area: the
    pucks' gap then has its nearest point on whichever side of the rims the faces' tilt puts it,
    and its derivative turns with the tilt's sign (no step that tilts them opens it); these
    points, smooth each, keep the faces from entering each other on every side (a polygon of
    support points, as for a flat contact), beside the pucks' gap."""
    first, second = pair_discs(model, key)
    near = _facing(model, R, first, second) & (gap < FACE_REACH * (model.disc_thickness[first]
                                                                     + model.disc_thickness[second]))
    if not near.any():
        return np.zeros((0, 3), int)
    points = np.arange(2 * FACE_POINTS)
    chosen = np.repeat(key[near], points.size, 0)
    chosen[:, 2] = -2 - np.tile(points, int(near.sum()))
    return chosen


def _puck_gap(xa, Ra, ra, ha, xb, Rb, rb, hb, where: bool = False):
    """(gap, point on the first puck, unit normal pushing it away, rows (k, 2, 6)) of two pucks
    on frames at ``xa``, ``xb`` with rotations ``Ra``, ``Rb`` (core radii ``r``, half thicknesses ``h``);
    with ``where``, also the nearest points of the two cores (on the first, on the second)."""
    da, pa, qa = _rim_to_disk(xa, Ra[..., 0], Ra[..., 1], ra, xb, Rb[..., 2], rb)
    db, pb, qb = _rim_to_disk(xb, Rb[..., 0], Rb[..., 1], rb, xa, Ra[..., 2], ra)
    first = (da <= db)[..., None]
    p, q = np.where(first, pa, qb), np.where(first, qa, pb)          # on the first core, on the second
    out = _core_gap(p, q, np.minimum(da, db), xa, ha, xb, hb)
    return out + ((p, q),) if where else out


def _core_gap(p, q, distance, xa, ha, xb, hb):
    """(gap, point on the first puck, unit normal pushing it away, rows (k, 2, 6)) of two pucks
    whose cores (on frames at ``xa``, ``xb``; half thicknesses ``h``) come nearest at ``p`` (on the
    first) and ``q``, ``distance`` apart: the rows of the nearest points held on their bodies."""
    normal = (p - q) / np.maximum(distance, 1e-300)[..., None]
    rows = np.empty(p.shape[:-1] + (2, 6))
    rows[..., 0, :3] = normal
    rows[..., 0, 3:] = _cross(p - xa, normal)
    rows[..., 1, :3] = -normal
    rows[..., 1, 3:] = -_cross(q - xb, normal)
    return distance - ha - hb, p - ha[..., None] * normal, normal, rows


def disc_gaps(model: ContactModel, state, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The gaps (m) between discs ``first`` and ``second`` (index arrays, any two discs) at ``state``."""
    return _disc_pairs(model, qmatrix(state.quaternions), state.positions, first, second)[0]


def _discs(model, R, x, key):
    """Disc–disc contacts ``key`` (m, 3; adjacent or not: :func:`_disc_pairs`); the sliding of the
    nearest points is in the curvature's differences (:func:`_pair_curvature`), not in ``slide``."""
    gap, point, normal, rows, frames = _disc_pairs(model, R, x, *pair_discs(model, key), -2 - key[:, 2])
    return gap, point, normal, frames, rows, np.zeros((key.shape[0], 2, 3))


_FEATURES = {RIM: _rims, BALL: _balls, CHORD: _chords}


def _counts(model) -> dict:
    return {RIM: 2 * model.disc_frame.size, BALL: model.ball_frame.size, CHORD: model.chord.size}


def evaluate(model: ContactModel, state, keys: np.ndarray | None = None) -> ContactSet:
    """The contacts at ``state``: every candidate whose gap is below the margin (``keys`` None:
    the broad phase — the margin around each obstacle's bounds, then the exact gaps), or exactly
    the contacts ``keys`` (m, 3), in their order."""
    x, R = state.positions, qmatrix(state.quaternions)
    parts = []
    if keys is None:
        if model.pair.size:
            features = np.arange(model.pair.shape[0])
            key = np.column_stack([np.full(features.size, PAIR), features, np.full(features.size, -1)])
            parts.append((key, _discs(model, R, x, key)))
        first, second = fold_pairs(model, x)
        if first.size:
            key = np.column_stack([np.full(first.size, FOLD), first * model.disc_frame.size + second,
                                   np.full(first.size, -1)])
            parts.append((key, _discs(model, R, x, key)))
        if parts:          # discs lying face to face: points round their rims beside the pucks' gap
            key = _face_points(model, R, np.concatenate([k for k, _ in parts]),
                               np.concatenate([found[0] for _, found in parts]))
            if key.size:
                parts.append((key, _discs(model, R, x, key)))
        for j, obstacle in enumerate(model.obstacles):
            near = _near(model, x, obstacle)
            for kind, function in _FEATURES.items():
                features = near[kind]
                if kind == CHORD and isinstance(obstacle, Plane):
                    continue        # a plane is nearest a chord at an end, which a ball covers
                if features.size:
                    parts.append((np.column_stack([np.full(features.size, kind), features,
                                                   np.full(features.size, j)]),
                                  function(model, R, x, features, obstacle)))
    else:
        keys = np.asarray(keys, int).reshape(-1, 3)
        for kind, j in sorted(set(zip(keys[:, 0].tolist(), keys[:, 2].tolist()))):
            chosen = keys[(keys[:, 0] == kind) & (keys[:, 2] == j)]
            features = chosen[:, 1]
            found = (_discs(model, R, x, chosen) if kind in DISCS
                     else _chords(model, R, x, features, model.obstacles[j], ends=True) if kind == CHORD
                     else _FEATURES[kind](model, R, x, features, model.obstacles[j]))
            parts.append((chosen, found))
    if not parts:
        return ContactSet(np.zeros((0, 3), int), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)),
                          np.zeros((0, 2), int), np.zeros((0, 2, 6)), np.zeros((0, 2, 3)), np.zeros((0, 2, 3)))
    key = np.concatenate([k for k, _ in parts])
    gap, point, normal, frames, rows, slide = (np.concatenate([found[i] for _, found in parts]) for i in range(6))
    origin = np.where((frames >= 0)[:, :, None], x[np.maximum(frames, 0)], 0.0)
    found = ContactSet(key, gap, point, normal, frames, rows, origin, slide)
    if keys is None:
        return found.take(np.flatnonzero(found.gap < model.margin))
    return found.select(keys)


def _near(model, x, obstacle) -> dict:
    """The broad phase: the features of each kind whose bounding box comes within the margin of
    the obstacle's (every feature for an unbounded obstacle)."""
    counts = _counts(model)
    box = obstacle.bounds()
    if box is None:
        return {kind: np.arange(n) for kind, n in counts.items()}
    low, high = box[0] - model.margin, box[1] + model.margin
    out = {}
    reach = np.repeat(model.disc_radius + 0.5 * model.disc_thickness, 2)
    centre = np.repeat(x[model.disc_frame], 2, 0) if model.disc_frame.size else np.zeros((0, 3))
    out[RIM] = np.flatnonzero(np.all((centre + reach[:, None] >= low) & (centre - reach[:, None] <= high), 1))
    ball = x[model.ball_frame]
    out[BALL] = np.flatnonzero(np.all((ball + model.ball_radius[:, None] >= low)
                                      & (ball - model.ball_radius[:, None] <= high), 1))
    a, b = x[model.chord], x[model.chord + 1]
    r = model.chord_radius[:, None]
    out[CHORD] = np.flatnonzero(np.all((np.maximum(a, b) + r >= low) & (np.minimum(a, b) - r <= high), 1))
    return out


# ---------------------------------------------------------------------------------------------
# the complementarity problem in constraint space


def complementarity(W: np.ndarray, b: np.ndarray, start: np.ndarray | None = None) -> np.ndarray | None:
    """``λ ≥ 0`` with ``w = b + Wλ ≥ 0`` and ``wᵀλ = 0`` for a P-matrix ``W`` (positive definite,
    or the unsymmetric Delassus operator of a dead-moment tangent), by principal pivoting: the
    forces of a pressed set come from one dense solve on its rows, and the set is the answer when
    none of them pulls and no other gap penetrates (to 1e-13 of the problem's scale). From the set
    ``start`` (bool (m,): the contacts pressed now, mostly the answer again along a solve; default
    the contacts with ``b < 0``): block pivots — every wrong index of the set changed at once
    (Júdice and Pires) — while they lower the fewest wrong indices seen (``BLOCK_TRIES`` more that
    do not), then Murty's single pivots (least index rule: finite for P-matrices from any set).
    Where those cycle (nearly redundant contacts: the answer is then unique only up to the
    tolerance), after ``SINGLE_PIVOTS`` per contact the Dantzig–Cottle path from nothing pressed is
    tried (:func:`_principal_path`, about one solve per contact it presses), then Murty's pivots go
    on. The answer is unique for a P-matrix: the order changes only the work. None when no set is
    found."""
    m = b.size
    active = (b < 0.0) if start is None else np.asarray(start, bool).copy()
    scale = np.abs(b).max(initial=0.0) + 1e-300
    force_floor = -1e-13 * scale / max(np.abs(np.diag(W)).max(initial=0.0), 1e-300)
    gap_floor = -1e-13 * scale
    fewest, spare, single = m + 1, BLOCK_TRIES, 0
    for _ in range(PIVOTS * max(m, 1)):
        lam = np.zeros(m)
        index = np.flatnonzero(active)
        if index.size:
            try:
                lam[index] = np.linalg.solve(W[np.ix_(index, index)], -b[index])
            except np.linalg.LinAlgError:
                return None
        w = b + W @ lam
        wrong = np.flatnonzero((active & (lam < force_floor)) | (~active & (w < gap_floor)))
        if not wrong.size:
            return np.where(active, np.maximum(lam, 0.0), 0.0)
        if not single:
            if wrong.size < fewest:
                fewest, spare = wrong.size, BLOCK_TRIES
            elif spare:
                spare -= 1
            else:
                single = 1                       # Murty's pivoting from here on
        if not single:
            active[wrong] = ~active[wrong]
            continue
        single += 1
        if single == SINGLE_PIVOTS * m:
            path = _principal_path(W, b, gap_floor)
            if path is not None:
                active = path
                continue
        active[wrong[0]] = not active[wrong[0]]
    return None


def _principal_path(W: np.ndarray, b: np.ndarray, floor: float) -> np.ndarray | None:
    """The pressed set (bool (m,)) that the Dantzig–Cottle principal pivoting method reaches for
    ``w = b + Wλ`` from nothing pressed: the most penetrating contact's force is raised, the
    pressed ones' following to keep their gaps closed, until its gap closes (it is pressed), a
    pressed force falls to zero (that contact opens) or another gap closes (that one is pressed
    too); then the next penetrating contact (``w < floor``), until none is left. For a P-matrix
    its gap always opens as its force rises. None when a pivot fails or it takes more than
    ``PATH_PIVOTS`` pivots per contact (degenerate steps)."""
    m = b.size
    active = np.zeros(m, bool)
    lam, w = np.zeros(m), b.copy()
    r = -1
    for _ in range(PATH_PIVOTS * max(m, 1)):
        if r < 0:
            open_ = np.flatnonzero(~active & (w < floor))
            if not open_.size:
                return active
            r = int(open_[np.argmin(w[open_])])
        index = np.flatnonzero(active)
        d = np.zeros(m)
        d[r] = 1.0
        if index.size:
            try:
                d[index] = -np.linalg.solve(W[np.ix_(index, index)], W[index, r])
            except np.linalg.LinAlgError:
                return None
        dw = W @ d
        if not dw[r] > 0.0:
            return None
        t, leaving = -w[r] / dw[r], r
        falling = index[d[index] < 0.0]
        if falling.size:
            ratio = lam[falling] / -d[falling]
            k = int(np.argmin(ratio))
            if ratio[k] < t:
                t, leaving = ratio[k], int(falling[k])
        closing = np.flatnonzero(~active & (dw < 0.0) & (w >= 0.0))
        closing = closing[closing != r]
        if closing.size:
            ratio = w[closing] / -dw[closing]
            k = int(np.argmin(ratio))
            if ratio[k] < t:
                t, leaving = ratio[k], int(closing[k])
        t = max(t, 0.0)
        lam += t * d
        w += t * dw
        if active[leaving]:                  # a pressed force fell to zero: that contact opens
            active[leaving], lam[leaving] = False, 0.0
        else:                                # a gap closed (the raised contact's: it is pressed)
            active[leaving], w[leaving] = True, 0.0
            if leaving == r:
                r = -1
    return None


@dataclass
class Step:
    """A contact-constrained step: the frame increments, the multipliers and the contacts they
    act at (taken at the step's start), and the Lagrangian's residual ``r + Gᵀλ``."""

    dq: np.ndarray
    multipliers: np.ndarray
    contacts: ContactSet
    balanced: np.ndarray


class Constraints:
    """The contact side of one Newton stage: the contacts of the states it visits, the
    multipliers of the last step, and what the forward solve asks of them."""

    def __init__(self, trunk):
        self.trunk, self.model = trunk, trunk.contact
        self.n_frames = trunk.frames.count
        self.keys = np.zeros((0, 3), int)        # contacts with a positive multiplier
        self.multipliers = np.zeros(0)
        self.reference = None                     # gaps of those contacts at the step's start
        self.springs = None                       # (G, k) of the last stiffened tangent
        self._cache = ((None, None), (None, None))    # the candidates of the last two states asked
        self._pressed = (None, None, None)
        assembler = trunk.assembler             # the cable pieces' terms by the frames they join
        self._pairs = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(assembler.pair_a, assembler.pair_b))}

    def at(self, state) -> ContactSet:
        """Every candidate contact at ``state`` (kept for the last two states asked: an iterate and
        its line search's trial)."""
        last, before = self._cache
        if last[0] is state:
            return last[1]
        if before[0] is state:
            self._cache = (before, last)
            return before[1]
        self._cache = ((state, evaluate(self.model, state)), last)
        return self._cache[0][1]

    def contacts(self, state, keys: np.ndarray) -> ContactSet:
        """The contacts ``keys`` at ``state``, in their order: taken from the candidates
        (:meth:`at`, which the iterate's step or convergence test needs anyway) when they are all
        among them, else evaluated (a contact whose gap left the margin, a chord's point at its end)."""
        found = self.at(state)
        if keys.shape[0] <= found.count:
            index = {tuple(k): i for i, k in enumerate(found.key.tolist())}
            take = [index.get(tuple(k), -1) for k in keys.tolist()]
            if min(take, default=0) >= 0 and np.all(np.isfinite(found.gap[take])):
                return found.take(np.array(take, int))
        return evaluate(self.model, state, keys)

    def pressed(self, state) -> ContactSet:
        """The contacts carrying the current multipliers, at ``state`` (kept for the last state
        and multipliers asked)."""
        if self._pressed[0] is not state or self._pressed[1] is not self.keys:
            self._pressed = (state, self.keys, self.contacts(state, self.keys))
        return self._pressed[2]

    def balance(self, gradient: np.ndarray, state) -> np.ndarray:
        """The Lagrangian's gradient ``∇E − Gᵀλ`` (n_frames, 6) at ``state``."""
        if not self.multipliers.size:
            return gradient
        return gradient - self.pressed(state).forces(self.multipliers, self.n_frames)

    def step(self, factor, r: np.ndarray, state) -> Step | None:
        """The sequential-QP step (module docstring) with the factor of the shifted tangent ``K``;
        None when the complementarity problem has no solution the pivoting finds."""
        contacts = self.at(state)
        p = factor.solve(r)
        if not contacts.count:
            return Step(p, np.zeros(0), contacts, r)
        G = contacts.jacobian(self.n_frames)
        Z = factor.solve(np.asfortranarray(G.T))                  # K⁻¹Gᵀ: one solve per contact
        W = G @ Z
        b = contacts.gap + G @ p
        regularised = W.copy()
        regularised.flat[::W.shape[0] + 1] += REGULARISATION * max(float(np.abs(np.diag(W)).max()), 1e-300)
        # from the contacts pressed now (the last step's, mostly the answer again)
        pressed = {tuple(k) for k in self.keys.tolist()}
        start = (np.array([tuple(k) in pressed for k in contacts.key.tolist()], bool) if pressed else None)
        lam = complementarity(regularised, b, start)
        if lam is None:
            return None
        active = np.flatnonzero(lam > 0.0)
        if active.size:
            # the pressed contacts' gaps closed exactly (the regularisation only picks the set)
            exact = np.linalg.lstsq(W[np.ix_(active, active)], -b[active], rcond=1e-13)[0]
            if np.all(exact > 0.0):
                lam[active] = exact
        return Step(p + Z @ lam, lam, contacts, r + G.T @ lam)

    def accept(self, step: Step) -> None:
        """Take a step's multipliers as the current ones (only the pressed contacts are kept)."""
        pressed = step.multipliers > 0.0
        self.keys = step.contacts.key[pressed]
        self.multipliers = step.multipliers[pressed]
        self.reference = step.contacts.gap[pressed]

    def current(self) -> tuple:
        """The current multipliers (keys, values), to return to them (:meth:`resume`)."""
        return self.keys, self.multipliers

    def resume(self, current: tuple, state) -> None:
        """Take the multipliers ``current`` (:meth:`current`) again for a step from ``state`` that no
        complementarity problem gave (a negative-curvature step, which keeps the pressed contacts)."""
        self.keys, self.multipliers = current
        self.reference = self.pressed(state).gap

    def reestimate(self, gradient: np.ndarray, state, weights: np.ndarray) -> None:
        """Replace the multipliers by the forces ``λ ≥ 0`` of the pressed contacts that balance
        ``∇E`` at ``state`` best, ``min ‖w(∇E − Gᵀλ)‖`` (``weights``: 1 for forces, 1/L for
        moments) — the least-squares multipliers of sequential QP: at an equilibrium they are the
        step's, away from it they keep an overshooting step's forces out of the next tangent."""
        if not self.multipliers.size:
            return
        from scipy.optimize import nnls

        found = self.pressed(state)
        rows = found.rows
        G = np.zeros((self.multipliers.size, self.n_frames, 6))
        for side in range(2):
            frame = found.frames[:, side]
            used = frame > 0
            np.add.at(G, (np.flatnonzero(used), frame[used]), rows[used, side])
        A = (G[:, 1:] * weights).reshape(self.multipliers.size, -1).T
        b = (gradient[1:] * weights).reshape(-1)
        lam, _ = nnls(A, b)
        kept = lam > 0.0
        self.keys, self.multipliers = self.keys[kept], lam[kept]
        if self.reference is not None:
            self.reference = self.reference[kept]

    def work(self, trial) -> float:
        """``λᵀ(g(trial) − g(start))``: the Lagrangian's change beyond the potential's."""
        if not self.multipliers.size:
            return 0.0
        return float(self.multipliers @ (self.pressed(trial).gap - self.reference))

    def feasible(self, state) -> bool:
        """No contact penetrates beyond the tolerance and every pressed contact is closed."""
        tolerance = GAP_TOLERANCE * self.model.length
        contacts = self.at(state)
        if contacts.count and float(contacts.gap.min()) < -tolerance:
            return False
        if self.multipliers.size:
            gaps = self.pressed(state).gap
            if float(np.abs(gaps).max()) > ACTIVE_GAP * self.model.length:
                return False
        return True

    def lagrangian(self, matrix, state):
        """The tangent of the Lagrangian ``E − λᵀg``: ``matrix`` plus ``−Σ λ_i ∂²g_i`` of the
        pressed contacts (:func:`curvature`), added to the band's terms of the link or the cable
        pieces that join its frames; a contact between frames that neither joins (discs of a
        trunk folded onto itself) puts its coupling beside the band (:func:`_split_coupling`)."""
        if not self.multipliers.size:
            return matrix
        frames, blocks = curvature(self.model, self.pressed(state), self.multipliers, state)
        terms = matrix.terms.copy()
        links = matrix.assembler.views(terms)[0]
        a, b = frames[:, 0], frames[:, 1]
        lower = np.where(b >= 0, np.minimum(a, b), a)
        upper = np.where(b >= 0, np.maximum(a, b), -1)
        swap = np.flatnonzero((b >= 0) & (b < a))
        if swap.size:
            blocks[swap] = blocks[swap][:, _SWAP][:, :, _SWAP]
        joined = upper == lower + 1
        if joined.any():
            np.add.at(links, lower[joined], blocks[joined])
        single = (upper < 0) & (lower > 0)
        if single.any():
            np.add.at(links, (lower[single] - 1, slice(6, 12), slice(6, 12)), blocks[single, :6, :6])
        # frames a repetition apart: the slot of the cable pieces that join them, where a cable does
        apart = (upper >= 0) & ~joined
        if not apart.any():
            return type(matrix)(matrix.assembler, terms, matrix.low_rank)
        slot = np.array([self._pairs.get((a, b), -1) for a, b in zip(lower.tolist(), upper.tolist())], int)
        cabled = apart & (slot >= 0)
        if cabled.any():
            np.add.at(matrix.assembler.views(terms)[1], slot[cabled], blocks[cabled])
        apart &= ~cabled
        low_rank = matrix.low_rank
        both = apart & (lower > 0)
        if both.any():
            first, _ = pair_discs(self.model, self.keys[both])
            diagonal, U = _split_coupling(blocks[both], self.model.disc_radius[first])
            blocks = blocks.copy()
            blocks[both] = diagonal
            columns = np.zeros((self.n_frames, 6, U.shape[0], 6))       # frame, dof, contact, column
            contact_index = np.arange(U.shape[0])
            columns[lower[both], :, contact_index] = U[:, :6]
            columns[upper[both], :, contact_index] = U[:, 6:]
            U = columns[1:].reshape(6 * (self.n_frames - 1), -1)
            low_rank = ((U, np.ones(U.shape[1])) if low_rank is None
                        else (np.hstack([low_rank[0], U]), np.concatenate([low_rank[1], np.ones(U.shape[1])])))
        np.add.at(links, (lower[both] - 1, slice(6, 12), slice(6, 12)), blocks[both, :6, :6])
        np.add.at(links, (upper[apart] - 1, slice(6, 12), slice(6, 12)), blocks[apart, 6:, 6:])
        return type(matrix)(matrix.assembler, terms, low_rank)

    def released(self, step: "Step") -> bool:
        """Does ``step`` leave open (no force) a contact that the last springs hold?"""
        if self.springs is None:
            return False
        held = {tuple(k) for k in self.springs[2].tolist()}
        kept = self.held(None, step)
        return bool(held - ({tuple(k) for k in kept.key.tolist()} if kept is not None else set()))

    def held(self, state, step: "Step | None" = None) -> "ContactSet | None":
        """The contacts that hold the trunk (springs along them judge stability): the pressed ones
        at ``state``, or those ``step`` keeps pressed; None when there are none."""
        if step is None:
            return self.pressed(state) if self.multipliers.size else None
        keep = step.multipliers > 0.0
        return step.contacts.select(step.contacts.key[keep]) if keep.any() else None

    def report(self, state) -> tuple:
        """Every candidate contact of ``state`` with its force (:func:`report`)."""
        return report(self.model, state, self.keys, self.multipliers, found=self.at(state))

    def stiffened(self, matrix, state, stiffness: float = STABILITY_SPRING, step: "Step | None" = None):
        """The tangent plus a stiff spring along each pressed contact (``stiffness`` × the
        stiffness of the tangent's diagonal along the contact's direction; with ``step``, along the
        contacts it keeps pressed): positive definite exactly when the tangent is on the directions
        the contacts leave free (the constrained equilibrium's stability), up to the spring's
        finiteness. Kept as the last springs (:meth:`released`)."""
        self.springs = None
        held = self.held(state, step)
        if held is None:
            return matrix
        G = held.jacobian(self.n_frames)
        moving = np.add.reduce(G * G, 1) > 0.0         # (a contact on clamped frames only holds nothing)
        G, key = G[moving], held.key[moving]
        if not G.shape[0]:
            return matrix
        squared = np.add.reduce(G * G, 1)
        # the tangent's stiffness along each contact's direction, from its diagonal
        along = (G * G) @ np.abs(matrix.diagonal()) / squared
        spring = stiffness * along / squared
        self.springs = (G, spring, key)
        U, d = (G.T, spring) if matrix.low_rank is None else (np.hstack([matrix.low_rank[0], G.T]),
                                                              np.concatenate([matrix.low_rank[1], spring]))
        return type(matrix)(matrix.assembler, matrix.terms, (U, d))


def _split_coupling(blocks: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``blocks`` (k, 12, 12) on two frames ``[a; b]`` that no band term joins, as diagonal blocks
    (k, 12, 12; zero coupling) plus a positive semi-definite term ``U Uᵀ`` (``U`` (k, 12, 6)) that
    holds the coupling: with ``C`` the (symmetrised) coupling and a positive diagonal ``D``,
    ``[[A, C], [Cᵀ, B]] = [[A − D, 0], [0, B − Cᵀ D⁻¹ C]] + [D^½; Cᵀ D^-½][D^½; Cᵀ D^-½]ᵀ``.
    ``D`` is ``s`` on the turns and ``s/ℓ²`` on the moves (``length`` ℓ (k,): the moves' scale, a
    disc's radius; ``s`` the coupling's norm in those units), which takes as much from each
    frame's block as from the other's."""
    C = 0.5 * (blocks[:, :6, 6:] + np.swapaxes(blocks[:, 6:, :6], 1, 2))
    scale = np.ones((blocks.shape[0], 6))
    scale[:, :3] = length[:, None]
    s = np.linalg.norm(scale[:, :, None] * C * scale[:, None, :], ord=2, axis=(1, 2))
    D = np.maximum(s, 1e-300)[:, None] / (scale * scale)                    # (k, 6)
    U = np.zeros((blocks.shape[0], 12, 6))
    U[:, :6] = np.sqrt(D)[:, :, None] * np.eye(6)
    U[:, 6:] = np.swapaxes(C, 1, 2) / np.sqrt(D)[:, None, :]
    diagonal = np.zeros_like(blocks)
    diagonal[:, :6, :6] = blocks[:, :6, :6] - D[:, :, None] * np.eye(6)
    diagonal[:, 6:, 6:] = blocks[:, 6:, 6:] - np.swapaxes(C, 1, 2) @ (C / D[:, :, None])
    return diagonal, U


def _hat(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _surface_curvature(obstacle, point: np.ndarray, scale: float) -> np.ndarray:
    """The Hessian of the obstacle's signed distance at ``point`` (k, 3, 3): the derivative of
    its normal — zero for planes, closed form by the nearest feature for boxes and meshes
    (:meth:`~vertebra.solver.obstacles.Polyhedron.curvature`), else by central differences."""
    if isinstance(obstacle, Plane):
        return np.zeros((point.shape[0], 3, 3))
    polyhedron = getattr(obstacle, "polyhedron", None)
    if polyhedron is not None:          # a box, a mesh: closed form by the nearest feature
        return polyhedron.curvature(point, *obstacle.closest(point))
    h = 1e-6 * scale
    shifted = point[:, None, :] + h * np.eye(3)[None]
    plus = obstacle.closest(shifted.reshape(-1, 3))[1].reshape(-1, 3, 3)
    minus = obstacle.closest((point[:, None, :] - h * np.eye(3)[None]).reshape(-1, 3))[1].reshape(-1, 3, 3)
    S = np.swapaxes(plus - minus, 1, 2) / (2.0 * h)              # S[:, i, k] = ∂n_i/∂p_k
    return 0.5 * (S + np.swapaxes(S, 1, 2))


def _rotation(axis: int, angle: float) -> np.ndarray:
    """The rotation by ``angle`` about the world axis ``axis``."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.eye(3)
    out[i, i] = out[j, j] = c
    out[j, i], out[i, j] = s, -s
    return out


def pair_discs(model: ContactModel, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two discs (first, second) of disc–disc contacts ``key`` (m, 3): an adjacent pair's
    feature is its index in ``model.pair``, another's ``first · discs + second``."""
    feature = key[:, 1]
    first, second = np.divmod(feature, max(model.disc_frame.size, 1))
    adjacent = key[:, 0] == PAIR
    if adjacent.any():
        first[adjacent], second[adjacent] = model.pair[feature[adjacent]].T
    return first, second


def _pair_curvature(model: ContactModel, state, key: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``−λ ∂²g`` (k, 12, 12) of disc–disc contacts on their frames ``[a; b]``: central differences
    of the gap's rows (the contact force's generalised force, its nearest points found again at
    each moved pose: the sliding of the points along the rims is in it) under moves of each frame
    along the world axes (``DIFFERENCE`` × the disc radius) and turns about them (``DIFFERENCE`` rad).
    Face points (:func:`_face_points`) are held on their rims. The pucks' nearest point is held
    where the differences make it jump (:data:`JUMP`: to the other rim, or along its rim by more
    than ``JUMP`` rad for a step of ``DIFFERENCE``): faces within about ``DIFFERENCE / JUMP`` rad of
    parallel, where it crosses the rims with the faces' tilt — a difference across that jump is no
    curvature, and the sliding it would add holds only for steps shorter than the tilt. Elsewhere
    (discs tilted against each other, folded over or not) it slides smoothly and its sliding is
    the gap's curvature: holding it there (as the code before did for every pair folded over with
    faces within ``2R sin θ < t₁ + t₂`` of parallel) left the tangent wrong by the sliding term
    and random robot 46 crawling (docs/contact.md)."""
    first, second = pair_discs(model, key)
    fa, fb = model.disc_frame[first], model.disc_frame[second]
    ha, hb = 0.5 * model.disc_thickness[first], 0.5 * model.disc_thickness[second]
    ra, rb = model.disc_radius[first] - ha, model.disc_radius[second] - hb
    x, R = state.positions, qmatrix(state.quaternions)
    k = key.shape[0]
    point = -2 - key[:, 2]
    on_second, angle = _face_point(np.maximum(point, 0))
    fixed = point >= 0
    moved = [np.repeat(v[None], 24, 0) for v in (x[fa], R[fa], x[fb], R[fb])]
    step = np.empty((12, k))
    for c in range(12):
        body, what = divmod(c, 6)
        for sign, row in ((1.0, 2 * c), (-1.0, 2 * c + 1)):
            if what < 3:
                h = DIFFERENCE * model.disc_radius[first if body == 0 else second]
                moved[2 * body][row, :, what] += sign * h
            else:
                h = np.full(k, DIFFERENCE)
                moved[2 * body + 1][row] = _rotation(what - 3, sign * DIFFERENCE) @ moved[2 * body + 1][row]
        step[c] = h
    flat = [v.reshape((24 * k,) + v.shape[2:]) for v in moved]
    tiled = (np.tile(ra, 24), np.tile(ha, 24), np.tile(rb, 24), np.tile(hb, 24))
    rows = np.empty((24 * k, 2, 6))
    free = np.tile(~fixed, 24)
    if free.any():
        # the pucks' gap with its nearest points found again at each moved pose, and where they lie
        # on their bodies (a tie between the rims — rim on rim — moves neither point)
        f = [v[free] for v in flat]
        r_a, h_a, r_b, h_b = (v[free] for v in tiled)
        *found, (p, q) = _puck_gap(f[0], f[1], r_a, h_a, f[2], f[3], r_b, h_b, where=True)
        rows[free] = found[3]
        *_, (p0, q0) = _puck_gap(x[fa], R[fa], ra, ha, x[fb], R[fb], rb, hb, where=True)
        body = np.zeros((24 * k, 2, 3))
        body[free, 0] = np.einsum("kji,kj->ki", f[1], p - f[0])
        body[free, 1] = np.einsum("kji,kj->ki", f[3], q - f[2])
        at = np.stack([np.einsum("kji,kj->ki", R[fa], p0 - x[fa]), np.einsum("kji,kj->ki", R[fb], q0 - x[fb])], 1)
        slid = np.sqrt(np.add.reduce((body.reshape(24, k, 2, 3) - at) ** 2, -1)).max(axis=(0, 2))
        jumped = ~fixed & (slid > JUMP * np.maximum(ra, rb))
        if jumped.any():
            # held where it jumps: at the pose's own nearest point
            on_second[jumped], angle[jumped] = _nearest_rim_point(x[fa[jumped]], R[fa[jumped]], ra[jumped],
                                                                  x[fb[jumped]], R[fb[jumped]], rb[jumped])
            fixed = fixed | jumped
    hold = np.tile(fixed, 24)
    if hold.any():
        rows[hold] = _rim_point_gap(*(v[hold] for v in (flat[0], flat[1], tiled[0], tiled[1], flat[2], flat[3],
                                                         tiled[2], tiled[3])), np.tile(on_second, 24)[hold],
                                    np.tile(angle, 24)[hold])[3]
    rows = rows.reshape(12, 2, k, 12)
    derivative = (rows[:, 0] - rows[:, 1]) / (2.0 * step[:, :, None])              # (12 moves, k, 12 rows)
    return -lam[:, None, None] * np.transpose(derivative, (1, 2, 0))


def curvature(model: ContactModel, contacts: ContactSet, multipliers: np.ndarray, state=None):
    """``−λ_i ∂²g_i`` of each contact as a 12×12 block on its frames ``[a; b]`` (the derivative of
    the contact forces' generalised forces: the turning of the lever arms, the turning of a disc's
    face normal, the obstacle's surface curvature and the sliding of a closest point along a rim
    or chord; a disc's face on a box or convex mesh: its pairing's closed form, disc pairs: central
    differences). ``state``: the contacts' state. Returns (frames (k, 2), blocks (k, 12, 12))."""
    key, frames = contacts.key, contacts.frames
    lam = multipliers[:, None, None]
    n = contacts.normal
    # the point carrying the force (a ball's centre, a chord's axis point, a rim point)
    radius = np.zeros(key.shape[0])
    ball = key[:, 0] == BALL
    radius[ball] = model.ball_radius[key[ball, 1]]
    chord = key[:, 0] == CHORD
    radius[chord] = model.chord_radius[key[chord, 1]]
    point = contacts.point + radius[:, None] * n
    pair = (key[:, 0] == PAIR) | (key[:, 0] == FOLD)
    S = np.zeros((key.shape[0], 3, 3))
    surface = ~pair & (key[:, 0] < TANGENTIAL)       # (a tangential row's directions are held: no curvature)
    featured = np.zeros(key.shape[0], bool)          # disc faces on convex polyhedra: their own closed form
    for j in np.unique(key[surface, 2]):
        chosen = surface & (key[:, 2] == j)
        if _disk_gap(model.obstacles[j]) is not None:
            featured |= chosen & (key[:, 0] == RIM)
            chosen &= key[:, 0] != RIM
        if chosen.any():
            S[chosen] = _surface_curvature(model.obstacles[j], point[chosen], model.length)
    blocks = _blocks(contacts, lam, S, point, n, pair, chord)
    for j in np.unique(key[featured, 2]):
        chosen = np.flatnonzero(featured & (key[:, 2] == j))
        blocks[chosen, :6, :6] = -multipliers[chosen, None, None] * _polyhedron_rims(
            model, state, key[chosen, 1], model.obstacles[j])
    if pair.any():
        blocks[pair] = _pair_curvature(model, state, key[pair], multipliers[pair])
    return frames, blocks


def _blocks(contacts, lam, S, point, n, pair, chord):
    key = contacts.key
    blocks = np.zeros((key.shape[0], 12, 12))
    origin = contacts.origin
    lam = lam[:, 0, 0]
    obstacle = np.flatnonzero(~pair & ~chord)          # a point on one frame (a rim point, a ball)
    l = point[obstacle] - origin[obstacle, 0]
    So, lo = S[obstacle], lam[obstacle, None, None]
    curved = So.any()                                   # (a plane's S is zero: its terms vanish)
    hat_l, hat_n = _hat(l), _hat(n[obstacle])
    # −λ∂²g for a point on frame a: [[−λS, λS l̂], [−λ l̂ S, −λ n̂ l̂ + λ l̂ S l̂]]
    if curved:
        blocks[obstacle, :3, :3] = -lo * So
        blocks[obstacle, :3, 3:6] = lo * So @ hat_l
        blocks[obstacle, 3:6, :3] = -lo * hat_l @ So
        blocks[obstacle, 3:6, 3:6] = lo * (-hat_n @ hat_l + hat_l @ So @ hat_l)
    else:
        blocks[obstacle, 3:6, 3:6] = lo * (-hat_n @ hat_l)
    # a chord's axis point (1 − t) x_a + t x_b
    chords = np.flatnonzero(chord)
    if chords.size:
        t = np.add.reduce(contacts.rows[chords, 1, :3] * n[chords], -1)
        weights = np.stack([1.0 - t, t], 1)
        for i in range(2):
            for k in range(2):
                blocks[chords, 6 * i:6 * i + 3, 6 * k:6 * k + 3] = -(lam[chords, None, None] * S[chords]
                                                                    * (weights[:, i] * weights[:, k])[:, None, None])
    # (disc pairs: :func:`_pair_curvature`, by differences)
    # the closest point sliding along its rim or chord: g = min_s f(s, q) adds −f_qs f_sqᵀ / f_ss
    # to ∂²g, so −λ∂²g gains λ v vᵀ / f_ss with v = ∂f_s/∂q (a ball's point does not slide: τ = 0)
    tau, second = contacts.slide[:, 0], contacts.slide[:, 1]
    length = np.sqrt(np.add.reduce(tau * tau, -1))
    moving = np.flatnonzero(length > 0.0)
    if not moving.size:
        return blocks
    tau, second, Sm, nm = tau[moving], second[moving], S[moving], n[moving]
    S_tau = np.einsum("kij,kj->ki", Sm, tau)
    f_ss = np.add.reduce(tau * S_tau, -1) + np.add.reduce(nm * second, -1)
    v = np.zeros((moving.size, 12))
    rim = np.isin(moving, obstacle)
    if rim.any():
        v[rim, :3] = S_tau[rim]
        v[rim, 3:6] = _cross(point[moving[rim]] - origin[moving[rim], 0], S_tau[rim]) + _cross(tau[rim], nm[rim])
    along = chord[moving]
    if along.any():
        t = np.add.reduce(contacts.rows[moving[along], 1, :3] * nm[along], -1)[:, None]
        v[along, :3] = (1.0 - t) * S_tau[along] - nm[along]
        v[along, 6:9] = t * S_tau[along] + nm[along]
    sliding = f_ss > 1e-12 * length[moving] * (np.abs(Sm).max(axis=(1, 2)) * length[moving] + np.sqrt(
        np.add.reduce(second * second, -1)) + 1e-300)
    scale = np.where(sliding, lam[moving] / np.where(sliding, f_ss, 1.0), 0.0)
    blocks[moving] += scale[:, None, None] * v[:, :, None] * v[:, None, :]
    return blocks


@dataclass(frozen=True)
class Contact:
    """One contact of a solved state (the JSON's ``contacts``)."""

    bodies: tuple
    point: tuple          # on the body, world (m)
    normal: tuple         # unit, pushing the body away
    gap: float            # m (≥ 0 up to the solve's tolerance)
    force: float          # N (≥ 0)
    friction: tuple | None = None     # at an obstacle with friction: the tangential force on the body (N, world)
    sliding: str | None = None        # … and "stick", "slip" or "open" (None: a frictionless contact)

    def as_dict(self) -> dict:
        out = {"bodies": list(self.bodies), "point": list(self.point), "normal": list(self.normal),
               "gap": self.gap, "force": self.force}
        if self.sliding is not None:
            out.update(friction=list(self.friction), sliding=self.sliding)
        return out


def report(model: ContactModel, state, keys: np.ndarray, multipliers: np.ndarray, tangential=None,
           found: ContactSet | None = None) -> tuple:
    """Every candidate contact of ``state`` with its force (the pressed ones first); ``tangential``
    (a function of the contacts' keys, or None) gives each one's friction fields; ``found``: the
    candidates at ``state`` when they are known (:func:`evaluate`)."""
    if found is None:
        found = evaluate(model, state)
    force = np.zeros(found.count)
    index = {tuple(k): i for i, k in enumerate(found.key.tolist())}
    extra = []
    for k, lam in zip(keys.tolist(), multipliers.tolist()):
        if tuple(k) in index:
            force[index[tuple(k)]] = lam
        else:
            extra.append((k, lam))
    if extra:
        more = evaluate(model, state, np.array([k for k, _ in extra]))
        found = ContactSet(*(np.concatenate([a, b]) for a, b in zip(
            (found.key, found.gap, found.point, found.normal, found.frames, found.rows, found.origin, found.slide),
            (more.key, more.gap, more.point, more.normal, more.frames, more.rows, more.origin, more.slide))))
        force = np.concatenate([force, [lam for _, lam in extra]])
    order = np.lexsort((found.gap, -force))
    fields = tangential(found.key[order]) if tangential is not None else [{}] * order.size
    return tuple(Contact(bodies(model, key), tuple(point), tuple(normal), gap, lam, **more)
                 for key, point, normal, gap, lam, more in zip(found.key[order].tolist(), found.point[order].tolist(),
                                                               found.normal[order].tolist(), found.gap[order].tolist(),
                                                               force[order].tolist(), fields))
