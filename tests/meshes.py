"""Triangle meshes and robots for the mesh contact tests and benchmarks/bench_contact_meshes.py:
icospheres, prisms of polygons (an L-block, a U-channel), a tendon robot and a pushed rod."""

from __future__ import annotations

import math

import numpy as np


# --- meshes ----------------------------------------------------------------------------------

def icosphere(radius: float, center, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """An icosahedron subdivided ``subdivisions`` times (20·4^s triangles), vertices on the sphere."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    vertices = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        middle, faces = {}, []

        def mid(i, j):
            key = (min(i, j), max(i, j))
            if key not in middle:
                p = vertices[i] + vertices[j]
                vertices.append(p / np.linalg.norm(p))
                middle[key] = len(vertices) - 1
            return middle[key]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = faces
    return np.array(vertices) * radius + np.asarray(center, float), np.array(f, int)


def _ear_clip(polygon: np.ndarray) -> list:
    """Triangles of a simple counter-clockwise polygon (n, 2) by ear clipping."""
    index = list(range(polygon.shape[0]))
    out = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    while len(index) > 3:
        for k in range(len(index)):
            i, j, l = index[k - 1], index[k], index[(k + 1) % len(index)]
            a, b, c = polygon[i], polygon[j], polygon[l]
            if cross(a, b, c) <= 1e-15:
                continue
            if any(cross(a, b, polygon[m]) >= 0 and cross(b, c, polygon[m]) >= 0 and cross(c, a, polygon[m]) >= 0
                   for m in index if m not in (i, j, l)):
                continue
            out.append((i, j, l))
            index.pop(k)
            break
        else:
            raise ValueError("not a simple counter-clockwise polygon")
    out.append(tuple(index))
    return out


def prism(polygon, depth: float, origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh: the counter-clockwise polygon (n, 2) in the x–z plane, extruded along y over
    ``[−depth/2, depth/2]`` from ``origin`` (triangles outward)."""
    polygon = np.asarray(polygon, float)
    n = polygon.shape[0]
    # the polygon's (x, z) counter-clockwise seen from −y: its cap at y = −depth/2 faces −y
    xz = np.column_stack([polygon[:, 0], polygon[:, 1]])
    front = np.column_stack([xz[:, 0], np.full(n, -depth / 2), xz[:, 1]])
    back = front + [0.0, depth, 0.0]
    vertices = np.concatenate([front, back]) + np.asarray(origin, float)
    caps = _ear_clip(xz)
    triangles = [(a, b, c) for a, b, c in caps] + [(c + n, b + n, a + n) for a, b, c in caps]
    for i in range(n):
        j = (i + 1) % n
        triangles += [(i, i + n, j + n), (i, j + n, j)]
    triangles = np.array(triangles, int)
    # orient outward: (counter-clockwise in x–z seen from −y: the normal of (x, z) ccw is −y)
    c = vertices[triangles]
    normal = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    signed = np.einsum("ij,ij->", normal, c[:, 0])            # 3 × volume
    if signed < 0.0:
        triangles = triangles[:, ::-1]
    return vertices, triangles


def l_block(x0: float, z0: float, step: float, size: float, depth: float):
    """An L-block in the x–z plane: a foot reaching to ``x0`` below ``z0`` and a wall set back by
    ``step`` above it (the foot's top meets the wall at a concave edge ``(x0 + step, z0)`` and its
    own side at a convex edge ``(x0, z0)``)."""
    polygon = [(x0, z0 - size), (x0 + step + size, z0 - size), (x0 + step + size, z0 + size),
               (x0 + step, z0 + size), (x0 + step, z0), (x0, z0)]
    return prism(polygon, depth)


def u_channel(x0: float, z0: float, width: float, wall: float, size: float, depth: float):
    """A U-channel opening towards −x: floor at ``x0``, walls along x at ``z0 ± width/2`` ``wall``
    thick, ``size`` deep (concave edges where the floor meets the walls)."""
    h = width / 2.0
    polygon = [(x0 - size, z0 - h - wall), (x0 + wall, z0 - h - wall), (x0 + wall, z0 + h + wall),
               (x0 - size, z0 + h + wall), (x0 - size, z0 + h), (x0, z0 + h), (x0, z0 - h), (x0 - size, z0 - h)]
    return prism(polygon, depth)


def mesh_obstacle(vertices, triangles) -> dict:
    return {"type": "mesh", "vertices": np.asarray(vertices).tolist(), "triangles": np.asarray(triangles).tolist()}




def tendon_scene(obstacle) -> dict:
    """A tendon robot: 8 vertebrae 20 mm apart on a 0.6 mm nitinol-like rod, 8 mm discs, one cable
    8 mm off the axis at 0° (it bends towards +x)."""
    return {"segment": [{"type": "beam", "count": 8, "length": 0.02, "elements": 2, "youngs_modulus": 5e10,
                         "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 6e-4},
                         "vertebra": {"mass": 0.0, "disc_radius": 0.008, "disc_thickness": 0.002}}],
            "cable": [{"name": "c", "radius": 0.006, "angle_deg": 0.0, "to": 8, "tension": 6.0}],
            "obstacle": [obstacle] if obstacle else []}


def rod_scene(obstacle, disc=0.0, contact_radius=None, push=0.01) -> dict:
    """A nylon-like rod (E 2 GPa, 1 mm radius, 0.3 m) along +z, its tip pushed along +x by the force
    that would move it ``push``; a disc on its tip vertebra or a capsule radius."""
    E, radius, length = 2e9, 1e-3, 0.3
    force = push * 3.0 * E * math.pi * radius ** 4 / 4.0 / length ** 3
    segment = {"type": "beam", "count": 1, "elements": 20, "length": length, "youngs_modulus": E,
               "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": radius}}
    if disc:
        segment["vertebra"] = {"mass": 0.0, "disc_radius": disc, "disc_thickness": 0.002}
    if contact_radius is not None:
        segment["contact_radius"] = contact_radius
    return {"segment": [segment], "obstacle": [obstacle] if obstacle else [],
            "load": [{"vertebra": -1, "force": [force, 0.0, 0.0]}]}




