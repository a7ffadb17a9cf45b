"""Geometrically nonlinear FE of segments and trunks (designer.nonlinear) against known answers.

Coarse P2 meshes (1–5k DoFs) keep the file fast. Every tolerance says where it comes from:
finite-difference truncation, the size of the nonlinear terms at the load used, or the
physics a closed form leaves out.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra.designer import FAMILIES, canonical_parameters
from vertebra.designer.fem import condense
from vertebra.designer.geometry import mesh_segment
from vertebra.designer.nonlinear import (MATERIALS, NonlinearSegment, NonlinearTrunk, TrunkLoads, VertebraMass,
                                         get_material)
from vertebra.designer.nonlinear.framed import Pose
from vertebra.core.errors import ConvergenceError
from vertebra.core.lie import ad, hat, se3_exp_matrix, so3_exp

E = 1.0e6
PNEUMATIC = dict(outer_radius=0.012, chamber_radius=0.003, chamber_offset=0.0065, chambers=2, length=0.015,
                 youngs_modulus=E, poisson_ratio=0.45)


def _mesh(family, parameters, h):
    fam = FAMILIES[family]
    p = canonical_parameters(fam, parameters)
    return fam, p, mesh_segment(fam, p, h, 2)


def _segment(family, parameters, h, material="neo_hookean"):
    fam, p, mesh = _mesh(family, parameters, h)
    return NonlinearSegment.build(mesh, get_material(material, p["youngs_modulus"], p["poisson_ratio"]),
                                  density=p["density"], n_cavities=fam.n_cavities(p), length=fam.length(p))


@pytest.fixture(scope="module")
def pneumatic_mesh():
    return _mesh("pneumatic", PNEUMATIC, 0.006)


@pytest.fixture(scope="module")
def pneumatic(pneumatic_mesh):
    fam, p, mesh = pneumatic_mesh
    return NonlinearSegment.build(mesh, get_material("neo_hookean", E, 0.45), n_cavities=2, length=fam.length(p))


def _left(L):
    """ζ_linear = A ζ: the linear designer moves frame b about its own origin, ours about a's."""
    A = np.eye(6)
    A[:3, 3:] = -hat(np.array([0.0, 0.0, L]))
    return A


# ---- materials ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_material_stress_and_tangent_are_derivatives_of_the_energy(name):
    material = get_material(name, E, 0.45)
    H = 0.3 * np.random.default_rng(1).standard_normal((6, 3, 3))
    W, P, A = material.evaluate(H)
    h = 1e-6
    P_fd, A_fd = np.zeros_like(P), np.zeros_like(A)
    for i in range(3):
        for j in range(3):
            d = np.zeros((3, 3))
            d[i, j] = h
            Wp, Pp, _ = material.evaluate(H + d, tangent=False)
            Wm, Pm, _ = material.evaluate(H - d, tangent=False)
            P_fd[..., i, j] = (Wp - Wm) / (2 * h)
            A_fd[..., :, :, i, j] = (Pp - Pm) / (2 * h)
    # central differences: truncation ~h² |W'''| and round-off ~1e-16 |W|/h, both < 1e-8 here
    assert np.abs(P_fd - P).max() <= 1e-7 * np.abs(P).max()
    assert np.abs(A_fd - A).max() <= 1e-7 * np.abs(A).max()


@pytest.mark.parametrize("name", ["svk", "neo_hookean"])
def test_materials_reduce_to_linear_elasticity_at_small_strain(name):
    material, linear = get_material(name, E, 0.3), get_material("linear", E, 0.3)
    zero = np.zeros((1, 3, 3))
    np.testing.assert_allclose(material.evaluate(zero)[2], linear.evaluate(zero)[2], rtol=0, atol=1e-9 * E)
    H = 1e-6 * np.random.default_rng(2).standard_normal((5, 3, 3))
    P, P_lin = material.evaluate(H, tangent=False)[1], linear.evaluate(H, tangent=False)[1]
    # the nonlinear terms are O(|H|) relative: 1e-6 here
    assert np.abs(P - P_lin).max() <= 1e-5 * np.abs(P_lin).max()


