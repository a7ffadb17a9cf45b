"""A disc's face against a convex polyhedron (a box, a convex triangle mesh) by its features
(docs/contact.md, "Sharp features").

A disc meets obstacles through the flat disks of its two faces (centre ``c``, unit axis ``a``,
radius ``ρ``). Against a convex polyhedron ``B`` the gap of such a disk ``D`` is their signed
distance — the distance apart, or less the depth they overlap — which the separating-axis theorem
gives as the largest separation along any unit direction ``n``:

    ``g = max_n φ(n),   φ(n) = min_{y∈D} n·y − max_{b∈B} n·b = n·c − ρ|n − (n·a)a| − max_v n·v``

(``v`` the vertices). ``φ`` is smooth except where a support is not unique, so its maximum is
at one of the features' pairings, each the stationary point of a smooth function:

* **face** ``f`` of ``B`` against the rim: ``n`` = the face's normal, the rim point lowest along it;
* **edge** (line ``o + w u``) against the rim: the rim point and the line's point nearest each other
  (``(p − e) ⊥ u``, ``(p − e) ⊥ τ``, ``τ`` the rim's tangent), ``n = ±τ × u/|τ × u|`` (the side
  that makes ``p`` the disk's lowest point along ``n``) — signed through zero: a rim crossing an edge
  has a negative gap that is as smooth as a positive one;
* **vertex** ``v`` against the rim: the nearest rim point, ``n = ±(p − v)/|p − v|``;
* **axis**: ``n = ±a``, the disk's face against the polyhedron's vertex farthest along it (a corner
  or an edge under the flat face).

Each candidate's value is ``φ`` at its direction, a lower bound of ``g`` whatever the pose; the
largest is ``g`` (the true direction is among them). The gap's derivative is the winner's
``[n, (p − x) × n]`` on the disc's frame (``p`` on the disk, envelope theorem), and its second
derivative is the winner's in closed form: how ``n`` and the contact point move as the frame moves
and turns, the point sliding along the rim by the pairing's stationarity (:func:`disk_polyhedron`).
A rim on an edge has a gap with a 1/distance normal when read as a point's distance to the
polyhedron; as the pairing of a circle and a line it has none.
"""

from __future__ import annotations

import math

import numpy as np

FACE, EDGE, VERTEX, AXIS, POINT = 0, 1, 2, 3, 4   # the pairing that gives a disk's gap (POINT: disk_mesh)
SAMPLES = 16                                    # starting samples of a rim's angle against a line …
BISECTIONS = 52                                 # … then bisection to the rounding of the angle


def _cross(a, b):
    """Row-wise cross products of (…, 3) arrays (np.cross costs more on small stacks); contact.py's too."""
    a, b = np.broadcast_arrays(a, b)
    out = np.empty(a.shape)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _dot(a, b):
    return np.add.reduce(a * b, -1)


def _hat(v):
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _separation(n, c, a, rho, vertices):
    """``φ(n)`` (k, m) for directions ``n`` (k, m, 3) of disks ``c``, ``a``, ``rho`` (k, …)."""
    inplane = n - _dot(n, a[:, None])[..., None] * a[:, None]
    return (_dot(n, c[:, None]) - rho[:, None] * np.sqrt(_dot(inplane, inplane))
            - np.max(n @ vertices.T, -1))


