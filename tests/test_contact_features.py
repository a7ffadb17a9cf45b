"""Contact on the sharp features of boxes and meshes (docs/contact.md, "Sharp features"): a disc's
face against a convex polyhedron by the pairing of features that holds it apart (face, edge,
vertex, the disc's axis), its gap against the distance, its derivatives against finite
differences, and the solves that a 1/distance normal at an edge kept from converging."""

import math

import numpy as np
import pytest

from meshes import moved_differences, rod_scene
from vertebra import solver
from vertebra.core.lie import qmatrix, qmul
from vertebra.solver import contact
from vertebra.solver.contact_features import AXIS, EDGE, FACE, VERTEX, disk_polyhedron, segment_polyhedron
from vertebra.solver.obstacles import Box, Mesh

RHO = 0.015                     # the disk's radius (m)


def _quaternion(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[math.cos(0.5 * angle), math.sin(0.5 * angle) * axis]


def _rotation(axis, angle):
    return qmatrix(_quaternion(np.eye(3)[axis], angle))


BOX = Box(np.zeros(3), np.array([0.03, 0.02, 0.025]), qmatrix(_quaternion([0.1, -0.3, 0.2], 0.9)))
TETRAHEDRON = Mesh(np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.01, 0.045, 0.0], [0.015, 0.012, 0.04]]),
                   np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


def _disk(x, R, offset=0.002):
    """Disc faces on frames at ``x`` (n, 3) turned by ``R`` (n, 3, 3): their disks ``offset`` along
    the frames' z (one frame: ``x`` (3,), ``R`` (3, 3))."""
    x, R = np.reshape(x, (-1, 3)), np.reshape(R, (-1, 3, 3))
    a = R[:, :, 2]
    return x, x + offset * a, a, R[:, :, 0], R[:, :, 1], np.full(x.shape[0], RHO)


def _rows(poly, x, R):
    """Gaps, rows ``[n, (p − x) × n]`` and pairings of the disks of frames ``x``, ``R``."""
    gap, point, normal, kind = disk_polyhedron(poly, *_disk(x, R))
    return gap, np.concatenate([normal, np.cross(point - np.reshape(x, (-1, 3)), normal)], 1), kind


def _row(poly, x, R):
    gap, row, kind = _rows(poly, x, R)
    return gap[0], row[0], kind[0]


def _poses(poly, count, seed):
    """Random frames near the polyhedron with its disk's gap within 5 mm of zero."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(12 * count, 4))
    x = poly.vertices.mean(0) + rng.normal(size=(12 * count, 3)) * 0.03
    R = qmatrix(q / np.linalg.norm(q, axis=1)[:, None])
    near = np.flatnonzero(np.abs(_rows(poly, x, R)[0]) < 5e-3)[:count]
    assert near.size == count
    return x[near], R[near]


def _differences(poly, x, R, h=1e-6):
    """Central differences of the gaps and of their rows (n, 6, 6) under moves (h × the radius)
    and turns (h rad) of the frames, and whether the pairings stayed the same across them."""
    x, R = np.reshape(x, (-1, 3)), np.reshape(R, (-1, 3, 3))
    gaps, rows, kind = moved_differences(lambda xs, Rs: _rows(poly, xs, Rs), x, R, RHO, h)
    same = np.all(kind == _rows(poly, x, R)[2], (0, 1))
    return (gaps, rows, same) if x.shape[0] > 1 else (gaps[0], rows[0], bool(same[0]))


def _assert_the_differences(poly, x, R):
    """One disk's pairing unchanged across the differences, its row their gap's and its curvature
    their rows'."""
    gaps, rows, same = _differences(poly, x, R)
    M = disk_polyhedron(poly, *_disk(x, R), second=True)[4][0]
    row = _row(poly, x, R)[1]
    assert same and np.abs(gaps - row).max() <= 1e-7 and np.abs(rows - M).max() <= 1e-6 * np.abs(M).max()