def test_neo_hookean_is_the_abaqus_calculix_form():
    nu = 0.45
    mu, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    C10, D1 = mu / 2, 2 / K
    F = np.eye(3) + 0.25 * np.random.default_rng(3).standard_normal((4, 3, 3))
    J = np.linalg.det(F)
    I1 = np.einsum("nij,nij->n", F, F)
    expected = C10 * (J ** (-2 / 3) * I1 - 3) + (J - 1) ** 2 / D1
    W = get_material("neo_hookean", E, nu).energy(F - np.eye(3))
    np.testing.assert_allclose(W, expected, rtol=1e-12)


def test_patch_test_homogeneous_deformation_is_reproduced_exactly():
    """A homogeneous deformation leaves interior nodes in equilibrium for every material on curved
    P2 tetrahedra (the quadrature integrates cof(J)∇N exactly) and the energy is W(F)·volume."""
    from vertebra.designer.fem import build_fe
    from vertebra.designer.nonlinear.fe_assembly import SolidModel
    fam, p, mesh = _mesh("rod", dict(radius=0.004, length=0.01, youngs_modulus=E, poisson_ratio=0.3), 0.003)
    fe = build_fe(mesh, E, 0.3, 0.0, 0, 0.01)
    boundary_nodes = np.unique(np.concatenate([t.ravel() for t in mesh.facets.values()]))
    interior = np.setdiff1d(np.arange(fe.n_dofs), fe.node_dofs[boundary_nodes].ravel())
    F = np.array([[1.2, 0.1, -0.05], [0.08, 0.9, 0.2], [-0.1, 0.15, 1.1]])
    for name in MATERIALS:
        model = SolidModel(fe, get_material(name, E, 0.3))
        X = model.X.reshape(-1, 3)
        u = (X @ (F - np.eye(3)).T).ravel()
        ev = model.evaluate(u, order=1)
        # round-off of the element sums: 1e-12 of the largest nodal force
        assert np.abs(ev.internal_force[interior]).max() <= 1e-11 * np.abs(ev.internal_force).max(), name
        volume = fe.basis.dx.sum()
        W = model.material.energy((F - np.eye(3))[None])[0]
        assert ev.strain_energy == pytest.approx(W * volume, rel=1e-12)


# ---- one segment ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["linear", "svk", "neo_hookean"])
def test_small_load_limit_equals_the_linear_condensation(pneumatic_mesh, name):
    fam, p, mesh = pneumatic_mesh
    L = fam.length(p)
    seg = NonlinearSegment.build(mesh, get_material(name, E, 0.45), n_cavities=2, length=L)
    cond = condense(seg.framed.fe, ("top",), linear_solver="direct")
    S, g, Vi = cond.stiffness, cond.pressure_wrench, cond.interior_volume
    A = _left(L)
    rest = seg.solve(*seg.rest_pose())
    # at rest every material has the linear tangent: equal to round-off of two assemblies
    assert np.abs(rest.tangent - A.T @ S @ A).max() <= 1e-10 * np.abs(S).max()
    assert np.abs(rest.dvolume_dpose - g.T @ A).max() <= 1e-10 * np.abs(g).max()
    assert np.abs(rest.dvolume_dpressure - Vi).max() <= 1e-10 * np.abs(Vi).max()
    np.testing.assert_allclose(rest.volumes, seg.framed.fe.cavity_volumes, rtol=1e-12)
    # a tiny pose and pressure: wrench and volume growth are linear to O(1e-7) (rotation size)
    xi = 1e-7 * np.array([1.0, -0.5, 0.3, 2.0, 1.0, -1.5]) * np.array([L, L, L, 1, 1, 1])
    R, t = se3_exp_matrix(xi)
    pressures = np.array([0.1, -0.03])
    resp = seg.solve(R, t + R @ [0.0, 0.0, L], pressures)
    wrench = A.T @ S @ A @ xi - A.T @ g @ pressures
    assert np.abs(resp.wrench - wrench).max() <= 1e-5 * np.abs(wrench).max()
    growth = g.T @ A @ xi + Vi @ pressures
    assert np.abs(resp.volume_growth - growth).max() <= 1e-5 * np.abs(growth).max()