def _rim_line(c, a, e1, e2, rho, o, u, both: bool = False):
    """The rim angle ``s`` (k, e) nearest each line ``o + w u`` (e, 3, or (k, e, 3) per disk): 16
    samples, then bisection on the derivative of the squared distance (``r⊥·τ``) to the rounding
    of the angle. With ``both``, the two local minima (k, e, 2) and whether the second is one (a
    line through the disk has one on either side of its crossing: the rim crossing the line
    there, or nearest it, on the segment or not)."""
    if o.ndim == 2:
        o, u = o[None], u[None]

    def at(s):
        cs, sn = np.cos(s)[..., None], np.sin(s)[..., None]
        radial = cs * e1[:, None] + sn * e2[:, None]
        r = c[:, None] + rho[:, None, None] * radial - o
        perp = r - _dot(r, u)[..., None] * u
        return perp, rho[:, None, None] * (cs * e2[:, None] - sn * e1[:, None])

    k, e = c.shape[0], o.shape[-2]
    samples = 2.0 * math.pi * np.arange(SAMPLES) / SAMPLES
    d2 = np.stack([_dot(*(at(np.full((k, e), s))[0],) * 2) for s in samples], -1)          # (k, e, SAMPLES)
    # the squared distance along the rim is a trigonometric polynomial of degree 2: at most two
    # local minima; each of the two best sampled ones is bisected and the nearer kept
    low_here = (d2 <= np.roll(d2, 1, -1)) & (d2 <= np.roll(d2, -1, -1))
    ranked = np.argsort(np.where(low_here, d2, np.inf), -1)[..., :2]
    starts = samples[ranked]                                                                 # (k, e, 2)
    width = 2.0 * math.pi / SAMPLES
    found = []
    for j in range(2):
        low, high = starts[..., j] - width, starts[..., j] + width
        for _ in range(BISECTIONS):
            middle = 0.5 * (low + high)
            perp, tau = at(middle)
            falling = _dot(perp, tau) < 0.0
            low, high = np.where(falling, middle, low), np.where(falling, high, middle)
        found.append(0.5 * (low + high))
    if both:
        second = np.isfinite(np.take_along_axis(np.where(low_here, d2, np.inf), ranked[..., 1:], -1)[..., 0])
        return np.stack(found, -1), second
    near = [_dot(*(at(s)[0],) * 2) for s in found]
    return np.where(near[1] < near[0], found[1], found[0])


def _crossing(tau, u, apart):
    """Whether a rim–line pairing's direction is taken as ``τ × u`` (the rim crossing the line at
    an angle: defined through contact) rather than as ``p − e`` (the rim parallel to the line where
    they are nearest, as a disc bending over an edge across its bending plane: defined while apart):
    the longer of the two (``|τ × u| = ρ sin θ`` against ``|p − e|``); where both are defined they
    are the same direction."""
    N = _cross(tau, u)
    return _dot(N, N) >= _dot(apart, apart)


