"""QA: seeded random (but physically sensible) beam robots against the runtime solver,
its linearisation and the inverse.

The generator draws 1–4 beam segments (1–8 vertebrae each, 1–4 elements per vertebra,
5 mm–0.2 m per vertebra), one Young's modulus per robot in 1 MPa–200 GPa (±½ decade per
segment), a common radius giving a whole-robot slenderness of 10–200 (±40 % per segment),
densities and vertebra masses, 0–6 cables at random angles/radii/ranges, 0–2 dead forces
and, for half the robots, gravity in a random direction. Loads are scaled to the softest
segment so that they are *moderate*: dead forces and the total weight at most EI/L², each
cable moment at most 0.15 EI/L. (With loads far beyond that — weight 10³–10⁵ EI/L², cable
compressions several Euler loads on a single link — links fold to a relative rotation of π,
where the constant-strain log map has its branch cut, and Newton gives up; that is a
modelling limit, not tested here.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.solver.inverse import invert
from vertebra.core.lie import qrotate

CABLE_MOMENT = 0.15   # largest cable moment, in units of EI/L of the softest segment


def random_scene(rng, *, gravity=False, n_cables=None, axis_effector=False):
    nseg = int(rng.integers(1, 5))
    counts = [int(rng.integers(1, 9)) for _ in range(nseg)]
    els = [int(rng.integers(1, 5)) for _ in range(nseg)]
    lengths = [float(np.exp(rng.uniform(np.log(0.005), np.log(0.2)))) for _ in range(nseg)]
    E0 = float(np.exp(rng.uniform(np.log(1e6), np.log(2e11))))
    Lsum = sum(c * length for c, length in zip(counts, lengths))
    r0 = Lsum / rng.uniform(10, 200)
    segs = []
    nv = 1 + sum(counts)
    for count, el, length in zip(counts, els, lengths):
        segs.append(dict(type="beam", count=count, length=length, elements=el,
                         youngs_modulus=float(min(2e11, max(1e6, E0 * 10 ** rng.uniform(-0.5, 0.5)))),
                         poisson_ratio=float(rng.uniform(0.2, 0.49)),
                         section=dict(shape="circle", radius=float(r0 * rng.uniform(0.7, 1.4))),
                         density=float(rng.uniform(0, 8000)),
                         vertebra=dict(mass=float(rng.uniform(0, 1e-3)), center_of_mass=[0.0, 0.0, 0.0])))
    scene = dict(name="qa-random", segment=segs)
    EI = min(s["youngs_modulus"] * math.pi * s["section"]["radius"] ** 4 / 4 for s in segs)
    Ltot = sum(s["length"] * s["count"] for s in segs)
    fscale = EI / Ltot ** 2
    rmin = min(s["section"]["radius"] for s in segs)
    if gravity:
        probe = solver.build_model(solver.parse_scene(dict(name="probe", segment=segs)))
        weight = float(np.sum(probe.frame_mass))
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if weight > 0:
            scene["gravity"] = {"vector": (d * rng.uniform(0.1, 1.0) * fscale / weight).tolist()}
    nc = int(rng.integers(0, 7)) if n_cables is None else n_cables
    cables = []
    for k in range(nc):
        a = int(rng.integers(1, nv))
        b = int(rng.integers(a, nv))
        rad = float(rng.uniform(1, 4) * rmin)
        tau = float(rng.uniform(0, CABLE_MOMENT) * EI / Ltot / rad)
        cables.append({"name": f"c{k}", "radius": rad, "angle_deg": float(rng.uniform(0, 360)), "from": a,
                       "to": b, "tension": tau, "min_tension": 0.0, "max_tension": float(2 * EI / Ltot / rad)})
    if cables:
        scene["cable"] = cables
    loads = []
    for _ in range(int(rng.integers(0, 3))):
        f = rng.normal(size=3)
        f *= rng.uniform(0, 1) * fscale / np.linalg.norm(f)
        loads.append(dict(vertebra=int(rng.integers(1, nv)), force=f.tolist()))
    if loads:
        scene["load"] = loads
    effs = [dict(name="tip", vertebra=-1, offset=[0.0, 0.0, 0.0])]
    if nv > 2:
        effs.append(dict(name="mid", vertebra=int(nv // 2), offset=[rmin, 0.0, 0.0]))
    if axis_effector:
        effs.append(dict(name="ax", vertebra=-1, axis=[0.0, 0.0, 1.0], weight=0.05))
    scene["effector"] = effs
    return scene, Ltot


def build(scene):
    return solver.build_model(solver.parse_scene(scene))


def quaternion(rotvec):
    angle = float(np.linalg.norm(rotvec))
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * np.asarray(rotvec) / angle]


# ---------------------------------------------------------------------------- forward

@pytest.mark.parametrize("seed", range(30))
def test_random_robot_forward_equilibrium_restart_and_objectivity(seed):
    rng = np.random.default_rng(seed)
    scene, L = random_scene(rng, gravity=bool(rng.random() < 0.5))
    model = build(scene)
    result = model.solve()
    assert result.converged
    assert np.all(np.isfinite(result.state.positions)) and np.all(np.isfinite(result.state.quaternions))
    loads = model.trunk.loads
    if not (np.any(result.actuation) or loads.has_dead_forces or loads.has_dead_moments or loads.has_gravity):
        # nothing acts on the robot: the stress-free rest pose is returned as it is
        assert result.iterations == 0 and result.residual == 0.0
        assert np.array_equal(result.state.positions, model.rest_state.positions)
    else:
        # the reported residual is the real one: recompute the out-of-balance force independently
        lin = model.linearise(result.state, result.actuation)
        recomputed = model.residual_norm(lin.residual, result.actuation)
        assert recomputed == pytest.approx(result.residual, rel=1e-9, abs=1e-15)
    # converged means below the tolerance, unless it says the pose is at its rounding floor
    # (docs/solver.md, "Convergence measure")
    assert result.residual <= model.scene.solver.tolerance or result.rounding_limited

    # a warm-started re-solve from the equilibrium stays there (to a few ulps of the extent)
    again = model.solve(initial=result.state)
    assert again.converged
    assert np.max(np.abs(again.state.positions - result.state.positions)) <= 1e-12 * L

    # objectivity: rotating the base, gravity and dead loads rotates the solution.
    # Measured ≤ 1.7e-9 L over 400 seeds (the 1e-9 scaled residual leaves an error of that
    # order in the pose); 1e-8 L leaves a margin and still catches any real asymmetry.
    q = quaternion(rng.normal(size=3))
    offset = np.array([0.1, -0.2, 0.3])
    turned = dict(scene, base={"position": offset.tolist(), "quaternion": q.tolist()})
    if "gravity" in scene:
        turned["gravity"] = {"vector": qrotate(q, np.array(scene["gravity"]["vector"])).tolist()}
    if "load" in scene:
        turned["load"] = [dict(load, force=qrotate(q, np.array(load["force"])).tolist()) for load in scene["load"]]
    rotated = build(turned).solve()
    expected = offset + qrotate(q[None], result.state.positions)
    assert np.max(np.abs(rotated.state.positions - expected)) <= 1e-8 * L


# ---------------------------------------------------------------------------- linearisation

@pytest.mark.parametrize("seed", range(8))
def test_random_robot_linearisation_matches_finite_differences(seed):
    """K, B, Ja and Je against central differences through ``model.step(state, ±h·v)``.

    Steps are 1e-6 (relative length / rad). Errors are measured against the size of the
    terms that make up each product (|M| @ |v|), so cancellation in the product does not
    inflate them. Measured at h = 1e-6 over 20 seeds: K ≤ 3.3e-7 (it falls as h² down to
    the conditioning floor of the explicit inverse, ~1e-8), Je ≤ 1e-9, Ja ≤ 1e-7,
    B ≤ 2e-11; the bounds below are 30–100× those.
    """
    rng = np.random.default_rng(seed)
    scene, L = random_scene(rng, gravity=bool(rng.random() < 0.5), n_cables=int(rng.integers(1, 5)),
                            axis_effector=True)
    model = build(scene)
    result = model.solve()
    state, act = result.state, result.actuation
    n = model.n_dof
    lin = model.linearise(state, act)
    K = np.linalg.inv(lin.solve(np.eye(n)))
    h = np.tile(np.r_[np.full(3, 1e-6 * L), np.full(3, 1e-6)], n // 6)
    for _ in range(3):
        v = rng.normal(size=n) * h
        plus, minus = model.step(state, v), model.step(state, -v)
        d_res = (model.linearise(plus, act).residual - model.linearise(minus, act).residual) / 2
        assert np.max(np.abs(K @ v + d_res) / (np.abs(K) @ np.abs(v))) <= 1e-5          # K = −∂r/∂q
        d_eff = (model.effector_positions(plus) - model.effector_positions(minus)).reshape(-1) / 2
        Je = lin.effector_jacobian
        # plus the rounding of differenced world positions/directions (~1e-16 of their size)
        floor = 1e-15 * (1.0 + np.max(np.abs(state.positions)))
        assert np.all(np.abs(Je @ v - d_eff) <= 1e-7 * (np.abs(Je) @ np.abs(v)) + floor)
        d_act = (model.actuator_displacements(plus, act) - model.actuator_displacements(minus, act)) / 2
        Ja = lin.actuator_jacobian
        assert np.all(np.abs(Ja @ v - d_act) <= 1e-5 * (np.abs(Ja) @ np.abs(v)) + floor)
    for a in range(len(act)):
        step = 1e-6 * model.actuator_bounds[1][a]
        up, down = act.copy(), act.copy()
        up[a] += step
        down[a] -= step
        d_res = (model.linearise(state, up).residual - model.linearise(state, down).residual) / (2 * step)
        B = lin.actuator_forces[:, a]
        assert np.max(np.abs(B - d_res)) <= 1e-8 * np.max(np.abs(d_res))


# ---------------------------------------------------------------------------- inverse

@pytest.mark.parametrize("seed", range(14))
def test_random_robot_inverse_of_a_forward_solution(seed):
    """Targets are where a forward solve put the effectors (reachable by construction, with
    actuation inside the bounds); the converged inverse from zero tension must reach them
    to its 1e-6 m tolerance (docs/inverse.md) with the bounds held exactly, and an
    independent forward solve under the returned actuation must confirm it."""
    rng = np.random.default_rng(seed)
    scene, L = random_scene(rng, gravity=bool(rng.random() < 0.5), n_cables=int(rng.integers(1, 7)),
                            axis_effector=bool(rng.random() < 0.5))
    model = build(scene)
    forward = model.solve()
    targets = model.effector_positions(forward.state)
    out = invert(model, targets, actuation=np.zeros(model.n_cables))
    assert out.reached and out.equilibrium, (out.status, out.errors)
    assert np.max(out.errors) <= 1e-6
    lower, upper = model.actuator_bounds
    assert np.all(out.actuation >= lower) and np.all(out.actuation <= upper)
    check = model.solve(out.actuation, initial=out.state)
    # 1e-6 m plus what a 1e-9 scaled residual can move the effectors
    assert np.max(np.abs(model.effector_positions(check.state) - targets)) <= 1e-6 + 1e-9 * L
