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

FACE, EDGE, VERTEX, AXIS = 0, 1, 2, 3          # the pairing that gives a disk's gap
SAMPLES = 16                                    # starting samples of a rim's angle against a line …
BISECTIONS = 52                                 # … then bisection to the rounding of the angle


def _cross(a, b):
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


def _rim_line(c, a, e1, e2, rho, o, u):
    """The rim angle ``s`` (k, e) nearest each line ``o + w u`` (e, 3, or (k, e, 3) per disk): 16
    samples, then bisection on the derivative of the squared distance (``r⊥·τ``) to the rounding
    of the angle."""
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
    best = np.full((k, e), np.inf)
    start = np.zeros((k, e))
    for s in samples:
        perp, _ = at(np.full((k, e), s))
        d2 = _dot(perp, perp)
        start = np.where(d2 < best, s, start)
        best = np.minimum(best, d2)
    width = 2.0 * math.pi / SAMPLES
    low, high = start - width, start + width
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        perp, tau = at(middle)
        falling = _dot(perp, tau) < 0.0
        low, high = np.where(falling, middle, low), np.where(falling, high, middle)
    return 0.5 * (low + high)


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


def _pairing_derivative(x, c, a, rho, gap, point, n, kind, u_edge, support):
    """``M`` (k, 6, 6): the derivative of a disk's gap row ``[n, (p − x) × n]`` under a move ``δx``
    and a turn ``δφ`` (world axes) of its frame at ``x``, for the pairing ``kind`` that gives its gap
    (``u_edge``: an edge pairing's line direction; ``support``: an axis pairing's vertex)."""
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


def segment_polyhedron(poly, closest, a, b):
    """The parameter ``t`` (k,) of the point of each segment ``a → b`` (k, 3) nearest the convex
    polyhedron ``poly`` (``closest``: its obstacle's :meth:`closest`), and that point's signed
    distance. Outside the polyhedron the distance along a line is smooth and convex, made of a
    face's (linear), an edge's or a vertex's pieces, so its least is at an end, at a vertex's
    projection on the segment or at the segment's point nearest an edge's line: each candidate's
    distance from one query, the least taken (exact where it is positive). A segment that passes
    through the polyhedron has its least inside, at none of these: its distance is −∞."""
    V = poly.vertices
    ab = b - a
    length2 = np.maximum(_dot(ab, ab), 1e-300)
    at_vertex = _dot(V[None] - a[:, None], ab[:, None]) / length2[:, None]                  # (k, v)
    o, u = V[poly.edges[:, 0]], V[poly.edges[:, 1]] - V[poly.edges[:, 0]]
    u = u / np.sqrt(_dot(u, u))[:, None]
    r = a[:, None] - o[None]                                                               # (k, e, 3)
    along = _dot(ab[:, None], u[None])                                                     # (k, e)
    square = length2[:, None] - along * along
    at_edge = np.where(square > 1e-12 * length2[:, None],
                       (along * _dot(r, u[None]) - _dot(r, ab[:, None])) / np.maximum(square, 1e-300), 0.0)
    t = np.clip(np.concatenate([np.zeros((a.shape[0], 1)), np.ones((a.shape[0], 1)), at_vertex, at_edge], 1), 0.0, 1.0)
    distance = closest((a[:, None] + t[..., None] * ab[:, None]).reshape(-1, 3))[0].reshape(t.shape)
    best = np.argmin(distance, 1)
    rows = np.arange(a.shape[0])
    # a segment through the polyhedron (clipped by the faces' half-spaces): its least distance is
    # inside, where the candidates need not be — reported as −∞ (the caller searches)
    start = a @ poly.face_normal.T - poly.face_offset                                      # (k, f)
    end = b @ poly.face_normal.T - poly.face_offset
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = start / (start - end)
    enter = np.max(np.where((start > 0.0) & (end <= 0.0), crossing, np.where(start > 0.0, np.inf, 0.0)), 1)
    leave = np.min(np.where((start <= 0.0) & (end > 0.0), crossing, 1.0), 1)
    through = enter <= leave
    return t[rows, best], np.where(through, -np.inf, distance[rows, best])