@pytest.mark.parametrize("poly", [BOX.polyhedron, TETRAHEDRON.polyhedron], ids=["box", "tetrahedron"])
def test_a_disks_gap_on_a_polyhedron_has_the_derivatives_of_its_differences(poly):
    # every pairing (face, edge, vertex, axis), apart and overlapping by up to 5 mm: the row is the
    # gap's central difference and M the row's, to 1e-7 / 1e-6 of their largest entry (differences
    # of 1e-6: truncation ~1e-10, rounding ~1e-9 of the entries)
    x, R = _poses(poly, 100, 3)
    gap, point, normal, kind, M = disk_polyhedron(poly, *_disk(x, R), second=True)
    gaps, rows, same = _differences(poly, x, R)
    row = _rows(poly, x, R)[1]
    for k in np.flatnonzero(same):           # (elsewhere the pairing changes within the steps)
        assert np.abs(gaps[k] - row[k]).max() <= 1e-7 * np.abs(row[k]).max()
        assert np.abs(rows[k] - M[k]).max() <= 1e-6 * np.abs(rows[k]).max(), (kind[k], gap[k])
    assert set(kind[same].tolist()) >= {FACE, EDGE, AXIS} and same.sum() >= 80


def test_a_rim_across_an_edge_has_a_signed_smooth_gap_through_contact():
    # a rim crossing a box edge at an angle, 1e-4 m apart, touching and 1e-4 m across: the gap is
    # the signed distance of rim and line (smooth through zero: its derivatives are the
    # differences on both sides and at contact), the pairing an edge's
    box = Box(np.zeros(3), np.array([0.02, 0.02, 0.02]), np.eye(3))
    R = _rotation(0, 0.4) @ _rotation(1, 0.3)
    for target in (1e-4, 0.0, -1e-4):
        # the disk's centre beside the edge x = y = 0.02 (along z), moved along its normal onto the target gap
        x = np.array([0.02 + 0.7 * RHO, 0.02 + 0.7 * RHO, 0.0])
        for _ in range(4):
            gap, _, normal, kind = disk_polyhedron(box.polyhedron, *_disk(x, R))
            x = x - (gap[0] - target) * normal[0]
        assert kind[0] == EDGE and abs(gap[0] - target) <= 1e-15
        _assert_the_differences(box.polyhedron, x, R)


def test_a_rim_parallel_to_an_edge_has_the_distance_between_them():
    # a disc bending over an edge across its bending plane: the rim's tangent at its nearest point is
    # parallel to the edge, so the pairing's direction is p − e (τ × u vanishes). 0.5 mm apart along
    # a direction between the two faces: the gap is that distance and its derivatives the differences
    box = Box(np.zeros(3), np.array([0.02, 0.02, 0.02]), np.eye(3))
    direction = np.array([math.cos(0.6), 0.0, math.sin(0.6)])          # between the faces x = 0.02, z = 0.02
    nearest = np.array([0.02, 0.0, 0.02]) + 5e-4 * direction
    inward = np.array([math.cos(0.3), 0.0, math.sin(0.3)])             # from the rim point to the disk's centre
    R = np.stack([-inward, [0.0, 1.0, 0.0], np.cross(-inward, [0.0, 1.0, 0.0])], 1)   # the disk holds y, the edge's direction
    x = nearest + RHO * inward - 0.002 * R[:, 2]
    gap, point, normal, kind = disk_polyhedron(box.polyhedron, *_disk(x, R))
    assert kind[0] == EDGE and abs(gap[0] - 5e-4) <= 1e-12 and np.allclose(normal[0], direction, atol=1e-9)
    _assert_the_differences(box.polyhedron, x, R)


def test_a_rim_beside_a_vertex_has_the_distance_to_it():
    # a box's corner 0.5 mm beyond the rim along its normal cone's middle (1, 1, 1)/√3, off the
    # disk's plane: the pairing is the vertex's, the gap the corner's distance to the rim, its
    # derivatives the differences (the normal turns as the rim point moves: (I − nnᵀ)/g)
    box = Box(np.zeros(3), np.array([0.02, 0.02, 0.02]), np.eye(3))
    direction = np.ones(3) / math.sqrt(3.0)
    nearest = np.full(3, 0.02) + 5e-4 * direction
    R = _rotation(0, 0.5) @ _rotation(1, 1.1)
    inplane = direction - (direction @ R[:, 2]) * R[:, 2]
    x = nearest + RHO * inplane / np.linalg.norm(inplane) - 0.002 * R[:, 2]
    gap, point, normal, kind = disk_polyhedron(box.polyhedron, *_disk(x, R))
    assert kind[0] == VERTEX and abs(gap[0] - 5e-4) <= 1e-12 and np.allclose(normal[0], direction, atol=1e-12)
    _assert_the_differences(box.polyhedron, x, R)