def disk_polyhedron(poly, x, c, a, e1, e2, rho, second: bool = False):
    """The gap of each disk (centre ``c``, unit axis ``a``, in-plane axes ``e1``, ``e2``, radius
    ``rho``; (k, …)) on a frame at ``x`` against the convex polyhedron ``poly``: (gap (k,), point on
    the disk (k, 3), unit normal pushing the disk away (k, 3), pairing (k,)); with ``second``, also
    ``M`` (k, 6, 6): the derivative of the gap's row ``[n, (p − x) × n]`` under a move ``δx`` and a
    turn ``δφ`` (world axes) of the frame."""
    k = c.shape[0]
    V = poly.vertices
    # candidate directions: faces, the axis both ways, vertices, edges
    faces = np.broadcast_to(poly.face_normal, (k,) + poly.face_normal.shape)
    f = faces.shape[1]
    axes = np.stack([a, -a], 1)
    w = V[None] - c[:, None]                                                    # (k, v, 3)
    w_in = w - _dot(w, a[:, None])[..., None] * a[:, None]
    rho_v = np.sqrt(_dot(w_in, w_in))
    radial = np.where((rho_v > 0.0)[..., None], w_in / np.maximum(rho_v, 1e-300)[..., None], e1[:, None])
    p_vertex = c[:, None] + rho[:, None, None] * radial
    d_vertex = p_vertex - V[None]
    length = np.sqrt(_dot(d_vertex, d_vertex))
    sign = np.where(rho_v > rho[:, None], 1.0, -1.0)
    n_vertex = np.where((length > 1e-12 * poly.size)[..., None],
                        sign[..., None] * d_vertex / np.maximum(length, 1e-300)[..., None], a[:, None])
    o, b = V[poly.edges[:, 0]], V[poly.edges[:, 1]]
    u = (b - o) / np.sqrt(_dot(b - o, b - o))[:, None]
    s = _rim_line(c, a, e1, e2, rho, o, u)
    radial_e = np.cos(s)[..., None] * e1[:, None] + np.sin(s)[..., None] * e2[:, None]
    tau_e = rho[:, None, None] * _cross(a[:, None], radial_e)
    apart = c[:, None] + rho[:, None, None] * radial_e - o[None]
    apart -= _dot(apart, u[None])[..., None] * u[None]                          # p − e, ⊥ the line
    m = np.where(_crossing(tau_e, u[None], apart)[..., None], _cross(tau_e, u[None]), apart)
    norm_m = np.sqrt(_dot(m, m))
    m = m / np.maximum(norm_m, 1e-300)[..., None]
    m = np.where((_dot(m, radial_e) < 0.0)[..., None], m, -m)                  # the rim point lowest along m
    m = np.where((norm_m > 0.0)[..., None], m, a[:, None])
    directions = np.concatenate([faces, axes, n_vertex, m], 1)
    phi = _separation(directions, c, a, rho, V)
    # a vertex's or an edge's pairing is the stationary point it stands for only where that
    # feature is the polyhedron's farthest along its direction (else its φ, a lower bound still,
    # is not the pairing's distance and its derivative not the pairing's)
    tol = 1e-9 * poly.size
    reach = np.max(directions @ V.T, -1)
    own = np.concatenate([_dot(n_vertex, V[None]), _dot(m, o[None])], 1)
    phi[:, f + 2:] = np.where(reach[:, f + 2:] - own <= tol, phi[:, f + 2:], -np.inf)
    best = np.argmax(phi, 1)
    rows = np.arange(k)
    n = directions[rows, best]
    gap = phi[rows, best]
    kind = np.select([best < f, best < f + 2, best < f + 2 + V.shape[0]], [FACE, AXIS, VERTEX], EDGE)
    # the contact point on the disk: its lowest point along n (the support vertex projected on the
    # disk where n is the axis)
    inplane = n - _dot(n, a)[:, None] * a
    norm_in = np.sqrt(_dot(inplane, inplane))
    axis = kind == AXIS
    support = V[np.argmax(n @ V.T, 1)]
    point = np.where(axis[:, None], support + gap[:, None] * n,
                     c - rho[:, None] * inplane / np.maximum(norm_in, 1e-300)[:, None])
    if not second:
        return gap, point, n, kind
    u_edge = np.zeros((k, 3))
    edge = kind == EDGE
    u_edge[edge] = u[best[edge] - (f + 2 + V.shape[0])]
    return gap, point, n, kind, _pairing_derivative(x, c, a, rho, gap, point, n, kind, u_edge, support)


