"""Contact on robots and scenes nobody tuned for (docs/contact.md, "Fuzzing"): seeded random
scenes, every converged state checked, every failure a clear message.

    python -m benchmarks.bench_contact_fuzz [--seconds 240] [--first-seed 0]

* forward: per seed a random robot — one of tests/robots.py's tendon robots (discs declared on
  some or all vertebrae, optionally capsule segments) or a cantilever beam (capsule radius,
  discs or both) under gravity and/or a tip load — and 1–3 random obstacles of every type
  (plane, sphere, a point stop = sphere of radius 0, capsule, box turned by a random
  quaternion, inline triangle-mesh box or tetrahedron), each placed across the path of a frame
  between its rest position and where the robot goes without the obstacle, so the robot
  touches it; Coulomb μ = 0 or > 0. Checked at every converged state: gap ≥ −1e-9 m, force ≥ 0,
  gap·force ≤ 1e-12 (pressed gaps also within the solve's own tolerance, ACTIVE_GAP of the
  length), friction within its cone, no two discs overlapping, and the balance ∇E − Gᵀλ
  (recomputed here from the reported forces) small against the forces. A solve that does not
  converge must say why (a message, never a traceback); a scene refused must be a SceneError
  naming file and field.
* inverse: for the tendon robots with obstacles, a target made by a forward solve (random
  tensions within bounds), reached by the converged inverse; and 8 ticks towards it: no state
  in an obstacle (converged: 1e-9 m, ticks: 1e-6 m) and no exception.
* scene input: bad obstacle / disc fields (wrong types, NaN, inf, negative or zero sizes,
  unknown or misspelt fields, bad quaternions, bad meshes inline and as files): every one must
  raise a SceneError naming the field (no other exception, no acceptance).

Writes benchmarks/results/contact_fuzz.json (``--output``: another name; contact_fuzz_31.json
holds the seeds 31–110).
"""

from __future__ import annotations

import argparse
import math
import re
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, loadavg, log, now, write_json
from vertebra.designer.threads import pin_blas_threads
from vertebra import __version__, solver
from vertebra.core.errors import ConvergenceError, SceneError, VertebraError
from vertebra.solver import contact

GAP = -1e-9            # m: deepest gap at a converged state
PRODUCT = 1e-12        # N·m: |gap·force| at a converged state
TICK_GAP = -1e-6       # m: deepest gap of a tick's state (1 % of the tick tolerance, docs/contact.md)
BALANCE = 1e-6         # the balance's residual, relative to the largest force on a frame
CONE = 1e-9            # friction: |f_t| ≤ μ f_n (1 + CONE) + tiny
SOLVE_LIMIT = 20.0     # s per solve before it is stopped and counted as over the limit ("hang")


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def limited(function, *args, seconds=SOLVE_LIMIT, **kwargs):
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        return function(*args, **kwargs)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)


def _log_uniform(rng, low, high):
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _unit(v):
    return v / np.linalg.norm(v)


def _quaternion(rng):
    q = rng.normal(size=4)
    return (q / np.linalg.norm(q)).tolist()


# --- robots ------------------------------------------------------------------------------------

def tendon(rng) -> dict:
    from robots import tendon_robot

    scene = tendon_robot(rng)
    holes = max(c["radius"] for c in scene["cable"])
    spacing = min(s["length"] for s in scene["segment"])
    radius = holes * float(rng.uniform(1.05, 2.0))
    disc = {"disc_radius": radius, "disc_thickness": min(spacing * float(rng.uniform(0.05, 0.4)), 1.9 * radius)}
    everywhere = rng.random() < 0.7
    segments = []
    for s in scene["segment"]:
        s = dict(s)
        if everywhere or rng.random() < 0.5:
            s["vertebra"] = dict(s.get("vertebra", {}), **disc)
        if rng.random() < 0.3:
            s["contact_radius"] = s["section"]["radius"] * float(rng.uniform(1.0, 3.0))
        segments.append(s)
    scene["segment"] = segments
    if rng.random() < 0.5:
        scene["base"] = dict(disc)
    return scene