@pytest.mark.parametrize("obstacle", [BOX, TETRAHEDRON], ids=["box", "tetrahedron"])
def test_a_disks_gap_is_its_signed_distance_to_the_polyhedron(obstacle):
    # apart: the gap is the least distance of the disk's points to the polyhedron, found
    # independently (the best of 40 radii × 360 angles, then SLSQP on the disk) to 1e-9 m;
    # overlapping: some point of the disk is inside the polyhedron
    from scipy.optimize import minimize

    r = np.linspace(0.0, RHO, 40)
    angle = np.linspace(0.0, 2.0 * math.pi, 361)
    for x, R in zip(*_poses(obstacle.polyhedron, 8, 5)):
        gap = _row(obstacle.polyhedron, x, R)[0]
        c = x + 0.002 * R[:, 2]
        plane = np.stack([(r[:, None] * np.cos(angle)).ravel(), (r[:, None] * np.sin(angle)).ravel()], 1)
        distance = obstacle.closest(c + plane @ R[:, :2].T)[0]
        if gap <= 0.0:
            assert distance.min() < 0.0
            continue
        found = minimize(lambda uv: obstacle.closest((c + R[:, :2] @ uv)[None])[0][0], plane[np.argmin(distance)],
                         method="SLSQP", constraints=[{"type": "ineq", "fun": lambda uv: RHO ** 2 - uv @ uv}],
                         options={"ftol": 1e-15, "maxiter": 200})
        assert gap <= distance.min() + 1e-12 and abs(found.fun - gap) <= 1e-9, (gap, found.fun)


def test_a_box_and_a_meshs_surface_curvature_is_their_normals_derivative():
    # beside a face, an edge and a vertex (the distance to a plane, a line, a point): the closed
    # form is the central difference of the closest normal, to 1e-6
    mesh = Mesh(BOX.polyhedron.vertices, np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                                                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]))
    # (the box's corners are ordered by their signs; the triangles outward where the signs say so)
    normals = mesh._faces[0]
    centroids = mesh.corners.mean(1)
    flip = np.add.reduce(normals * centroids, -1) < 0.0
    mesh = Mesh(mesh.vertices, np.where(flip[:, None], mesh.triangles[:, ::-1], mesh.triangles))
    assert mesh.polyhedron.convex and mesh.polyhedron.edges.shape[0] == 12      # the diagonals are no edges
    V = BOX.polyhedron.vertices
    points = [V[7] + 0.01 * (V[7] - BOX.center) / np.linalg.norm(V[7] - BOX.center),     # beside a vertex
              0.5 * (V[6] + V[7]) + 0.004 * BOX.rotation[:, 0] + 0.006 * BOX.rotation[:, 1],  # an edge
              BOX.center + (BOX.half[2] + 0.005) * BOX.rotation[:, 2]]                # a face
    for obstacle in (BOX, mesh):
        for p in points:
            S = obstacle.polyhedron.curvature(p[None], *obstacle.closest(p[None]))[0]
            h = 1e-7
            difference = np.stack([(obstacle.closest((p + h * e)[None])[1][0] - obstacle.closest((p - h * e)[None])[1][0])
                                   / (2 * h) for e in np.eye(3)], 1)
            assert np.abs(S - difference).max() <= 1e-6 * max(np.abs(S).max(), 1.0)


@pytest.mark.parametrize("obstacle", [BOX, TETRAHEDRON], ids=["box", "tetrahedron"])
def test_a_chords_nearest_point_on_a_convex_polyhedron_is_one_of_its_candidates(obstacle):
    # segments beside the polyhedron: the least distance over the candidates (ends, vertices'
    # projections, nearest points to the edges' lines) is the segment's least distance, found
    # independently (the best of 401 samples, then bounded Brent on the convex distance) to 1e-12 m
    from scipy.optimize import minimize_scalar

    rng = np.random.default_rng(7)
    a = obstacle.polyhedron.vertices.mean(0) + rng.normal(size=(40, 3)) * 0.04
    b = a + rng.normal(size=(40, 3)) * 0.03
    t, distance = segment_polyhedron(obstacle.polyhedron, obstacle.closest, a, b)
    samples = np.linspace(0.0, 1.0, 401)
    checked = 0
    for k in range(40):
        along = obstacle.closest(a[k] + samples[:, None] * (b[k] - a[k]))[0]
        if distance[k] == -np.inf:
            assert along.min() < 0.0             # through the polyhedron: the caller searches
            continue
        i = int(np.argmin(along))
        found = minimize_scalar(lambda s: obstacle.closest((a[k] + s * (b[k] - a[k]))[None])[0][0],
                                bounds=(samples[max(i - 1, 0)], samples[min(i + 1, 400)]), method="bounded",
                                options={"xatol": 1e-12})
        least = min(found.fun, along.min())          # (Brent stops short of a bound: the end's sample)
        assert least - 1e-12 <= distance[k] <= least + 1e-15
        checked += 1
    assert checked >= 20