def _pairing_derivative(x, c, a, rho, gap, point, n, kind, u_edge, support, curvature=None):
    """``M`` (k, 6, 6): the derivative of a disk's gap row ``[n, (p − x) × n]`` under a move ``δx``
    and a turn ``δφ`` (world axes) of its frame at ``x``, for the pairing ``kind`` that gives its gap
    (``u_edge``: an edge pairing's line direction; ``support``: an axis pairing's vertex;
    ``curvature``: the surface's Hessian (k, 3, 3) at a point held on the disk, pairing ``POINT``)."""
    k = c.shape[0]
    inplane = n - _dot(n, a)[:, None] * a
    norm_in = np.sqrt(_dot(inplane, inplane))
    axis = kind == AXIS
    l = point - x
    tau = _cross(a, point - c)                        # ∂p/∂s along the rim
    tau_s = c - point                                 # ∂τ/∂s
    Dx = np.zeros((k, 3, 6))
    Dx[:, :, :3] = np.eye(3)
    Dx[:, :, 3:] = -_hat(l)                           # the body point held: δx + δφ × l
    Dn = np.zeros((k, 3, 6))
    ds = np.zeros((k, 6))                             # the rim point's slide δs per move
    face = kind == FACE
    if face.any():
        # n fixed; the lowest point stays lowest: n·τ = 0
        f_ss = _dot(n[face], tau_s[face])
        ok = f_ss > 1e-9 * rho[face] * norm_in[face] * rho[face] + 1e-300
        ds[face, 3:] = np.where(ok[:, None], -_cross(tau[face], n[face]) / np.where(ok, f_ss, 1.0)[:, None], 0.0)
    edge = kind == EDGE
    if edge.any():
        ue, ne, te, ts, le, g = u_edge[edge], n[edge], tau[edge], tau_s[edge], l[edge], gap[edge]
        perp = te - _dot(te, ue)[:, None] * ue
        f_ss = _dot(perp, perp) + g * _dot(ne, ts)
        v = np.concatenate([perp, _cross(le, perp) + g[:, None] * _cross(te, ne)], 1)
        ds[edge] = -v / f_ss[:, None]
        # n = σ (τ × u)/|τ × u| with τ turning with the frame and sliding along the rim
        Dtau = np.zeros((edge.sum(), 3, 6))
        Dtau[:, :, 3:] = -_hat(te)
        Dtau += ts[:, :, None] * ds[edge][:, None, :]
        project = np.eye(3) - ne[:, :, None] * ne[:, None, :]
        Ne = _cross(te, ue)
        crossing = _crossing(te, ue, g[:, None] * ne)
        sigma = np.where(crossing, np.sign(_dot(Ne, ne)) / np.maximum(np.sqrt(_dot(Ne, Ne)), 1e-300), 0.0)
        Dn_edge = sigma[:, None, None] * project @ (-_hat(ue) @ Dtau)              # σ(I − nnᵀ)(δτ × u)/|τ × u|
        # … or n = (p − e)/g, the line's point e following p along u
        Dp_edge = Dx[edge] + te[:, :, None] * ds[edge][:, None, :]
        along = project @ (Dp_edge - ue[:, :, None] * np.einsum("ki,kij->kj", ue, Dp_edge)[:, None, :])
        Dn[edge] = np.where(crossing[:, None, None], Dn_edge, along / np.where(crossing, 1.0, g)[:, None, None])
    vertex = kind == VERTEX
    if vertex.any():
        nv, te, ts, le, g = n[vertex], tau[vertex], tau_s[vertex], l[vertex], gap[vertex]
        f_ss = _dot(te, te) + g * _dot(nv, ts)
        ds[vertex] = -np.concatenate([te, _cross(le, te) + g[:, None] * _cross(te, nv)], 1) / f_ss[:, None]
    Dp = Dx + tau[:, :, None] * ds[:, None, :]
    held = kind == POINT
    if held.any():
        Dn[held] = curvature[held] @ Dx[held]                   # the normal at a point held on the disk
    if vertex.any():
        project = np.eye(3) - n[vertex][:, :, None] * n[vertex][:, None, :]
        Dn[vertex] = project @ Dp[vertex] / gap[vertex][:, None, None]
    if axis.any():
        # n = ±a turns with the frame; the force's line passes through the polyhedron's vertex
        Dn[axis, :, 3:] = -_hat(n[axis])
        Dp[axis] = 0.0
        l[axis] = support[axis] - x[axis]
    M = np.empty((k, 6, 6))
    M[:, :3] = Dn
    Dl = Dp.copy()
    Dl[:, :, :3] -= np.eye(3)
    M[:, 3:] = -_hat(n) @ Dl + _hat(l) @ Dn            # δ(l × n) = δl × n + l × δn
    return M