def test_tangent_and_volume_derivatives_match_finite_differences(pneumatic):
    """At a finite pose (bend 0.15 rad, twist, shear) and pressure: the tangent against central
    differences of the wrench along exp(h δ^) T_b (the left trivialisation adds ½ ad_δᵀ w), and
    dvolume_dpose against differences of the volumes."""
    L = pneumatic.length
    R, t = se3_exp_matrix(np.array([0.0005, -0.0003, L, 0.05, 0.15, 0.08]))
    pressures = np.array([2e4, 0.0])
    base = pneumatic.solve(R, t, pressures)
    h = 1e-5
    rng = np.random.default_rng(4)
    for _ in range(2):
        delta = rng.standard_normal(6) * np.array([L, L, L, 1, 1, 1])
        out = []
        for sign in (1, -1):
            Rd, td = se3_exp_matrix(sign * h * delta)
            out.append(pneumatic.solve(Rd @ R, Rd @ t + td, pressures, initial=base.state))
        fd_wrench = (out[0].wrench - out[1].wrench) / (2 * h) + 0.5 * ad(delta).T @ base.wrench
        expected = base.tangent @ delta
        # FD truncation ~(h|δ|)² relative and Newton tolerance 1e-10/h: both ≲ 1e-6
        assert np.abs(fd_wrench - expected).max() <= 1e-5 * np.abs(expected).max()
        fd_volume = (out[0].volumes - out[1].volumes) / (2 * h)
        np.testing.assert_allclose(fd_volume, base.dvolume_dpose @ delta, rtol=1e-5,
                                   atol=1e-5 * np.abs(base.dvolume_dpose @ delta).max())
    np.testing.assert_allclose(base.tangent, base.tangent.T, atol=1e-12 * np.abs(base.tangent).max())


def test_reciprocity_wrench_per_pressure_is_minus_volume_per_pose(pneumatic):
    L = pneumatic.length
    R, t = se3_exp_matrix(np.array([0.0, 0.0, L, 0.1, -0.05, 0.0]))
    p0 = np.array([1.5e4, 5e3])
    base = pneumatic.solve(R, t, p0)
    h = 20.0
    for k in range(2):
        dp = np.zeros(2)
        dp[k] = h
        plus = pneumatic.solve(R, t, p0 + dp, initial=base.state)
        minus = pneumatic.solve(R, t, p0 - dp, initial=base.state)
        dwrench = (plus.wrench - minus.wrench) / (2 * h)
        # ψ is smooth: ∂²ψ/∂ζ∂p = −∂V/∂ζ; FD truncation in p is ~(h/E)² relative
        np.testing.assert_allclose(dwrench, -base.dvolume_dpose[k], rtol=1e-5,
                                   atol=1e-5 * np.abs(base.dvolume_dpose[k]).max())
        np.testing.assert_allclose((plus.volumes - minus.volumes) / (2 * h), base.dvolume_dpressure[:, k],
                                   rtol=1e-5, atol=1e-5 * np.abs(base.dvolume_dpressure).max())
    np.testing.assert_allclose(base.dvolume_dpressure, base.dvolume_dpressure.T, rtol=1e-10)