def beam(rng) -> dict:
    length = _log_uniform(rng, 0.05, 0.6)
    count = int(rng.integers(1, 12))
    radius = _log_uniform(rng, 3e-4, 3e-3)
    E = _log_uniform(rng, 1e7, 2e11)
    EI = E * math.pi * radius ** 4 / 4
    segment = {"type": "beam", "count": count, "elements": int(rng.integers(1, 5)), "length": length / count,
               "youngs_modulus": E, "poisson_ratio": float(rng.uniform(0.25, 0.49)),
               "section": {"shape": "circle", "radius": radius}, "density": float(rng.uniform(500, 8000))}
    shape = rng.integers(0, 3)
    if shape in (0, 2):
        segment["contact_radius"] = radius * float(rng.uniform(1.0, 4.0))
    if shape in (1, 2):
        disc = _log_uniform(rng, 2 * radius, 0.03)
        segment["vertebra"] = {"mass": float(rng.uniform(0, 2e-3)), "disc_radius": disc,
                               "disc_thickness": min(0.4 * length / count, 0.5 * _log_uniform(rng, 2 * radius, 0.02),
                                                     1.9 * disc)}
    scene = {"name": "fuzz-beam", "segment": [segment], "effector": [{"name": "tip", "vertebra": -1}]}
    if rng.random() < 0.7:
        scene["load"] = [{"vertebra": -1, "force": (float(rng.uniform(0.2, 5)) * EI / length ** 2
                                                     * _unit(rng.normal(size=3) * [1, 1, 0.3])).tolist()}]
    if rng.random() < 0.5 or "load" not in scene:
        weight = float(np.sum(solver.build_model(solver.parse_scene({"segment": [dict(
            segment, vertebra={"mass": segment.get("vertebra", {}).get("mass", 0.0)})]})).frame_mass))
        g = float(rng.uniform(0.5, 5)) * EI / length ** 2 / max(weight, 1e-12)
        scene["gravity"] = {"vector": (g * _unit(rng.normal(size=3) * [1, 1, 0.3])).tolist()}
    return scene


# --- obstacles ---------------------------------------------------------------------------------

def box_mesh(center, half, rotation):
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * half
    vertices = corners @ rotation.T + center
    triangles = []
    for a, b, c, d in [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]:
        for t in ((a, b, c), (a, c, d)):
            triangles.append(_outward(vertices, t, center))
    return vertices, triangles


def tetra_mesh(center, size, rng):
    vertices = center + size * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) \
        @ np.linalg.qr(rng.normal(size=(3, 3)))[0].T
    return vertices, [_outward(vertices, t, center) for t in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3))]


def _outward(vertices, t, center):
    p = vertices[list(t)]
    return list(t) if np.cross(p[1] - p[0], p[2] - p[0]) @ (p.mean(0) - center) > 0 else [t[0], t[2], t[1]]


def obstacle(rng, kind, at, direction, scale):
    """An obstacle of ``kind`` whose surface passes near ``at`` and faces −``direction`` (the
    way the robot comes), sized by ``scale``."""
    from vertebra.core.lie import qmatrix

    d = _unit(direction)
    if kind == "plane":
        return {"type": "plane", "point": at.tolist(), "normal": (-d).tolist()}
    if kind in ("sphere", "point"):
        r = 0.0 if kind == "point" else _log_uniform(rng, 0.05, 2.0) * scale
        return {"type": "sphere", "center": (at + r * d).tolist(), "radius": r}
    if kind == "capsule":
        r = _log_uniform(rng, 0.02, 0.5) * scale
        side = _unit(np.cross(d, rng.normal(size=3)))
        half = _log_uniform(rng, 0.2, 2.0) * scale
        c = at + r * d
        return {"type": "capsule", "a": (c - half * side).tolist(), "b": (c + half * side).tolist(), "radius": r}
    half = rng.uniform(0.1, 1.0, 3) * scale
    q = _quaternion(rng)
    R = qmatrix(np.array(q))
    if kind == "box":
        center = at + d * float(np.abs(R.T @ d) @ half)
        return {"type": "box", "center": center.tolist(), "half_extents": half.tolist(), "quaternion": q}
    if kind == "mesh_box":
        center = at + d * float(np.abs(R.T @ d) @ half)
        vertices, triangles = box_mesh(center, half, R)
    else:
        size = float(half.mean())
        vertices, triangles = tetra_mesh(np.zeros(3), size, rng)
        vertices = vertices + at + d * float(np.max(vertices @ -d))
    return {"type": "mesh", "vertices": np.asarray(vertices).tolist(), "triangles": triangles}


