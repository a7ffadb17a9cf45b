"""Rigid obstacles of a scene (``[[obstacle]]`` tables, docs/contact.md): their geometry and the
signed distance of points to them.

Every obstacle answers one question, batched over points: :meth:`closest` gives each point's
signed distance to its surface (positive outside), the outward unit normal at the closest
surface point and that point. A registry (:data:`OBSTACLE_TYPES`) maps a table's ``type`` to
the class that parses it; adding a type touches this module only. Triangle meshes are read
from STL (ASCII or binary) or Wavefront OBJ files by the small readers below (numpy only: the
runtime does not import meshio), or given inline as ``vertices`` and ``triangles``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vertebra.core.lie import qmatrix

TINY = 1e-300
MAX_TRIANGLES = 200_000


def _unit(t, key, vector):
    norm = math.sqrt(sum(v * v for v in vector))
    if not norm > 0.0:
        raise t.error(key, "a direction must not be the zero vector")
    return np.array(vector, float) / norm


def _normalised(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.sqrt(np.add.reduce(v * v, -1))
    return v / np.maximum(norm, TINY)[..., None], norm


@dataclass(frozen=True, eq=False)
class Polyhedron:
    """A box's or a mesh's vertices, face planes and sharp edges (the features a body touches:
    docs/contact.md, "Sharp features"). ``convex``: every vertex on the inner side of every face
    plane — then the separating-axis gap of :mod:`vertebra.solver.contact_features` holds."""

    vertices: np.ndarray          # (v, 3)
    face_normal: np.ndarray       # (f, 3) outward unit normals
    face_offset: np.ndarray       # (f,) normal · x of the face's plane
    edges: np.ndarray             # (e, 2) vertex indices of the convex edges (faces meeting at an angle)
    convex: bool

    @functools.cached_property
    def size(self) -> float:
        return float(np.ptp(self.vertices, 0).max()) + TINY

    def curvature(self, points, distance, normal, surface) -> np.ndarray:
        """The Hessian (k, 3, 3) of the signed distance at ``points`` from their closest surface
        points: zero on a face, ``(I − uuᵀ − nnᵀ)/d`` beside an edge of direction ``u`` and
        ``(I − nnᵀ)/d`` beside a vertex (the distance to a line, to a point); zero within rounding
        of the surface, where the distance has a kink at an edge or a vertex."""
        k = points.shape[0]
        S = np.zeros((k, 3, 3))
        tol = 1e-10 * self.size
        off = np.flatnonzero(distance > 1e3 * tol)
        if not off.size:
            return S
        q, n, d = surface[off], normal[off], distance[off]
        outer = np.eye(3) - n[:, :, None] * n[:, None, :]
        at_vertex = np.add.reduce((q[:, None] - self.vertices[None]) ** 2, -1).min(1) <= tol * tol
        a, b = self.vertices[self.edges[:, 0]], self.vertices[self.edges[:, 1]]
        u, _ = _normalised(b - a)
        t = np.clip(np.einsum("kei,ei->ke", q[:, None] - a[None], b - a) / np.add.reduce((b - a) ** 2, -1), 0.0, 1.0)
        apart = np.add.reduce((q[:, None] - a[None] - t[..., None] * (b - a)[None]) ** 2, -1)       # (k, e)
        edge = np.argmin(apart, 1) if self.edges.size else np.zeros(off.size, int)
        on_edge = ~at_vertex & (apart[np.arange(off.size), edge] <= tol * tol if self.edges.size else False)
        S[off[at_vertex]] = outer[at_vertex] / d[at_vertex, None, None]
        if np.any(on_edge):
            ue = u[edge[on_edge]]
            S[off[on_edge]] = (outer[on_edge] - ue[:, :, None] * ue[:, None, :]) / d[on_edge, None, None]
        return S


@dataclass(frozen=True, eq=False)
class Plane:
    """The half-space below a plane through ``point`` with outward ``normal``."""

    point: np.ndarray
    normal: np.ndarray
    friction: float = 0.0                 # Coulomb's μ at contacts with it (contact_friction)
    type = "plane"

    @classmethod
    def parse(cls, t, base_dir) -> "Plane":
        return cls(np.array(t.vector("point", 3, (0.0, 0.0, 0.0))), _unit(t, "normal", t.vector("normal", 3, required=True)))

    def closest(self, points):
        distance = (points - self.point) @ self.normal
        normal = np.broadcast_to(self.normal, points.shape)
        return distance, normal, points - distance[..., None] * self.normal

    def bounds(self):
        return None                       # unbounded


@dataclass(frozen=True, eq=False)
class Sphere:
    """A solid ball; ``radius = 0`` is a point stop."""

    center: np.ndarray
    radius: float
    friction: float = 0.0
    type = "sphere"

    @classmethod
    def parse(cls, t, base_dir) -> "Sphere":
        return cls(np.array(t.vector("center", 3, required=True)), t.number("radius", required=True, nonneg=True))

    def closest(self, points):
        normal, norm = _normalised(points - self.center)
        return norm - self.radius, normal, self.center + self.radius * normal

    def bounds(self):
        return self.center - self.radius, self.center + self.radius


def _segment_parameter(points, a, b):
    """Parameter in [0, 1] of the point of each segment a→b closest to ``points``."""
    ab = b - a
    return np.clip(np.add.reduce((points - a) * ab, -1) / np.maximum(np.add.reduce(ab * ab, -1), TINY), 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class Capsule:
    """The points within ``radius`` of the segment ``a``–``b`` (a cylinder with round ends)."""

    a: np.ndarray
    b: np.ndarray
    radius: float
    friction: float = 0.0
    type = "capsule"

    @classmethod
    def parse(cls, t, base_dir) -> "Capsule":
        return cls(np.array(t.vector("a", 3, required=True)), np.array(t.vector("b", 3, required=True)),
                   t.number("radius", required=True, positive=True))

    def closest(self, points):
        s = _segment_parameter(points, self.a, self.b)
        axis = self.a + s[..., None] * (self.b - self.a)
        normal, norm = _normalised(points - axis)
        return norm - self.radius, normal, axis + self.radius * normal

    def bounds(self):
        return np.minimum(self.a, self.b) - self.radius, np.maximum(self.a, self.b) + self.radius


@dataclass(frozen=True, eq=False)
class Box:
    """A box of half-sides ``half`` centred at ``center``, turned by the unit ``quaternion``."""

    center: np.ndarray
    half: np.ndarray
    rotation: np.ndarray
    friction: float = 0.0
    type = "box"

    @classmethod
    def parse(cls, t, base_dir) -> "Box":
        half = t.vector("half_extents", 3, required=True)
        if min(half) <= 0.0:
            raise t.error("half_extents", f"must be > 0, got {list(half)}")
        q = t.vector("quaternion", 4, (1.0, 0.0, 0.0, 0.0))
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > 1e-6:
            raise t.error("quaternion", f"must have unit norm, got norm {norm:.6g}")
        return cls(np.array(t.vector("center", 3, required=True)), np.array(half),
                   qmatrix(np.array(q) / norm))

    def closest(self, points):
        local = (points - self.center) @ self.rotation
        clamped = np.clip(local, -self.half, self.half)
        outside = local - clamped
        away = np.sqrt(np.add.reduce(outside * outside, -1))
        # inside: the nearest face
        depth = self.half - np.abs(local)                     # distance to each pair of faces
        face = np.argmin(depth, -1)
        inside = away <= 0.0
        surface = clamped.copy()
        index = np.nonzero(inside)
        sign = np.where(local[index + (face[index],)] >= 0.0, 1.0, -1.0)
        surface[index + (face[index],)] = sign * self.half[face[index]]
        normal_local = np.where(inside[..., None], 0.0, outside / np.maximum(away, TINY)[..., None])
        normal_local[index + (face[index],)] = sign
        distance = np.where(inside, -np.take_along_axis(depth, face[..., None], -1)[..., 0], away)
        return distance, normal_local @ self.rotation.T, surface @ self.rotation.T + self.center

    @functools.cached_property
    def polyhedron(self) -> Polyhedron:
        signs = np.array([[i, j, k] for i in (-1.0, 1.0) for j in (-1.0, 1.0) for k in (-1.0, 1.0)])
        vertices = (signs * self.half) @ self.rotation.T + self.center
        normals = np.concatenate([self.rotation.T, -self.rotation.T])          # rows: ±the box's axes
        offsets = normals @ self.center + np.concatenate([self.half, self.half])
        edges = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(signs[i] != signs[j]) == 1])
        return Polyhedron(vertices, normals, offsets, edges, True)

    def bounds(self):
        extent = np.abs(self.rotation) @ self.half
        return self.center - extent, self.center + extent


@dataclass(frozen=True, eq=False)
class Mesh:
    """A closed triangle mesh (outward-facing triangles): ``vertices`` (k, 3), ``triangles`` (t, 3)."""

    vertices: np.ndarray
    triangles: np.ndarray
    source: str = ""
    friction: float = 0.0
    type = "mesh"

    @classmethod
    def parse(cls, t, base_dir) -> "Mesh":
        if t.has("path"):
            path = Path(base_dir) / t.string("path", required=True)
            vertices, triangles = read_mesh(path, t)
            source = str(path)
        else:
            vertices = np.array(_rows(t, "vertices", 3, float), float)
            triangles = np.array(_rows(t, "triangles", 3, int), int)
            source = "inline"
        scale = t.number("scale", 1.0, positive=True)
        offset = np.array(t.vector("offset", 3, (0.0, 0.0, 0.0)))
        if triangles.size == 0:
            raise t.error("triangles" if source == "inline" else "path", "the mesh has no triangles")
        if triangles.shape[0] > MAX_TRIANGLES:
            raise t.error("path", f"{triangles.shape[0]} triangles; at most {MAX_TRIANGLES} are supported")
        if triangles.min() < 0 or triangles.max() >= vertices.shape[0]:
            raise t.error("triangles" if source == "inline" else "path",
                          f"vertex indices must lie in 0..{vertices.shape[0] - 1}")
        with np.errstate(over="ignore", invalid="ignore"):
            placed = vertices * scale + offset
        if not np.all(np.isfinite(placed)):
            # a file's NaN or inf coordinates (or ones the scale overflows): such a triangle's
            # bounding box never passes the broad phase, so the obstacle would be silently missing
            raise t.error("path" if source != "inline" else "vertices",
                          f"vertex {int(np.flatnonzero(~np.isfinite(placed).all(1))[0])} has a coordinate that is "
                          "not a finite number" + (" (after the scale)" if np.all(np.isfinite(vertices)) else ""))
        mesh = cls(placed, triangles, source)
        if np.any(mesh.areas <= 0.0):
            raise t.error("triangles", f"triangle {int(np.argmin(mesh.areas))} has no area")
        return mesh

    @property
    def corners(self) -> np.ndarray:
        return self.vertices[self.triangles]                 # (t, 3, 3)

    @functools.cached_property
    def _faces(self) -> tuple[np.ndarray, np.ndarray]:
        """The triangles' unit normals (t, 3) and their angles at each corner (t, 3)."""
        c = self.corners
        normals, _ = _normalised(_cross3(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]))
        angles = np.empty(c.shape[:2])
        for k in range(3):
            e1, e2 = c[:, (k + 1) % 3] - c[:, k], c[:, (k + 2) % 3] - c[:, k]
            angles[:, k] = np.arctan2(np.sqrt(np.add.reduce(_cross3(e1, e2) ** 2, -1)), np.add.reduce(e1 * e2, -1))
        return normals, angles

    @functools.cached_property
    def polyhedron(self) -> Polyhedron:
        normals, _ = self._faces
        c = self.corners
        offsets = np.add.reduce(normals * c[:, 0], -1)
        # edges with the triangles on either side; convex where each triangle's far corner lies
        # below the other's plane (an edge between coplanar triangles is no feature)
        sides = np.sort(np.stack([self.triangles, np.roll(self.triangles, -1, 1)], -1), -1).reshape(-1, 2)
        far = np.roll(self.triangles, 1, 1).reshape(-1)
        owner = np.repeat(np.arange(self.triangles.shape[0]), 3)
        order = np.lexsort((sides[:, 1], sides[:, 0]))
        sides, far, owner = sides[order], far[order], owner[order]
        size = float(np.ptp(self.vertices, 0).max()) + TINY
        paired = np.flatnonzero(np.all(sides[1:] == sides[:-1], 1))
        first, second = paired, paired + 1
        below = np.add.reduce(normals[owner[first]] * (self.vertices[far[second]] - c[owner[first], 0]), -1)
        edges = sides[first][below < -1e-9 * size]
        manifold = 2 * paired.size == sides.shape[0]
        inside = self.vertices @ normals.T - offsets <= 1e-9 * size
        return Polyhedron(self.vertices, normals, offsets, edges, bool(manifold and inside.all()))

    @property
    def areas(self) -> np.ndarray:
        c = self.corners
        return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=-1)

    @functools.cached_property
    def surface(self) -> "MeshSurface":
        """The mesh's features for contact (:class:`MeshSurface`): built once."""
        return MeshSurface.of(self)

    def near(self, points: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (point index, triangle index) of the triangles that may hold a surface point within
        ``reach`` (k,) of each point (their centroids within ``reach`` + their circumradius: a k-d tree)."""
        surface = self.surface
        found = surface.tree.query_ball_point(points, np.maximum(reach, 0.0) + surface.radius_max)
        counts = np.fromiter((len(f) for f in found), int, len(found))
        point = np.repeat(np.arange(len(found)), counts)
        triangle = np.fromiter((t for f in found for t in f), int, int(counts.sum()))
        keep = np.add.reduce((surface.centroid[triangle] - points[point]) ** 2, -1) <= (
            reach[point] + surface.radius[triangle]) ** 2
        return point[keep], triangle[keep]

    def closest(self, points):
        """Closest points on the triangles (Ericson, Real-Time Collision Detection §5.1.5) after a
        broad phase: the nearest vertex (a k-d tree) bounds each point's distance, and only the
        triangles whose centroid lies within that bound and their circumradius can hold its
        closest point (:meth:`near`). The sign comes from the closest feature's angle-weighted
        pseudonormal (a face's normal inside it)."""
        shape = points.shape[:-1]
        p = points.reshape(-1, 3)
        c = self.corners
        bound, _ = self.surface.vertex_tree.query(p)
        point, triangle = self.near(p, bound * (1.0 + 1e-9) + 1e-12 * self.surface.size)
        q = _closest_on_triangles(p[point], c[triangle])
        d2 = np.add.reduce((q - p[point]) ** 2, -1)
        order = np.lexsort((d2, point))                                     # by point, nearest first
        first = order[np.r_[True, point[order][1:] != point[order][:-1]]]
        distance, surface, best = np.sqrt(d2[first]), q[first], triangle[first]
        offset = p - surface
        # the sign: the offset against the angle-weighted pseudonormal of the closest feature
        # (Bærentzen & Aanæs 2005) — the face's normal inside a face, the sum of the triangles'
        # normals weighted by their angle at the closest point on an edge (π each) or a vertex
        # (the corner angles). One nearest triangle's normal is not enough: outside a vertex
        # whose faces meet at more than 90° (a tetrahedron's) the offset can point against one
        # of them, and the point was taken to be deep inside the mesh.
        normals, angles = self._faces
        face = normals[best]
        scale = 1e-9 * (1.0 + np.abs(p).max())
        tied = np.flatnonzero(np.add.reduce((q - surface[point]) ** 2, -1) <= scale * scale)
        shared = np.bincount(point[tied], minlength=first.size) > 1        # on an edge or a vertex
        if shared.any():
            tied = tied[shared[point[tied]]]
            to_corner = np.add.reduce((c[triangle[tied]] - surface[point[tied]][:, None]) ** 2, -1)     # (m, 3)
            corner = np.argmin(to_corner, 1)
            rows = np.arange(tied.size)
            weight = np.where(to_corner[rows, corner] <= scale * scale, angles[triangle[tied], corner], math.pi)
            pseudo = np.zeros((first.size, 3))
            np.add.at(pseudo, point[tied], weight[:, None] * normals[triangle[tied]])
            face = face.copy()
            face[shared] = _normalised(pseudo[shared])[0]
        sign = np.where(np.add.reduce(offset * face, -1) < 0.0, -1.0, 1.0)
        normal = np.where((distance > 1e-12 * (1.0 + np.abs(p).max()))[:, None], sign[:, None] * offset
                          / np.maximum(distance, TINY)[:, None], face)
        return (sign * distance).reshape(shape), normal.reshape(shape + (3,)), surface.reshape(shape + (3,))

    def bounds(self):
        return self.vertices.min(0), self.vertices.max(0)


@dataclass(frozen=True, eq=False)
class MeshSurface:
    """A mesh's triangles, edges and vertices as the features a disc's face touches
    (:func:`vertebra.solver.contact_features.disk_mesh`), with k-d trees of its triangles'
    centroids and of its vertices (the broad phase: cost ~log of the triangles)."""

    size: float
    normal: np.ndarray            # (t, 3) the triangles' outward unit normals
    offset: np.ndarray            # (t,) normal · x of their planes
    centroid: np.ndarray          # (t, 3)
    radius: np.ndarray            # (t,) the farthest corner from the centroid
    radius_max: float
    edges: np.ndarray             # (e, 2) every edge's vertices (once)
    edge_far: np.ndarray          # (e, 2) the far corners of the triangles on either side (an open edge: its one twice)
    edge_normal: np.ndarray       # (e, 3) the sum of the two triangles' normals (outward at the edge)
    triangle_edges: np.ndarray    # (t, 3) each triangle's edges (corners 0–1, 1–2, 2–0)
    neighbours: np.ndarray        # (v, m) each vertex's neighbours along edges (padded with itself)
    pseudonormal: np.ndarray      # (v, 3) the angle-weighted normal (outward at the vertex)
    flat_edge: np.ndarray         # (e,) between coplanar triangles: no feature
    flat_vertex: np.ndarray       # (v,) inside a plane of triangles: no feature
    tree: object                  # scipy.spatial.cKDTree of the centroids
    vertex_tree: object           # … of the vertices

    @classmethod
    def of(cls, mesh: "Mesh") -> "MeshSurface":
        from scipy.spatial import cKDTree

        c = mesh.corners
        normals, angles = mesh._faces
        t = mesh.triangles.shape[0]
        centroid = c.mean(1)
        radius = np.sqrt(np.add.reduce((c - centroid[:, None]) ** 2, -1).max(1))
        sides = np.sort(np.stack([mesh.triangles, np.roll(mesh.triangles, -1, 1)], -1), -1).reshape(-1, 2)
        far = np.roll(mesh.triangles, 1, 1).reshape(-1)                          # the corner opposite each side
        owner = np.repeat(np.arange(t), 3)
        edges, first, inverse = np.unique(sides, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        e = edges.shape[0]
        count = np.bincount(inverse, minlength=e)
        order = np.argsort(inverse, kind="stable")
        start = np.r_[0, np.cumsum(count)[:-1]]
        one, two = order[start], order[start + np.minimum(count, 2) - 1]
        edge_far = np.stack([far[one], far[two]], 1)
        edge_normal = normals[owner[one]] + normals[owner[two]]
        v = mesh.vertices.shape[0]
        pairs = np.concatenate([edges, edges[:, ::-1]])
        degree = np.bincount(pairs[:, 0], minlength=v)
        slot = np.argsort(pairs[:, 0], kind="stable")
        begin = np.r_[0, np.cumsum(degree)[:-1]]
        neighbours = np.repeat(np.arange(v)[:, None], max(int(degree.max()), 1), 1)
        rank = np.arange(pairs.shape[0]) - np.repeat(begin, degree)
        neighbours[pairs[slot, 0], rank] = pairs[slot, 1]
        pseudo = np.zeros((v, 3))
        np.add.at(pseudo, mesh.triangles.reshape(-1), (angles[:, :, None] * normals[:, None, :]).reshape(-1, 3))
        size = float(np.ptp(mesh.vertices, 0).max()) + TINY
        pseudo = _normalised(pseudo)[0]
        flat = 1.0 - 1e-12
        lowest = np.full(v, np.inf)
        np.minimum.at(lowest, mesh.triangles.reshape(-1), np.add.reduce(
            np.repeat(normals, 3, 0) * pseudo[mesh.triangles.reshape(-1)], -1))
        flat_edge = (count == 2) & (np.add.reduce(normals[owner[one]] * normals[owner[two]], -1) >= flat)
        return cls(size, normals, np.add.reduce(normals * c[:, 0], -1), centroid, radius, float(radius.max()),
                   edges, edge_far, edge_normal, inverse.reshape(t, 3), neighbours, pseudo, flat_edge, lowest >= flat,
                   cKDTree(centroid), cKDTree(mesh.vertices))


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (n, 3) arrays (np.cross's axis handling costs more than the product)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], 1)


def _closest_on_triangles(p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The point of each triangle ``c`` (N, 3, 3) closest to its point ``p`` (N, 3) (Ericson's regions)."""
    a, b, cc = c[:, 0], c[:, 1], c[:, 2]
    ab, ac, ap = b - a, cc - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - cc
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denominator = 1.0 / (va + vb + vc)
        v_in, w_in = vb * denominator, vc * denominator
        result = a + v_in[:, None] * ab + w_in[:, None] * ac                  # inside the face
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        edge_bc = b + w_bc[:, None] * (cc - b)
        v_ab = d1 / (d1 - d3)
        w_ac = d2 / (d2 - d6)
    edge_ab = a + v_ab[:, None] * ab
    edge_ac = a + w_ac[:, None] * ac
    # the regions, the later assignment winning (Ericson's early returns in reverse)
    result = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[:, None], edge_bc, result)
    result = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], edge_ac, result)
    result = np.where(((d6 >= 0) & (d5 <= d6))[:, None], cc, result)
    result = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], edge_ab, result)
    result = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, result)
    result = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, result)
    return result