def test_objectivity_a_rigid_motion_creates_no_force(pneumatic):
    """Both frames and every node moved by one rigid motion (1 rad): no strain energy, the same
    cavity volumes, and the forces (the pressure loads) only rotate with the body."""
    framed = pneumatic.framed
    Q, c = so3_exp([0.3, -0.6, 0.5]), np.array([0.01, -0.02, 0.005])
    X = framed.solid.X.reshape(-1, 3)
    u = (X @ Q.T + c - X).ravel()[framed.interior]
    poses = {"bottom": Pose(Q, c), "top": Pose(Q, c + Q @ [0.0, 0.0, framed.length])}
    pressures = np.array([1e4, 2e4])
    ev = framed.evaluate(u, poses, pressures)
    rest = framed.evaluate(np.zeros(framed.n_interior), framed.rest_poses(), pressures)
    assert ev.strain_energy <= 1e-20
    np.testing.assert_allclose(ev.volumes, rest.volumes, rtol=1e-12)
    # positions carry round-off ~1e-17 m; forces compared at 1e-9 of the force scale
    scale = rest.force_scale
    rotated = (rest.gradient_interior.reshape(-1, 3) @ Q.T).ravel()
    assert np.abs(ev.gradient_interior - rotated).max() <= 1e-9 * scale
    moved = np.concatenate([Q @ rest.gradient_frames[3 * j:3 * j + 3] for j in range(4)])
    assert np.abs(ev.gradient_frames - moved).max() <= 1e-9 * scale * framed.length
    # the pressure loads on walls and caps are self-equilibrated: no net force on the segment
    net = ev.gradient_frames[:3] + ev.gradient_frames[6:9] + ev.gradient_interior.reshape(-1, 3).sum(axis=0)
    assert np.abs(net).max() <= 1e-9 * scale


def test_slender_rod_bent_to_a_constant_curvature_carries_EI_theta_over_L():
    R, L = 0.003, 0.024                              # L/R = 8
    seg = _segment("rod", dict(radius=R, length=L, youngs_modulus=E, poisson_ratio=0.3), 0.003)
    theta = 0.5                                      # κR = 6 % strain at the surface
    resp = seg.solve(*se3_exp_matrix(np.array([0.0, 0.0, L, 0.0, theta, 0.0])))
    EI = E * math.pi * R ** 4 / 4
    # Euler–Bernoulli: M = EIθ/L. The rigid end faces add 1.4–1.9 % (linear FE rotation stiffness vs
    # EI/L on these meshes) and the neo-Hookean section loses ~1–2 % at 6 % strain: within 3 %
    assert resp.wrench_at_b[4] == pytest.approx(EI * theta / L, rel=0.03)


@pytest.mark.slow
def test_limit_point_of_an_inflated_chamber_is_reported(pneumatic):
    """Pressure control past the inflation limit: no equilibrium, a ConvergenceError that names the
    stage and the lost positive definiteness (never a silent extrapolation)."""
    from vertebra.designer.nonlinear import NewtonSettings, SegmentSettings
    # a coarse path (steps of 0.1 E, cut at most five times) keeps the test short
    seg = NonlinearSegment(pneumatic.framed, SegmentSettings(
        newton=NewtonSettings(rtol=1e-8, max_iterations=8, min_step=1.0 / 32), max_pressure_step=0.1))
    with pytest.raises(ConvergenceError, match="nonlinear segment: .*limit point") as error:
        seg.solve(*seg.rest_pose(), [E, 0.0])
    state, report = error.value.result
    # the last equilibrium reached is below the requested pressure, the chamber well inflated
    assert 0.1 * E < state.pressures[0] < E


# ---- trunk --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def chain():
    segments = [_segment("pneumatic", dict(PNEUMATIC, chambers=2, chamber_angle_deg=math.degrees(0.5), length=0.02,
                                           youngs_modulus=2 * E, poisson_ratio=0.3), 0.006),
                _segment("pneumatic", dict(PNEUMATIC, chambers=3), 0.006)]
    return segments


@pytest.mark.slow
def test_trunk_small_load_limit_equals_the_linear_full_fe_chain(chain):
    from reference.fe_chain import chain_fe_solve
    wrench = np.array([0.02, -0.01, 0.05, 1e-4, 2e-4, -1e-4])
    pressures = [np.array([2e3, 0.0]), np.array([0.0, 1.5e3, 0.0])]
    linear = chain_fe_solve([s.framed.fe for s in chain], wrench, pressures)
    trunk = NonlinearTrunk(chain)
    scale = 1e-5                                      # rotations ~1e-7 rad: nonlinear terms ~1e-7
    resp = trunk.solve(TrunkLoads(forces={-1: scale * wrench[:3]}, moments={-1: scale * wrench[3:]},
                                  pressures={0: scale * pressures[0], 1: scale * pressures[1]}))
    frames = resp.displacements(trunk.rest_state())[1:] / scale
    assert np.linalg.norm(frames - linear["frames"]) <= 1e-6 * np.linalg.norm(linear["frames"])
    for s in range(2):
        np.testing.assert_allclose(resp.volume_growth[s] / scale, linear["volume_growth"][s], rtol=1e-5,
                                   atol=1e-6 * np.abs(linear["volume_growth"][s]).max())