def _quadratic(history, floor=1e-7):
    """Every Newton step whose residuals stay above ``floor`` (where rounding does not set them)
    squares the residual: ``r_{k+1} ≤ 10 r_k²``."""
    pairs = [(a, b) for a, b in zip(history, history[1:]) if b > floor]
    return bool(pairs) and all(b <= 10.0 * a * a for a, b in pairs)


def _rod(obstacle, disc=0.0, contact_radius=None):
    """A nylon-like rod (E 2 GPa, 1 mm radius, 0.3 m, 20 elements) along +z, its tip pushed along
    +x by the force that would move it 10 mm; a disc on its tip vertebra or a capsule radius."""
    return solver.build_model(solver.parse_scene(rod_scene(obstacle, disc, contact_radius)))


@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_a_disc_pressed_on_a_box_edge_converges_quadratically(tilt):
    # the tip's 20 mm disc pushed onto a box's edge 5 mm beyond its rim (the edge vertical, or
    # turned 0.3 rad out of the disc's axis): rim on edge, complementary, the residual squared at
    # every step (the code before: no convergence in 700 iterations and 34 load stages)
    q = qmul(_quaternion([1, 0, 0], tilt), _quaternion([0, 0, 1], math.pi / 4))
    half = np.full(3, 0.02)
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)]) * half @ qmatrix(q).T
    centre = [0.02 + 0.005 - corners[:, 0].min(), 0.0, 0.3]
    model = _rod({"type": "box", "center": centre, "half_extents": half.tolist(), "quaternion": q.tolist()}, disc=0.02)
    result = model.solve()
    assert result.converged and result.iterations <= 5 and _quadratic(result.residual_history), result.residual_history
    (touch,) = [c for c in result.contacts if c.force > 0.0]
    assert touch.bodies == ("vertebra 1 disc", "obstacle 0 (box)")
    assert abs(touch.gap) <= 1e-12 and all(c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12 for c in result.contacts)
    state = result.state
    key = [k for k in contact.evaluate(model.trunk.contact, state).key if k[0] == contact.RIM]
    kinds = []
    for k in key:
        frame, center, e1, e2, axis, radius = contact._faces_of(model.trunk.contact, qmatrix(state.quaternions),
                                                                  state.positions, np.array([k[1]]))
        gap, _, _, kind = disk_polyhedron(model.trunk.contact.obstacles[0].polyhedron, state.positions[frame], center,
                                          axis, e1, e2, radius)
        if abs(gap[0]) <= 1e-12:
            kinds.append(int(kind[0]))
    assert kinds == [EDGE]


def test_a_capsule_pressed_on_a_tetrahedrons_vertex_converges_quadratically():
    # the rod as a capsule (radius 10 mm) pushed at 0.55 of its length onto a tetrahedron's vertex:
    # the chord's interior on the vertex (a distance to a point: curvature (I − nnᵀ)/d), complementary,
    # the residual squared at every step above rounding
    tip = np.array([0.01 + 1e-3, 0.0, 0.165])
    s = 0.02
    vertices = np.array([tip, tip + [s, -s, -s], tip + [s, s, -s], tip + [s, 0.3 * s, s]])
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    outward = np.einsum("ij,ij->i", np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                                             vertices[triangles[:, 2]] - vertices[triangles[:, 0]]),
                        vertices[triangles].mean(1) - vertices.mean(0)) > 0.0
    triangles = np.where(outward[:, None], triangles, triangles[:, ::-1])
    model = _rod({"type": "mesh", "vertices": vertices.tolist(), "triangles": triangles.tolist()}, contact_radius=0.01)
    result = model.solve()
    assert result.converged and result.iterations <= 8 and _quadratic(result.residual_history), result.residual_history
    (touch,) = [c for c in result.contacts if c.force > 0.0]
    assert touch.bodies[0].startswith("link") and touch.bodies[1] == "obstacle 0 (mesh)"
    # the force's line passes through the vertex: the body point is the vertex
    assert np.linalg.norm(np.array(touch.point) - tip) <= 1e-9
    assert all(c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12 for c in result.contacts)