KINDS = ("plane", "sphere", "point", "capsule", "box", "mesh_box", "mesh_tetra")


# --- checks ------------------------------------------------------------------------------------

def _forces_on_frames(model, state, contacts):
    """∇E − Gᵀλ from the reported contacts (matched to the candidates at the state by bodies and
    point), the friction forces included; and the largest generalised force."""
    found = contact.evaluate(model.trunk.contact, state)
    n = state.positions.shape[0]
    names = [contact.bodies(model.trunk.contact, k) for k in found.key]
    lam = np.zeros(found.count)
    unmatched = 0
    extra = np.zeros((n, 6))
    for c in contacts:
        if c.force == 0.0 and c.friction is None:
            continue
        hits = [i for i in range(found.count) if names[i] == c.bodies
                and np.linalg.norm(found.point[i] - c.point) <= 1e-9 * (1.0 + model.trunk.contact.length)]
        if not hits:
            unmatched += 1
            continue
        i = hits[0]
        lam[i] = c.force
        if c.friction is not None and any(c.friction):
            ft = np.array(c.friction)
            for side in range(2):
                f = found.frames[i, side]
                if f < 0:
                    continue
                weight = float(found.rows[i, side, :3] @ found.normal[i])
                extra[f, :3] += weight * ft
                extra[f, 3:] += weight * np.cross(found.point[i] - found.origin[i, side], ft)
    return found.forces(lam, n) + extra, unmatched


def check_state(model, result, actuation) -> list[str]:
    problems = []
    length = model.trunk.contact.length
    for c in result.contacts:
        if not c.force >= 0.0:
            problems.append(f"negative force {c.force:.3g} N at {c.bodies}")
        if not c.gap >= GAP:
            problems.append(f"gap {c.gap:.3g} m at {c.bodies}")
        if abs(c.gap * c.force) > PRODUCT and abs(c.gap) > contact.ACTIVE_GAP * length:
            problems.append(f"gap·force {c.gap * c.force:.3g} at {c.bodies} (gap {c.gap:.3g} m, force {c.force:.3g} N)")
        if c.friction is not None:
            mu = _mu(model, c.bodies[1])
            ft = float(np.linalg.norm(c.friction))
            if ft > mu * c.force * (1 + CONE) + 1e-12:
                problems.append(f"friction {ft:.6g} N outside the cone μ f_n = {mu * c.force:.6g} N at {c.bodies}")
    if model.trunk.contact.disc_frame.size >= 2:
        first, second = np.triu_indices(model.trunk.contact.disc_frame.size, 1)
        gaps = contact.disc_gaps(model.trunk.contact, result.state, first, second)
        if gaps.size and gaps.min() < GAP:
            k = int(np.argmin(gaps))
            problems.append(f"discs {first[k]} and {second[k]} overlap by {-gaps[k]:.3g} m")
    ev = model.evaluate(result.state, result.actuation)
    applied, unmatched = _forces_on_frames(model, result.state, result.contacts)
    if unmatched:
        problems.append(f"{unmatched} reported contacts not found at the state")
    balance = (ev.gradient - applied)[1:]
    weights = np.array([1.0] * 3 + [1.0 / model.trunk.frames.length_scale] * 3)
    # against the loads' scale (the gradient at rest under the same loads, as Newton's reference)
    # and the contact forces'
    rest = model.evaluate(model.trunk.rest_state, result.actuation).gradient[1:]
    scale = max(float(np.abs(rest * weights).max()), float(np.abs(applied[1:] * weights).max()), 1e-300)
    if any(c.friction is not None and c.force > 0 and c.bodies[0].startswith("link") for c in result.contacts):
        # a chord's frictional contact holds the chord parameter of the increment's start: how its
        # tangential force splits between the two frames is not in the report
        return problems, None
    if any(c.friction is not None and c.force > 0 for c in result.contacts):
        # a frictional contact's tangential force acts at the material point it holds since the
        # increment began (docs/contact.md, friction: it pivots, rolls only between increments),
        # not at the reported nearest point: the moments are not checked from the report
        weights = weights * [1, 1, 1, 0, 0, 0]
    relative = float(np.abs(balance * weights).max()) / scale
    if relative > BALANCE:
        problems.append(f"balance residual {relative:.3g} of the largest force")
    return problems, relative