def torus(major: float, minor: float, center, segments: int = 48, sides: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A ring of radii ``major`` (to the tube's axis) and ``minor`` (the tube's), its axis along z,
    ``segments`` × ``sides`` quads split into triangles (outward)."""
    u = 2.0 * math.pi * np.arange(segments) / segments
    v = 2.0 * math.pi * np.arange(sides) / sides
    U, W = np.meshgrid(u, v, indexing="ij")
    ring = major + minor * np.cos(W)
    vertices = np.stack([ring * np.cos(U), ring * np.sin(U), minor * np.sin(W)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(segments), np.arange(sides), indexing="ij")
    a, b = i * sides + j, ((i + 1) % segments) * sides + j
    c, d = ((i + 1) % segments) * sides + (j + 1) % sides, i * sides + (j + 1) % sides
    triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return vertices + np.asarray(center, float), triangles


def _turn(axis: int, angle: float) -> np.ndarray:
    """The rotation matrix by ``angle`` about the world axis ``axis``."""
    c, s_ = math.cos(angle), math.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.eye(3)
    out[i, i] = out[j, j] = c
    out[j, i], out[i, j] = s_, -s_
    return out


def moved_differences(rows, x, R, reach: float, h: float = 1e-6):
    """Central differences of ``rows(x, R) -> (gap (n,), row (n, 6), kind (n,))`` under moves of the
    frames ``x`` (n, 3), ``R`` (n, 3, 3) along the world axes (``h × reach``) and turns about them
    (``h`` rad): the gaps' (n, 6), the rows' (n, 6 rows, 6 moves), and the kinds at every moved
    pose (6, 2, n) to tell where the pairing stayed the same across the differences."""
    n = x.shape[0]
    moved_x, moved_R, steps = [], [], []
    for c in range(6):
        for sign in (1.0, -1.0):
            if c < 3:
                shifted = x.copy()
                shifted[:, c] += sign * h * reach
                moved_x.append(shifted)
                moved_R.append(R)
            else:
                moved_x.append(x)
                moved_R.append(_turn(c - 3, sign * h) @ R)
        steps.append(h * reach if c < 3 else h)
    gap, row, kind = rows(np.concatenate(moved_x), np.concatenate(moved_R))
    gap, row, kind = gap.reshape(6, 2, n), row.reshape(6, 2, n, 6), kind.reshape(6, 2, n)
    step = np.array(steps)
    gaps = ((gap[:, 0] - gap[:, 1]) / (2.0 * step[:, None])).T                                 # (n, 6)
    derivative = np.transpose((row[:, 0] - row[:, 1]) / (2.0 * step[:, None, None]), (1, 2, 0))
    return gaps, derivative, kind