def segment_polyhedron(poly, closest, a, b, near=None):
    """The parameter ``t`` (k,) of the point of each segment ``a → b`` (k, 3) nearest the convex
    polyhedron ``poly`` (``closest``: its obstacle's :meth:`closest`), and that point's signed
    distance. Outside the polyhedron the distance along a line is smooth and convex, made of a
    face's (linear), an edge's or a vertex's pieces, so its least is at an end, at a vertex's
    projection on the segment or at the segment's point nearest an edge's line: each candidate's
    distance from one query, the least taken (exact where it is positive). A segment that passes
    through the polyhedron has its least inside, at none of these: its distance is −∞.
    ``near(a, b)``: the (segment, vertex) and (segment, edge) pairs that may hold the least (a
    mesh's broad phase: ``(segment, vertex index)``, ``(segment, edge's vertices (·, 2))``); default
    every vertex and edge of ``poly`` for every segment."""
    V = poly.vertices
    k = a.shape[0]
    if near is None:
        vc, vi = np.repeat(np.arange(k), V.shape[0]), np.tile(np.arange(V.shape[0]), k)
        ec, ev = np.repeat(np.arange(k), poly.edges.shape[0]), np.tile(poly.edges, (k, 1))
    else:
        (vc, vi), (ec, ev) = near(a, b)
    ab = b - a
    length2 = np.maximum(_dot(ab, ab), 1e-300)
    at_vertex = _dot(V[vi] - a[vc], ab[vc]) / length2[vc]
    o, u = V[ev[:, 0]], V[ev[:, 1]] - V[ev[:, 0]]
    u = u / np.sqrt(_dot(u, u))[:, None]
    r = a[ec] - o
    along = _dot(ab[ec], u)
    square = length2[ec] - along * along
    at_edge = np.where(square > 1e-12 * length2[ec], (along * _dot(r, u) - _dot(r, ab[ec])) / np.maximum(square, 1e-300), 0.0)
    chord = np.r_[np.arange(k), np.arange(k), vc, ec]
    t = np.clip(np.r_[np.zeros(k), np.ones(k), at_vertex, at_edge], 0.0, 1.0)
    distance = closest(a[chord] + t[:, None] * ab[chord])[0]
    best = _pick(distance, chord, k, largest=False)
    # a segment through the polyhedron (clipped by the faces' half-spaces): its least distance is
    # inside, where the candidates need not be — reported as −∞ (the caller searches)
    start = a @ poly.face_normal.T - poly.face_offset                                      # (k, f)
    end = b @ poly.face_normal.T - poly.face_offset
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = start / (start - end)
    enter = np.max(np.where((start > 0.0) & (end <= 0.0), crossing, np.where(start > 0.0, np.inf, 0.0)), 1)
    leave = np.min(np.where((start <= 0.0) & (end > 0.0), crossing, 1.0), 1)
    through = enter <= leave
    return t[best], np.where(through, -np.inf, distance[best])


def mesh_near_segments(mesh, a, b):
    """The (segment, vertex) and (segment, edge) pairs of the triangles that may hold a segment's
    least distance to the mesh (for :func:`segment_polyhedron`): within the least of the distances
    of its ends and middle, by the k-d tree of the triangles."""
    S = mesh.surface
    middle = 0.5 * (a + b)
    bound = np.min(np.abs(mesh.closest(np.concatenate([a, b, middle]))[0].reshape(3, -1)), 0)
    half = 0.5 * np.sqrt(_dot(b - a, b - a))
    segment, tri = mesh.near(middle, half + bound + 1e-9 * S.size)
    nv, ne = mesh.vertices.shape[0], S.edges.shape[0]
    vertices = np.unique((segment[:, None] * nv + mesh.triangles[tri]).reshape(-1))
    edges = np.unique((segment[:, None] * ne + S.triangle_edges[tri]).reshape(-1))
    vc, vi = np.divmod(vertices, nv)
    ec, ei = np.divmod(edges, ne)
    keep = ~S.flat_edge[ei]
    return (vc, vi), (ec[keep], S.edges[ei[keep]])


RIM_SAMPLES = 16                                # rim points (and the centre) that bound a disk's distance to a mesh


def _pick(value, group, groups, largest):
    """Per group (0..groups−1) the index of its largest (or least) finite ``value``, −1 where none."""
    best = np.full(groups, -1)
    finite = np.flatnonzero(np.isfinite(value))
    if finite.size:
        order = finite[np.lexsort((-value[finite] if largest else value[finite], group[finite]))]
        first = np.r_[True, group[order][1:] != group[order][:-1]]
        best[group[order][first]] = order[first]
    return best