def _rows(t, key, n, kind):
    value = t.raw(key)
    if value is None:
        raise t.missing(key)
    if (not isinstance(value, list) or not value or any(not isinstance(row, list) or len(row) != n for row in value)
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int))
                   or not math.isfinite(v) for row in value for v in row)):
        raise t.error(key, f"expected a list of rows of {n} {'integers' if kind is int else 'finite numbers'}")
    return value


def read_mesh(path: Path, t) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an STL (ASCII or binary) or OBJ file (polygons fanned into
    triangles); errors name the scene field."""
    suffix = path.suffix.lower()
    try:
        data = path.read_bytes()
    except OSError as error:
        raise t.error("path", f"cannot read mesh {path}: {error.strerror or error}")
    try:
        if suffix == ".stl":
            return _read_stl(data)
        if suffix == ".obj":
            return _read_obj(data.decode("utf-8", "replace"))
    except (ValueError, IndexError) as error:
        raise t.error("path", f"{path}: not a valid {suffix[1:].upper()} mesh ({error})")
    raise t.error("path", f"{path}: mesh files are read as .stl or .obj (convert others with meshio)")


def _read_stl(data: bytes):
    if len(data) >= 84:
        count = int(np.frombuffer(data[80:84], "<u4")[0])
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
            corners = np.frombuffer(data, record, count, 84)["corners"].astype(float)
            return _merge(corners.reshape(-1, 3))
    text = data.decode("ascii", "replace")
    values = [line.split()[1:4] for line in text.splitlines() if line.strip().startswith("vertex")]
    corners = np.array(values, float)
    if corners.size == 0 or corners.shape[0] % 3:
        raise ValueError("no triangles of three vertices")
    return _merge(corners)


def _merge(corners: np.ndarray):
    vertices, inverse = np.unique(corners, axis=0, return_inverse=True)
    return vertices, inverse.reshape(-1, 3)


def _read_obj(text: str):
    vertices, triangles = [], []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(v) for v in parts[1:4]])
        elif parts[0] == "f":
            corners = [int(p.split("/")[0]) for p in parts[1:]]
            corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
            triangles += [[corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)]
    if not triangles:
        raise ValueError("no faces")
    return np.array(vertices, float), np.array(triangles, int)


#: an ``[[obstacle]]`` table's ``type`` → the class that parses it
OBSTACLE_TYPES = {cls.type: cls for cls in (Plane, Sphere, Capsule, Box, Mesh)}


def parse_obstacle(t, base_dir):
    kind = t.string("type", required=True, choices=tuple(OBSTACLE_TYPES))
    obstacle = OBSTACLE_TYPES[kind].parse(t, base_dir)
    # Coulomb friction at the obstacle's contacts (μ ≥ 0; 0: frictionless, docs/contact.md)
    mu = t.number("friction", 0.0, nonneg=True)
    t.done()
    return dataclasses.replace(obstacle, friction=float(mu)) if mu else obstacle