def _mu(model, name):
    index = int(name.split()[1])
    return model.trunk.contact.obstacles[index].friction


# --- one random scene --------------------------------------------------------------------------

def draw(seed):
    rng = np.random.default_rng(seed)
    scene = tendon(rng) if rng.random() < 0.6 else beam(rng)
    return rng, scene


def placed(rng, scene):
    """The scene with obstacles across the robot's path (None when the robot barely moves or the
    obstacle-free solve fails), and what was done."""
    free = solver.build_model(solver.parse_scene(scene))
    result = limited(free.solve, raise_on_failure=False)
    if not result.converged:
        return None, "obstacle-free solve failed: " + result.message[:120]
    x0 = _rest_positions(free)
    x1 = result.state.positions
    move = np.linalg.norm(x1 - x0, axis=1)
    total = sum(s["count"] * s["length"] for s in scene["segment"])
    if move.max() < 1e-4 * total:
        return None, "robot barely moves"
    obstacles, away = [], []
    mu = float(rng.choice([0.0, 0.0, 0.0, 0.3, 1.0]))
    for _ in range(int(rng.integers(1, 4))):
        candidates = np.flatnonzero(move > 0.3 * move.max())
        k = int(rng.choice(candidates))
        kind = str(rng.choice(KINDS))
        s = float(rng.uniform(0.3, 0.85))
        at = x0[k] + s * (x1[k] - x0[k])
        # stand off the rest shape: the widest body around the frame
        o = obstacle(rng, kind, at, x1[k] - x0[k], scale=0.3 * total)
        away.append(_unit(x1[k] - x0[k]))
        if mu:
            o["friction"] = mu
        obstacles.append(o)
    # moved away along the path until the rest shape is clear of every obstacle (refused otherwise)
    scene = dict(scene, obstacle=obstacles)
    for _ in range(8):
        try:
            solver.build_model(solver.parse_scene(scene))
            break
        except SceneError as error:
            found = re.search(r"obstacle (\d+) \(\w+\) overlap by ([0-9.e+-]+) m", str(error))
            if not found:
                break
            k, depth = int(found.group(1)), float(found.group(2))
            _shift(obstacles[k], away[k] * (1.2 * depth + 1e-3 * total))
    return scene, f"μ={mu}, " + ", ".join(o["type"] for o in obstacles)


def _shift(o, v):
    for key in ("point", "center", "a", "b"):
        if key in o:
            o[key] = (np.array(o[key]) + v).tolist()
    if "vertices" in o:
        o["vertices"] = (np.array(o["vertices"]) + v).tolist()


def _rest_positions(model):
    return model.trunk.rest_state.positions