def disk_mesh(mesh, x, c, a, e1, e2, rho, second: bool = False):
    """The gap of each disk (as :func:`disk_polyhedron`) against a triangle mesh, convex or not:
    the pairings of its face with the features of the triangles near it (a k-d tree: cost ~log of
    the triangles), each one's closed form as on a convex polyhedron.

    Apart, the gap is the disk's distance to the surface: the least over the pairings that stand
    for a pair of nearest points — a face's where the disk's lowest point along its normal lies
    over the triangle, an edge's where the line's point lies on the segment, and an edge's or a
    vertex's where its direction lies in the feature's normal cone (the surface on the inner side
    of the plane through the feature: ``n·(w − e) ≤ 0`` for the far corners and neighbours ``w``) and
    the disk's point is its lowest along it. Each such value is the distance between a point of
    the disk and a point of the surface, so none is below the gap, and the nearest pair is among
    them. A concave edge or vertex has no outward normal cone and never holds a gap.

    Across the surface (a pairing of that kind with a negative value whose disk point is inside
    the mesh), the gap is the largest such value, as the separating axes of a convex polyhedron
    give it: a rim crossing a convex edge keeps the edge's signed, smooth gap through contact.
    Where no pairing says so but one of the bounding points is inside (deep, confused overlaps),
    the gap is that point's signed distance (pairing ``POINT``: a point held on the disk)."""
    S = mesh.surface
    V = mesh.vertices
    k = c.shape[0]
    tol = 1e-9 * S.size
    rows = np.arange(k)
    # bounding points: the centre and RIM_SAMPLES rim points (their distance bounds the gap)
    angle = 2.0 * math.pi * np.arange(RIM_SAMPLES) / RIM_SAMPLES
    ring = (c[:, None] + rho[:, None, None] * (np.cos(angle)[None, :, None] * e1[:, None]
                                                + np.sin(angle)[None, :, None] * e2[:, None]))
    probes = np.concatenate([c[:, None], ring], 1)
    d_probe, n_probe, _ = mesh.closest(probes.reshape(-1, 3))
    d_probe, n_probe = d_probe.reshape(k, -1), n_probe.reshape(k, -1, 3)
    nearest = np.argmin(d_probe, 1)
    bound = d_probe[rows, nearest]
    # the broad phase: triangles within reach of the disk (a ball round its centre, then the slab
    # of its plane); deeper than the bound only for overlaps
    reach = np.where(bound >= 0.0, bound, 4.0 * np.abs(bound)) + tol
    disk, tri = mesh.near(c, rho + reach)
    keep = np.abs(_dot(S.centroid[tri] - c[disk], a[disk])) <= reach[disk] + S.radius[tri]
    disk, tri = disk[keep], tri[keep]
    # faces: the disk's lowest point along the normal, over the triangle (``outside``: how far its
    # foot lies beyond the triangle's edges)
    nf = S.normal[tri]
    cf, af = c[disk], a[disk]
    inplane = nf - _dot(nf, af)[:, None] * af
    norm_in = np.sqrt(_dot(inplane, inplane))
    pf = cf - rho[disk, None] * inplane / np.maximum(norm_in, 1e-300)[:, None]
    vf = _dot(nf, pf) - S.offset[tri]
    corners = V[mesh.triangles[tri]]
    q = pf - vf[:, None] * nf
    outside = np.full(tri.size, -np.inf)
    for j in range(3):
        edge = corners[:, (j + 1) % 3] - corners[:, j]
        outside = np.maximum(outside, -_dot(_cross(edge, q - corners[:, j]), nf) / np.sqrt(_dot(edge, edge)))
    # edges of those triangles (once per disk): the rim point nearest the line, the direction outward
    pair = np.unique((disk[:, None] * S.edges.shape[0] + S.triangle_edges[tri]).reshape(-1))
    de, je = np.divmod(pair, S.edges.shape[0])
    o, b = V[S.edges[je, 0]], V[S.edges[je, 1]]
    u = (b - o) / np.sqrt(_dot(b - o, b - o))[:, None]
    # both local minima of the rim's distance to the line: an edge through the disk, one end under
    # its face and the other beyond the rim, is held where the rim crosses (or nears) the segment,
    # which need not be the nearer of the two
    s, other = _rim_line(c[de], a[de], e1[de], e2[de], rho[de], o[:, None], u[:, None], both=True)
    minima = np.r_[np.arange(je.size), np.flatnonzero(other[:, 0])]
    s = np.r_[s[:, 0, 0], s[other[:, 0], 0, 1]]
    de, je = de[minima], je[minima]
    o, b = V[S.edges[je, 0]], V[S.edges[je, 1]]
    length = np.sqrt(_dot(b - o, b - o))
    u = (b - o) / length[:, None]
    radial_e = np.cos(s)[:, None] * e1[de] + np.sin(s)[:, None] * e2[de]
    pe = c[de] + rho[de, None] * radial_e
    tau_e = rho[de, None] * _cross(a[de], radial_e)
    along = _dot(pe - o, u)
    apart = pe - o - along[:, None] * u                                         # p − e, ⊥ the line
    m = np.where(_crossing(tau_e, u, apart)[:, None], _cross(tau_e, u), apart)
    norm_m = np.sqrt(_dot(m, m))
    m = m / np.maximum(norm_m, 1e-300)[:, None]
    m = np.where((_dot(m, S.edge_normal[je]) >= 0.0)[:, None], m, -m)
    ve = _dot(m, apart)
    edge_ok = (~S.flat_edge[je] & (norm_m > 0.0) & (along >= -tol) & (along <= length + tol)
               & (_dot(m, V[S.edge_far[je, 0]] - pe + apart) <= tol) & (_dot(m, V[S.edge_far[je, 1]] - pe + apart) <= tol))
    edge_lowest = _dot(m, radial_e) <= 1e-9
    # edges through the disk (ends on either side of its plane, crossing it within the radius):
    # an overlap the rims need not see; their ends' axis pairings stand for it
    h0, h1 = _dot(o - c[de], a[de]), _dot(b - c[de], a[de])
    through = (h0 * h1 < 0.0)
    crossing_point = o + (h0 / np.where(through, h0 - h1, 1.0))[:, None] * (b - o)
    through &= _dot(crossing_point - c[de], crossing_point - c[de]) <= rho[de] ** 2
    pierced_keys = np.r_[de[through] * V.shape[0] + S.edges[je[through], 0], de[through] * V.shape[0] + S.edges[je[through], 1]]
    pierced = np.bincount(de[through], minlength=k) > 0
    # vertices of those triangles: the rim beside them; the axis both ways (the disk's face over
    # them — a bound on the distance apart — or beside them: a separating axis only)
    pair = np.unique((disk[:, None] * V.shape[0] + mesh.triangles[tri]).reshape(-1))
    dv, jv = np.divmod(pair, V.shape[0])
    w = V[jv] - c[dv]
    w_in = w - _dot(w, a[dv])[:, None] * a[dv]
    rho_v = np.sqrt(_dot(w_in, w_in))
    beside = rho_v > rho[dv]
    rim = np.flatnonzero(beside)
    p_rim = c[dv[rim]] + rho[dv[rim], None] * w_in[rim] / rho_v[rim, None]
    offset = p_rim - V[jv[rim]]
    v_rim = np.sqrt(_dot(offset, offset))
    n_rim = offset / np.maximum(v_rim, 1e-300)[:, None]
    axis_sign = np.r_[np.ones(dv.size), -np.ones(dv.size)]
    d_axis, j_axis = np.r_[dv, dv], np.r_[jv, jv]
    n_axis = axis_sign[:, None] * a[d_axis]
    v_axis = _dot(n_axis, c[d_axis] - V[j_axis])
    p_axis = V[j_axis] + v_axis[:, None] * n_axis
    dv, jv = np.r_[dv[rim], d_axis], np.r_[jv[rim], j_axis]
    nv, vv, pv = np.concatenate([n_rim, n_axis]), np.r_[v_rim, v_axis], np.concatenate([p_rim, p_axis])
    kind_v = np.r_[np.full(rim.size, VERTEX), np.full(d_axis.size, AXIS)]
    upper_v = np.r_[v_rim > 0.0, ~np.r_[beside, beside]]
    cone = ~S.flat_vertex[jv] & (np.max(np.einsum("ki,kmi->km", nv, V[S.neighbours[jv]] - V[jv][:, None]), 1) <= tol)
    # (an edge's end beside the disk it passes through: its axis pairing, where no other holds)
    forced = ~cone & (kind_v == AXIS) & np.isin(dv * V.shape[0] + jv, pierced_keys)
    kind = np.concatenate([np.full(tri.size, FACE), np.full(je.size, EDGE), kind_v])
    group = np.concatenate([disk, de, dv])
    value = np.concatenate([vf, ve, vv])
    point = np.concatenate([pf, pe, pv])
    normal = np.concatenate([nf, m, nv])
    line = np.concatenate([np.zeros((tri.size, 3)), u, np.zeros((jv.size, 3))])
    vertex = np.concatenate([np.zeros((tri.size, 3)), np.zeros((je.size, 3)), V[jv]])
    # the pairings: ``exact`` stands for a pair of nearest points (a bound on the distance apart);
    # ``separating`` is a separating axis of the feature's local convex patch (across the surface)
    feature = np.r_[outside <= tol, edge_ok, cone]
    lowest = np.r_[np.ones(tri.size, bool), edge_lowest, np.ones(jv.size, bool)]
    exact = feature & lowest & np.r_[np.ones(tri.size + je.size, bool), upper_v]
    separating = lowest & np.r_[outside <= np.abs(vf) + tol, edge_ok, cone]
    # overlap: a bounding point inside, an edge through the disk, or a pairing whose disk point it
    # puts under the surface lying inside the mesh
    # (beyond rounding: a touching pairing's value is zero either way)
    claim = np.flatnonzero(feature & (value < -tol) & (kind != AXIS))
    overlap = (bound < -tol) | pierced
    if claim.size:
        under = mesh.closest(point[claim])[0] < -tol
        overlap |= np.bincount(group[claim[under]], minlength=k) > 0
    # across, the largest negative separating value — no deeper than the disk's radius or four
    # times the deepest bounding point (a face's plane far off is no separating axis of the
    # local patch)
    deepest = np.maximum(rho, 4.0 * np.maximum(-bound, 0.0))
    negative = (value < 0.0) & overlap[group] & (value >= -deepest[group])
    across = _pick(np.where(negative & separating, value, np.nan), group, k, largest=True)
    fallback = _pick(np.where(negative & np.r_[np.zeros(tri.size + je.size, bool), forced], value, np.nan),
                     group, k, largest=True)
    across = np.where(across >= 0, across, fallback)
    apart_best = _pick(np.where(exact & (value >= -tol), value, np.nan), group, k, largest=False)
    best = np.where(overlap, across, apart_best)
    found = best >= 0
    pick = np.maximum(best, 0)
    gap = np.where(found, value[pick], np.inf)
    n = normal[pick]
    p = point[pick]
    kinds = np.where(found, kind[pick], POINT)
    # a bounding point nearer than every pairing (an overlap no pairing stands for): held there
    held = bound < gap - tol
    gap = np.where(held, bound, gap)
    n = np.where(held[:, None], n_probe[rows, nearest], n)
    p = np.where(held[:, None], probes[rows, nearest], p)
    kinds = np.where(held, POINT, kinds)
    if not second:
        return gap, p, n, kinds
    u_edge = np.where((kinds == EDGE)[:, None], line[pick], 0.0)
    support = np.where((kinds == AXIS)[:, None], vertex[pick], 0.0)
    curvature = np.zeros((k, 3, 3))
    if held.any():
        d, normal, surface = mesh.closest(p[held])
        curvature[held] = mesh.polyhedron.curvature(p[held], d, normal, surface)
    return gap, p, n, kinds, _pairing_derivative(x, c, a, rho, gap, p, n, kinds, u_edge, support, curvature)