@pytest.mark.slow
def test_trunk_rigid_base_motion_is_objective(chain):
    """The same trunk on a rotated and shifted base, under rotated loads: the same deformation."""
    Q, c = so3_exp([0.4, 0.2, -0.7]), np.array([0.1, 0.0, -0.3])
    loads = dict(forces={-1: np.array([0.3, 0.1, -0.2])}, moments={1: np.array([0.0, 2e-3, 1e-3])},
                 pressures={1: np.array([0.0, 2e4, 0.0])})
    upright = NonlinearTrunk(chain).solve(TrunkLoads(**loads))
    turned = NonlinearTrunk(chain, base_rotation=Q, base_position=c).solve(TrunkLoads(
        forces={k: Q @ v for k, v in loads["forces"].items()},
        moments={k: Q @ v for k, v in loads["moments"].items()}, pressures=loads["pressures"]))
    tip = upright.positions[-1]
    np.testing.assert_allclose(turned.positions[-1], Q @ tip + c, atol=1e-9 * np.linalg.norm(tip))
    np.testing.assert_allclose(turned.rotations[-1], Q @ upright.rotations[-1], atol=1e-9)
    for s in range(2):
        np.testing.assert_allclose(turned.volumes[s], upright.volumes[s], rtol=1e-9)


@pytest.mark.slow
def test_trunk_under_dead_moment_and_gravity_converges_quadratically(chain):
    """A dead moment (non-conservative in 3-D) with gravity on segments and vertebrae: the consistent
    tangent keeps Newton quadratic (few iterations per load step) and the equilibrium holds: the base
    reaction balances the loads."""
    segments = [_segment("pneumatic", dict(PNEUMATIC, density=1100.0), 0.006)] * 2
    vertebrae = [VertebraMass(), VertebraMass(0.01, [0.002, 0.0, 0.001]), VertebraMass(0.02, [0.0, 0.0, 0.002])]
    trunk = NonlinearTrunk(segments, vertebrae)
    resp = trunk.solve(TrunkLoads(moments={-1: [0.1, 0.15, 0.04]}, forces={1: [0.0, 0.5, 0.0]},
                                  gravity=[0.0, 0.0, -9.81]))
    assert resp.converged and resp.diagnostics["residual"] <= trunk.settings.newton.rtol
    assert resp.iterations <= 8 * resp.load_steps
    rotation = np.linalg.norm(resp.displacements(trunk.rest_state())[-1, 3:])
    assert rotation > 0.2                              # a large-rotation case


# ---- closed forms and the thick-walled tube -----------------------------------------------------

def test_one_dimensional_references_reduce_to_known_solutions():
    from reference.closed_form import lame_plane_strain_radial, neo_hookean_tube_plane_strain, planar_elastica_tip
    a, b = 0.005, 0.01
    R, r = neo_hookean_tube_plane_strain(10.0, a, b, E, 0.45)
    lame = lame_plane_strain_radial(np.array([a, b]), 10.0, a, b, E, 0.45)
    # the finite-strain tube differs from Lamé by O(strain) = 2e-5 at 10 Pa
    np.testing.assert_allclose([r[0] - a, r[-1] - b], lame, rtol=1e-4)
    tip, angle = planar_elastica_tip(1e-4)
    assert tip[1] == pytest.approx(1e-4 / 3, rel=1e-4) and angle == pytest.approx(1e-4 / 2, rel=1e-4)
    # Bisshopp & Drucker's large-deflection cantilever, PL²/EI = 1: tip at (0.9436, 0.3017) L
    tip, _ = planar_elastica_tip(1.0)
    np.testing.assert_allclose(tip, [0.9436, 0.3017], atol=1e-4)


