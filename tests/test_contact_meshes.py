"""Contact with triangle meshes, convex or not (docs/contact.md, "Meshes"): a disc's face against
the features of the triangles near it (contact_features.disk_mesh), the k-d tree broad phase of
Mesh.closest, chords on large meshes, and solves against an icosphere, an L-block and an STL file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from meshes import icosphere, l_block, mesh_obstacle, moved_differences, rod_scene, torus, u_channel
from vertebra import solver
from vertebra.core.lie import qmatrix
from vertebra.solver import contact
from vertebra.solver.contact_features import AXIS, EDGE, FACE, POINT, VERTEX, disk_mesh, disk_polyhedron
from vertebra.solver.obstacles import Mesh, _closest_on_triangles

RHO = 0.01
L_BLOCK = Mesh(*l_block(0.0, 0.0, 0.02, 0.03, 0.06))
U_CHANNEL = Mesh(*u_channel(0.0, 0.0, 0.02, 0.01, 0.04, 0.06))
ICOSPHERE = Mesh(*icosphere(0.03, [0.0, 0.0, 0.0], 2))
TETRAHEDRON = Mesh(np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.01, 0.045, 0.0], [0.015, 0.012, 0.04]]),
                   np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
RING = Mesh(*torus(0.03, 0.01, [0.0, 0.0, 0.0], 24, 12))
MESHES = {"L-block": L_BLOCK, "U-channel": U_CHANNEL, "icosphere": ICOSPHERE, "tetrahedron": TETRAHEDRON, "torus": RING}


def _rotation(axis, angle):
    return qmatrix(np.r_[math.cos(0.5 * angle), math.sin(0.5 * angle) * np.eye(3)[axis]])


def _disk(x, R, offset=0.002):
    a = R[:, :, 2]
    return x, x + offset * a, a, R[:, :, 0], R[:, :, 1], np.full(x.shape[0], RHO)


def _rows(mesh, x, R):
    gap, point, normal, kind = disk_mesh(mesh, *_disk(x, R))
    return gap, np.concatenate([normal, np.cross(point - x, normal)], 1), kind


def _poses(mesh, count, seed, low=-5e-3, high=5e-3):
    """Frames turned at random whose disks lie within ``low``–``high`` of the mesh: centred up to
    12 mm off random surface points."""
    rng = np.random.default_rng(seed)
    m = 8 * count
    tri = rng.integers(0, mesh.triangles.shape[0], m)
    w = rng.dirichlet(np.ones(3), m)
    on = np.einsum("ki,kij->kj", w, mesh.corners[tri])
    x = on + mesh.surface.normal[tri] * rng.uniform(-0.002, 0.012, m)[:, None] + rng.normal(size=(m, 3)) * 0.003
    q = rng.normal(size=(m, 4))
    R = qmatrix(q / np.linalg.norm(q, axis=1)[:, None])
    gap = disk_mesh(mesh, *_disk(x, R))[0]
    chosen = np.flatnonzero((gap > low) & (gap < high))[:count]
    assert chosen.size == count
    return x[chosen], R[chosen]


@pytest.mark.parametrize("name", list(MESHES))
def test_a_disks_gap_on_a_mesh_has_the_derivatives_of_its_differences(name):
    # 30 poses within 5 mm of contact, apart and across: the row [n, (p − x) × n] is the gap's
    # derivative and M the row's (central differences, the pairing unchanged across them)
    mesh = MESHES[name]
    x, R = _poses(mesh, 30, 1)
    gaps, rows, kind = moved_differences(lambda xs, Rs: _rows(mesh, xs, Rs), x, R, RHO)
    base_gap, base_row, base_kind = _rows(mesh, x, R)
    M = disk_mesh(mesh, *_disk(x, R), second=True)[4]
    same = np.all(kind == base_kind, (0, 1)) & (base_kind != POINT)
    assert same.sum() >= 24
    assert np.abs(gaps - base_row)[same].max() <= 1e-7
    assert np.abs(rows - M)[same].max() <= 1e-5
    kinds = set(base_kind[same].tolist())
    assert {FACE, EDGE} <= kinds


@pytest.mark.parametrize("name", ["L-block", "U-channel", "torus"])
def test_a_disks_gap_apart_from_a_non_convex_mesh_is_its_distance(name):
    # 8 gaps in (0, 5 mm): none above the least distance of 7,200 points of the disk (rim and
    # inside) and none more than the sampling's error below it
    mesh = MESHES[name]
    x, R = _poses(mesh, 8, 5, low=0.0)
    gap = disk_mesh(mesh, *_disk(x, R))[0]
    r, t = np.linspace(0.0, RHO, 20), np.linspace(0.0, 2.0 * math.pi, 360)
    for k in range(x.shape[0]):
        _, c, a, e1, e2, _ = _disk(x[k:k + 1], R[k:k + 1])
        points = c[0] + r[:, None, None] * (np.cos(t)[None, :, None] * e1[0] + np.sin(t)[None, :, None] * e2[0])
        least = mesh.closest(points.reshape(-1, 3))[0].min()
        assert least - 2e-5 <= gap[k] <= least + 1e-12, (k, gap[k], least)


@pytest.mark.parametrize("name", ["icosphere", "tetrahedron"])
def test_on_a_convex_mesh_the_gap_is_the_separating_axes_one(name):
    # apart, the features near the disk give the convex polyhedron's gap (every feature's
    # separating axis) exactly; across the surface the same, or at most 1 mm deeper where the
    # deepest point's foot lies over another triangle
    mesh = MESHES[name]
    x, R = _poses(mesh, 40, 3)
    gap, _, _, kind = disk_mesh(mesh, *_disk(x, R))
    reference = disk_polyhedron(mesh.polyhedron, *_disk(x, R))[0]
    apart = reference > 0.0
    assert apart.sum() >= 10 and (~apart).sum() >= 10
    assert np.abs(gap - reference)[apart].max() <= 1e-12
    assert np.all(gap[~apart] < 0.0) and np.all(gap[~apart] >= reference[~apart] - 1e-3)


def test_the_k_d_tree_broad_phase_keeps_the_closest_triangle():
    mesh = Mesh(*icosphere(0.03, [0.01, 0.0, 0.0], 3))
    p = np.random.default_rng(0).normal(size=(300, 3)) * 0.03
    distance = mesh.closest(p)[0]
    c = mesh.corners
    q = _closest_on_triangles(np.repeat(p, c.shape[0], 0), np.tile(c, (p.shape[0], 1, 1))).reshape(p.shape[0], -1, 3)
    least = np.sqrt(np.add.reduce((q - p[:, None]) ** 2, -1)).min(1)
    assert np.abs(np.abs(distance) - least).max() <= 1e-15


def _quadratic(history, floor=1e-7):
    pairs = [(a, b) for a, b in zip(history, history[1:]) if b > floor]
    return bool(pairs) and all(b <= 10.0 * a * a for a, b in pairs)


def _touching(model, state):
    """The pairings of the disc faces touching the mesh (gap within 1e-12 m)."""
    x, R = state.positions, qmatrix(state.quaternions)
    kinds = []
    for key in contact.evaluate(model.trunk.contact, state).key:
        if key[0] != contact.RIM:
            continue
        frame, center, e1, e2, axis, radius = contact._faces_of(model.trunk.contact, R, x, np.array([key[1]]))
        gap, _, _, kind = disk_mesh(model.trunk.contact.obstacles[0], x[frame], center, axis, e1, e2, radius)
        if abs(gap[0]) <= 1e-12:
            kinds.append(int(kind[0]))
    return kinds


def test_a_disc_beside_an_l_blocks_concave_edge_converges_quadratically():
    # the rod's 20 mm tip disc pushed onto an L-block's wall 4 mm beyond its rim, the foot's top
    # 1 mm below the disc's lower face: the wall's face holds a rim under 3 mm above the concave
    # edge where the foot meets the wall, the residual squared
    v, t = l_block(x0=-0.05, z0=0.3 - 0.002, step=0.074, size=0.04, depth=0.08)
    model = solver.build_model(solver.parse_scene(rod_scene(mesh_obstacle(v, t), disc=0.02)))
    result = model.solve()
    assert result.converged and result.iterations <= 6 and _quadratic(result.residual_history), result.residual_history
    (touch,) = [c for c in result.contacts if c.force > 0.0]
    assert touch.bodies == ("vertebra 1 disc", "obstacle 0 (mesh)")
    assert abs(touch.gap) <= 1e-12 and all(c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12 for c in result.contacts)
    assert set(_touching(model, result.state)) == {FACE}
    low = min(c.point[2] for c in result.contacts if abs(c.gap) <= 1e-12)
    assert 0.0 < low - (0.3 - 0.002) < 0.003 and abs(touch.point[0] - 0.024) <= 1e-9, low


@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_a_disc_on_an_l_blocks_convex_edge_converges_quadratically(tilt):
    # the L-block stood up (its edges vertical, turned by ``tilt`` about x), its foot's convex
    # edge 8 mm off the rod's bending plane and 5 mm beyond the rim of its tip disc: rim on edge,
    # the residual squared
    v, t = l_block(x0=math.sqrt(0.02 ** 2 - 0.008 ** 2) + 0.005, z0=-0.008, step=0.03, size=0.04, depth=0.08)
    v = v[:, [0, 2, 1]] @ _rotation(0, tilt).T + [0.0, 0.0, 0.3]
    model = solver.build_model(solver.parse_scene(rod_scene(mesh_obstacle(v, t[:, ::-1]), disc=0.02)))
    result = model.solve()
    assert result.converged and result.iterations <= 6 and _quadratic(result.residual_history), result.residual_history
    (touch,) = [c for c in result.contacts if c.force > 0.0]
    assert abs(touch.gap) <= 1e-12 and all(c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12 for c in result.contacts)
    assert _touching(model, result.state) == [EDGE]


def test_a_disc_and_a_capsule_on_an_icosphere_agree_with_the_sphere(tmp_path):
    # the rod's tip disc (10 mm) and, as a capsule (5 mm), its chord pushed onto a sphere of 30 mm
    # and onto its 1,280-triangle icosphere read from a binary STL file (meshio): the equilibria
    # within 0.2 mm (the mesh lies up to 0.05 mm inside the sphere, its normals turned by facets)
    import meshio

    R = 0.03
    for kind, centre in (({"contact_radius": 0.005}, [0.009 + R, 0.0, 0.18]), ({"disc": 0.01}, [0.014 + R, 0.0, 0.27])):
        v, t = icosphere(R, centre, 3)
        path = tmp_path / "icosphere.stl"
        meshio.write(str(path), meshio.Mesh(v, [("triangle", t)]), binary=True)
        tips = []
        for obstacle in ({"type": "sphere", "center": centre, "radius": R}, {"type": "mesh", "path": str(path)}):
            scene = rod_scene(obstacle, **kind)
            if "disc" in kind:
                scene["segment"][0].update(count=10, elements=2, length=0.03)
            model = solver.build_model(solver.parse_scene(scene, base_dir=str(tmp_path)))
            result = model.solve()
            assert result.converged and result.iterations <= 12, result.residual_history
            assert sum(c.force > 0.0 for c in result.contacts) >= 1
            assert all(c.gap >= -1e-9 and abs(c.gap * c.force) <= 1e-12 for c in result.contacts)
            tips.append(result.state.positions)
        assert np.abs(tips[0] - tips[1]).max() <= 2e-4, np.abs(tips[0] - tips[1]).max()


def test_an_edge_through_a_disk_beside_its_rim_is_held_where_the_rim_nears_it():
    # fuzz seed 116's box mesh and a disk (a disc's face) it pierces: the edge from a vertex under
    # the face (0.7 mm clear of it) to one beyond the rim crosses the face's plane 0.6 mm inside the
    # rim. The rim's distance to the edge's line has two minima; the nearer lies off the segment,
    # and with it alone the gap read a vertex's axis bound (−7.3 mm). The gap is the separating
    # axes' (largest over every direction of the disk's and the box's supports), smooth
    V = np.array([[-0.01906096722914585, 0.0001744772636286427, 0.09327686745233842],
                  [-0.0311734239930162, -0.03935199032618013, 0.07837110535162296],
                  [-0.05486109300666201, 0.024812889691105493, 0.05703303563700372],
                  [-0.06697354977053235, -0.014713577898703272, 0.042127273536288284],
                  [-0.033112109384949996, -0.0005642573471491324, 0.10665380317345668],
                  [-0.045224566148820346, -0.0400907249369579, 0.09174804107274125],
                  [-0.06891223516246615, 0.02407415508032772, 0.070409971358122],
                  [-0.0810246919263365, -0.015452312509481045, 0.05550420925740655]])
    T = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = Mesh(V, T)
    x = np.array([[-0.03179625603627595, 0.016740321215468354, 0.09108736132214326]])
    c = np.array([[-0.0313412158505402, 0.015884813153484147, 0.09032716822308502]])
    a = np.array([[-0.36946946686614324, 0.6946289964476845, 0.617238098587353]])
    e1 = np.array([[0.8415575927110893, -0.031546331245670356, 0.5392454423870962]])
    e2 = np.array([[0.39404711799982056, 0.7186761344855007, -0.5729148998909125]])
    rho = np.array([0.02548154975444144])

    def phi(n):
        inplane = n - np.outer(n @ a[0], a[0])
        return n @ c[0] - rho[0] * np.linalg.norm(inplane, axis=1) - (n @ V.T).max(1)

    gap, point, normal, kind = disk_mesh(box, x, c, a, e1, e2, rho)
    assert kind[0] == EDGE and -4.5e-3 < gap[0] < -4.2e-3, (gap, kind)
    assert abs(phi(normal)[0] - gap[0]) <= 1e-12                  # a separating value …
    directions = np.random.default_rng(0).normal(size=(20000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    assert phi(directions).max() <= gap[0] + 1e-12                # … the largest
    h = 1e-7
    for j in range(3):
        step = np.zeros((1, 3))
        step[0, j] = h
        moved = [disk_mesh(box, x + s * step, c + s * step, a, e1, e2, rho)[0][0] for s in (1.0, -1.0)]
        assert abs((moved[0] - moved[1]) / (2 * h) - normal[0, j]) <= 1e-6