def run_scene(seed) -> dict:
    rng, base = draw(seed)
    row = {"seed": seed, "robot": base.get("name", "")}
    try:
        scene, note = placed(rng, base)
    except Hang:
        return dict(row, outcome="skipped", note="obstacle-free solve hung")
    except VertebraError as error:
        return dict(row, outcome="skipped", note=f"obstacle-free: {type(error).__name__}: {error}"[:200])
    row["note"] = note
    if scene is None:
        return dict(row, outcome="skipped")
    try:
        model = solver.build_model(solver.parse_scene(scene))
    except SceneError as error:
        ok = bool(error.field) and "overlap" in str(error) or "inside" in str(error)
        return dict(row, outcome="refused" if ok else "bad_error", message=str(error)[:300])
    except Exception as error:             # noqa: BLE001 - a traceback is what is looked for
        return dict(row, outcome="traceback", message="".join(traceback.format_exception(error))[-1500:])
    row["obstacles"] = scene["obstacle"]
    start = time.perf_counter()
    try:
        result = limited(model.solve, raise_on_failure=False)
    except Hang:
        return dict(row, outcome="hang", seconds=SOLVE_LIMIT)
    except VertebraError as error:
        return dict(row, outcome="error", message=f"{type(error).__name__}: {error}"[:300])
    except Exception as error:             # noqa: BLE001
        return dict(row, outcome="traceback", message="".join(traceback.format_exception(error))[-1500:])
    row.update(seconds=time.perf_counter() - start, iterations=int(result.iterations),
               pressed=sum(c.force > 0 for c in result.contacts))
    if not result.converged:
        clear = bool(result.message) and "Traceback" not in result.message
        return dict(row, outcome="failed" if clear else "unclear_failure", message=result.message[:300])
    problems, balance = check_state(model, result, None)
    row["balance"] = balance
    if problems:
        return dict(row, outcome="violated", problems=problems[:6])
    row["outcome"] = "converged"
    if "cable" in scene and scene.get("effector") and rng.random() < 0.5:
        row["inverse"] = inverse_check(rng, model, scene)
    return row


def inverse_check(rng, model, scene) -> dict:
    from vertebra.solver.inverse import InverseController, InverseSettings

    cables = scene["cable"]
    out = {}
    try:
        a = np.array([float(rng.uniform(0.0, 1.0)) * min(c["max_tension"], 3 * c["tension"] + 1e-3) for c in cables])
        target_result = limited(model.solve, a, raise_on_failure=False)
        if not target_result.converged:
            return {"outcome": "target solve failed"}
        target = model.effector_positions(target_result.state)[0]
        controller = InverseController(model, InverseSettings(mode="converged", tolerance=1e-6, max_iterations=15,
                                                              time_budget=20.0))
        step = limited(controller.step, target[None])
        out["reached"] = bool(step.reached)
        out["error_m"] = float(np.max(step.errors))
        gap = float(contact.evaluate(model.trunk.contact, step.state).gap.min(initial=np.inf))
        out["deepest_gap_m"] = gap
        out["in_obstacle"] = bool(step.equilibrium and gap < GAP)
        ticks = InverseController(model, InverseSettings(mode="tick", tolerance=1e-4))
        deepest = np.inf
        for _ in range(8):
            tick = limited(ticks.step, target[None], seconds=10.0)
            deepest = min(deepest, float(contact.evaluate(model.trunk.contact, tick.state).gap.min(initial=np.inf)))
        out["tick_deepest_gap_m"] = deepest
        out["tick_in_obstacle"] = bool(deepest < TICK_GAP)
        out["outcome"] = "ok" if not (out["in_obstacle"] or out["tick_in_obstacle"]) else "penetrated"
    except Hang:
        out["outcome"] = "hang"
    except VertebraError as error:
        out.update(outcome="error", message=f"{type(error).__name__}: {error}"[:300])
    except Exception as error:             # noqa: BLE001
        out.update(outcome="traceback", message="".join(traceback.format_exception(error))[-1500:])
    return out


# --- scene input -------------------------------------------------------------------------------

BASE = {"segment": [{"type": "beam", "count": 3, "length": 0.02, "youngs_modulus": 1e9,
                     "section": {"shape": "circle", "radius": 0.001}, "contact_radius": 0.001}]}