@pytest.mark.slow
def test_thick_walled_tube_inflates_like_the_finite_strain_plane_strain_solution():
    """Clamped tube (a = 5 mm, b = 10 mm, L = 6 b, neo-Hookean, ν = 0.45) at 0.1 MPa: the bore grows by
    28 %. At mid-length the FE radial displacements follow the plane-strain neo-Hookean solution
    (within 4 %: the clamped ends still act at 3 b, and one P2 element spans the wall) while the
    linear (Lamé) answer is 30 % smaller."""
    from reference.closed_form import lame_plane_strain_radial, neo_hookean_tube_plane_strain
    a, b, nu, h = 0.005, 0.01, 0.45, 0.004
    L = 6 * b
    seg = _segment("pneumatic", dict(outer_radius=b, chamber_radius=a, chamber_offset=0.0, chambers=1, length=L,
                                     youngs_modulus=E, poisson_ratio=nu), h)
    p = 1e5
    resp = seg.solve(np.eye(3), [0.0, 0.0, L], [p])
    framed = seg.framed
    X = framed.solid.X.reshape(-1, 3)
    x = X + framed.displacement(resp.state.u_interior, resp.state.poses()).reshape(-1, 3)
    r0, r = np.hypot(X[:, 0], X[:, 1]), np.hypot(x[:, 0], x[:, 1])
    mid = np.abs(X[:, 2] - L / 2) < 0.25 * h
    _, reference = neo_hookean_tube_plane_strain(p, a, b, E, nu)
    lame = lame_plane_strain_radial(np.array([a, b]), p, a, b, E, nu)
    for radius, expected, linear in ((a, reference[0] - a, lame[0]), (b, reference[-1] - b, lame[1])):
        u = (r - r0)[mid & (np.abs(r0 - radius) < 1e-9)].mean()
        assert u == pytest.approx(expected, rel=0.04)
        assert u > 1.25 * linear


def test_segment_weight_is_shared_by_its_clamped_ends():
    """A rod (L/R = 8) clamped at both ends under lateral gravity, small load: frame b carries half
    the weight (symmetry; the unstructured mesh breaks it at ~1e-3) and the clamped-beam end moment
    w L²/12 (beam theory; the 3-D rod with rigid end faces within 5 %)."""
    R, L, rho = 0.003, 0.024, 1000.0
    seg = _segment("rod", dict(radius=R, length=L, youngs_modulus=E, poisson_ratio=0.3, density=rho), 0.003)
    g = np.array([9.81, 0.0, 0.0])
    resp = seg.solve(*seg.rest_pose(), gravity=g)
    weight = seg.framed.fe.mass * g
    np.testing.assert_allclose(resp.wrench[:3], -0.5 * weight, atol=2e-3 * np.linalg.norm(weight))
    # moment about b's origin needed to keep b from rotating: the clamped-beam end moment w L²/12
    assert abs(resp.wrench_at_b[4]) == pytest.approx(np.linalg.norm(weight) * L / 12, rel=0.05)


def test_p1_elements_have_the_linear_limit_too():
    fam, p, mesh = _mesh("pneumatic", dict(PNEUMATIC, poisson_ratio=0.3), 0.005)
    mesh = mesh_segment(fam, p, 0.005, 1)
    seg = NonlinearSegment.build(mesh, get_material("neo_hookean", E, 0.3), n_cavities=2, length=fam.length(p))
    cond = condense(seg.framed.fe, ("top",), linear_solver="direct")
    A = _left(fam.length(p))
    rest = seg.solve(*seg.rest_pose())
    assert np.abs(rest.tangent - A.T @ cond.stiffness @ A).max() <= 1e-10 * np.abs(cond.stiffness).max()
    assert np.abs(rest.dvolume_dpose - cond.pressure_wrench.T @ A).max() <= 1e-10 * np.abs(cond.pressure_wrench).max()