GOOD = {"plane": {"type": "plane", "point": [0.1, 0, 0], "normal": [-1, 0, 0]},
        "sphere": {"type": "sphere", "center": [0.1, 0, 0], "radius": 0.01},
        "capsule": {"type": "capsule", "a": [0.1, -0.1, 0], "b": [0.1, 0.1, 0], "radius": 0.01},
        "box": {"type": "box", "center": [0.1, 0, 0], "half_extents": [0.01, 0.02, 0.03],
                "quaternion": [1, 0, 0, 0]},
        "mesh": {"type": "mesh", "vertices": [[0.1, 0, 0], [0.2, 0, 0], [0.1, 0.1, 0], [0.1, 0, 0.1]],
                 "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}}
BAD_VALUES = [float("nan"), float("inf"), -1.0, 0.0, "x", True, [], [1.0], [[1.0, 2.0, 3.0]], {"a": 1}, 1e300,
              [float("nan"), 0, 0], [0, 0, 0], [1, 2], [0, 0, 0, 0], [1, 2, 3, 4]]


def _expect_refusal(data, base_dir=None) -> str | None:
    """None when ``data`` is refused with a SceneError naming its file and field; else what happened."""
    try:
        model = solver.build_model(solver.parse_scene(data, base_dir=base_dir) if base_dir else solver.parse_scene(data))
    except SceneError as error:
        if not error.field:
            return f"SceneError without a field: {error}"
        return None
    except Exception as error:             # noqa: BLE001
        return f"{type(error).__name__}: {error}"[:300] + " | " + traceback.format_exc().splitlines()[-3][:200]
    try:
        x = contact.evaluate(model.trunk.contact, _rest_positions_state(model))
        finite = bool(np.all(np.isfinite(x.gap)))
    except Exception as error:             # noqa: BLE001
        return f"accepted, then {type(error).__name__} in evaluate: {error}"[:300]
    return None if finite else "accepted with non-finite gaps"


def _rest_positions_state(model):
    return model.trunk.rest_state


def scene_input_fuzz(rng, count) -> dict:
    failures, accepted, tried = [], [], 0
    tmp = Path(tempfile.mkdtemp(prefix="contactfuzz"))
    cases = []
    for kind, good in GOOD.items():
        for field in list(good) + ["friction", "radus", "extra"]:
            if field == "type":
                continue
            for value in BAD_VALUES:
                cases.append((kind, field, value))
    rng.shuffle(cases)
    for kind, field, value in cases[:count]:
        o = dict(GOOD[kind])
        o[field] = value
        tried += 1
        problem = _expect_refusal(dict(BASE, obstacle=[o]))
        if problem is not None:
            failures.append({"kind": kind, "field": field, "value": repr(value), "problem": problem})
        elif False:
            accepted.append(None)
    # disc and capsule fields
    for where, field in (("vertebra", "disc_radius"), ("vertebra", "disc_thickness"), ("segment", "contact_radius"),
                         ("base", "disc_radius"), ("base", "disc_thickness")):
        for value in BAD_VALUES[:12]:
            data = {"segment": [dict(BASE["segment"][0])]}
            if where == "vertebra":
                data["segment"][0]["vertebra"] = {"disc_radius": 0.01, "disc_thickness": 0.002, field: value}
            elif where == "segment":
                data["segment"][0][field] = value
            else:
                data["base"] = {"disc_radius": 0.01, "disc_thickness": 0.002, field: value}
            tried += 1
            problem = _expect_refusal(data)
            if problem is not None:
                failures.append({"kind": where, "field": field, "value": repr(value), "problem": problem})
    # mesh files
    files = {"garbage.stl": b"not a mesh at all", "empty.stl": b"", "short.stl": b"\0" * 84,
             "nan.stl": "solid x\nfacet normal 0 0 0\nouter loop\nvertex nan 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                        "endloop\nendfacet\nendsolid x\n".encode(),
             "inf.obj": b"v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
             "flat.obj": b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
             "zero.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
             "range.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
             "text.obj": b"v a b c\nf 1 2 3\n",
             "noface.obj": b"v 0 0 0\n",
             "binary.obj": bytes(range(256)),
             "mesh.ply": b"ply\n", "dir.stl": None}
    for name, content in files.items():
        path = tmp / name
        if content is None:
            path.mkdir(exist_ok=True)
        else:
            path.write_bytes(content)
        tried += 1
        problem = _expect_refusal(dict(BASE, obstacle=[{"type": "mesh", "path": name, "offset": [0.1, 0, 0]}]),
                                  base_dir=tmp)
        if problem is not None:
            failures.append({"kind": "mesh file", "field": "path", "value": name, "problem": problem})
    return {"tried": tried, "failures": failures}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=240.0)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--seeds", type=int, default=10_000)
    parser.add_argument("--input-cases", type=int, default=400)
    parser.add_argument("--output", default="contact_fuzz.json", help="the file written in benchmarks/results")
    args = parser.parse_args(argv)
    pin_blas_threads()          # one BLAS thread: threaded BLAS on the small solves is 40x slower on a busy machine
    sys.path.insert(0, str(ROOT / "tests"))
    began, load = time.perf_counter(), [loadavg()]
    inputs = scene_input_fuzz(np.random.default_rng(12345), args.input_cases)
    log(f"scene input: {inputs['tried']} cases, {len(inputs['failures'])} failures")
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        if time.perf_counter() - began > args.seconds:
            break
        row = run_scene(seed)
        rows.append(row)
        inv = row.get("inverse", {}).get("outcome", "")
        log(f"seed {seed}: {row['outcome']} {row.get('note', '')} {inv} "
            f"{row.get('message', '')[:160] if row['outcome'] != 'converged' else ''} {row.get('problems', '')}")
    load.append(loadavg())
    outcomes = {}
    for r in rows:
        outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
    inverse = [r["inverse"] for r in rows if "inverse" in r]
    bad = ("traceback", "violated", "hang", "unclear_failure", "bad_error")
    summary = {"vertebra_version": __version__, "date": now(), "loadavg": load, "seconds": time.perf_counter() - began,
               "seeds": [rows[0]["seed"], rows[-1]["seed"]] if rows else [],
               "outcomes": outcomes,
               "bad": [r for r in rows if r["outcome"] in bad],
               "failed": [{"seed": r["seed"], "note": r.get("note"), "message": r.get("message")}
                          for r in rows if r["outcome"] in ("failed", "error")],
               "inverse": {"runs": len(inverse), "outcomes": {o: sum(i["outcome"] == o for i in inverse)
                                                              for o in sorted({i["outcome"] for i in inverse})},
                           "reached": sum(bool(i.get("reached")) for i in inverse),
                           "bad": [dict(i, seed=r["seed"]) for r in rows if "inverse" in r
                                   for i in [r["inverse"]] if i["outcome"] not in ("ok", "target solve failed")]},
               "largest_balance": max((r.get("balance") or 0.0 for r in rows if r["outcome"] == "converged"), default=0.0),
               "balance_not_checked": sum(r["outcome"] == "converged" and r.get("balance", 0.0) is None for r in rows),
               "scene_input": inputs, "rows": rows}
    print(f"forward: {len(rows)} scenes, outcomes {outcomes}; largest balance residual {summary['largest_balance']:.3g}")
    print(f"inverse: {summary['inverse']['runs']} runs, {summary['inverse']['outcomes']}, "
          f"{summary['inverse']['reached']} reached")
    print(f"scene input: {inputs['tried']} cases, {len(inputs['failures'])} not refused cleanly")
    for r in summary["bad"]:
        print("BAD", r["seed"], r["outcome"], r.get("note"), r.get("problems") or r.get("message", "")[-400:])
    for f in inputs["failures"][:20]:
        print("INPUT", f)
    write_json(summary, RESULTS / args.output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
