"""Seeded generators of robots the gallery does not contain (robustness tests and
``benchmarks/bench_robustness.py``).

* :func:`tendon_robot` — a random tendon robot: 1–8 vertebrae in 1–3 beam segments of 2–4
  links each, E 1 MPa–100 GPa, backbone radius 0.3–3 mm, vertebrae 5–40 mm apart, 1–8 cables
  at 3–20 mm (some at their tension bounds, some slack), optionally gravity and a dead tip
  force of up to PL²/EI = 10 (half of them nearly along the compressed axis). The tensions are
  scaled so that, in linear theory, no link turns more than 60°, the whole robot at most 1.5
  turns, and no cable piece shortens by more than 70 % of its length; loads and gravity come on
  top, so some draws are not representable — :func:`representable` tells.
* :func:`representable` — an independent check of a drawn robot: the same scene with 4× the
  links, solved by load continuation (20 stages); its equilibrium must turn no original link
  by more than 60° and the robot by at most 1.5 turns, and keep every cable piece at ≥ 25 % of
  its rest length (the vertebrae's discs do not collide).
* :func:`draw_representable` — draws until a robot passes the check.
* :func:`control_robot` — a random robot of a control experiment's size: 3–6 vertebrae 20–40 mm
  apart, 2–3 links each, E 0.5–100 GPa, groups of four tendons ending at 1–4 vertebrae, bounded
  tensions strong enough to bend it far beyond what a link represents, optional gravity (its
  weight at most WL²/EI = 2: a trunk that stands up).
* :func:`reachable_target` — a tip target a given distance from rest that a forward solution
  within the bounds reaches; :func:`reachable_circle` — a closed loop of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vertebra import solver
from vertebra.core.lie import qlog, qmatrix, qmul

TURN = math.radians(60.0)      # largest rotation of a link in a representable equilibrium
TURNS = 3.0 * math.pi          # largest total rotation (1.5 turns)
PIECE = 0.25                   # shortest cable piece, relative to its rest length
REFINE = 4                     # links of the reference per link of the robot


def _log_uniform(rng, low, high) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def tendon_robot(rng) -> dict:
    """A random tendon robot (module docstring) as a scene dictionary."""
    n_vertebrae = int(rng.integers(1, 9))
    groups = int(rng.integers(1, min(3, n_vertebrae) + 1))
    cuts = sorted(rng.choice(np.arange(1, n_vertebrae), groups - 1, replace=False).tolist()) if groups > 1 else []
    counts = np.diff([0, *cuts, n_vertebrae]).tolist()
    youngs = _log_uniform(rng, 1e6, 1e11)
    spacing = _log_uniform(rng, 0.005, 0.04)
    radius = _log_uniform(rng, 3e-4, 3e-3)
    segments = [dict(type="beam", count=int(count), length=spacing * float(rng.uniform(0.8, 1.25)),
                     elements=int(rng.integers(2, 5)), youngs_modulus=youngs * 10 ** float(rng.uniform(-0.2, 0.2)),
                     poisson_ratio=float(rng.uniform(0.25, 0.49)), section=dict(shape="circle", radius=radius),
                     density=float(rng.uniform(500, 8000)),
                     vertebra=dict(mass=float(rng.uniform(0, 1)) * 1e-3 * (radius / 1e-3) ** 2 * spacing / 0.01))
                for count in counts]
    length = sum(s["count"] * s["length"] for s in segments)
    EI = min(s["youngs_modulus"] for s in segments) * math.pi * radius ** 4 / 4
    cables = []
    for k in range(int(rng.integers(1, 9))):
        first = int(rng.integers(1, n_vertebrae + 1))
        hole = float(rng.uniform(0.003, 0.02))
        cables.append({"name": f"c{k}", "radius": hole, "angle_deg": float(rng.uniform(0, 360)), "from": first,
                       "to": int(rng.integers(first, n_vertebrae + 1)), "tension": float(rng.uniform(0, 1)) / hole})
    _scale_tensions(rng, cables, segments, EI)
    scene = dict(name="random-tendon-robot", segment=segments, cable=cables, effector=[dict(name="tip", vertebra=-1)])
    if rng.random() < 0.6:
        axial = rng.random() < 0.5
        direction = np.array([0.0, 0.0, -1.0]) + 0.05 * rng.normal(size=3) if axial else rng.normal(size=3)
        force = float(rng.uniform(0, 10)) * EI / length ** 2 * direction / np.linalg.norm(direction)
        scene["load"] = [dict(vertebra=-1, force=force.tolist())]
    if rng.random() < 0.5:
        weight = float(np.sum(solver.build_model(solver.parse_scene(dict(segment=segments))).frame_mass))
        direction = np.array([0.0, 0.0, -1.0]) if rng.random() < 0.5 else rng.normal(size=3)
        g = float(rng.uniform(0, 10)) * EI / length ** 2 / weight
        scene["gravity"] = {"vector": (g * direction / np.linalg.norm(direction)).tolist()}
    return scene


def _scale_tensions(rng, cables, segments, EI) -> None:
    """Scale the tensions so that the cables' combined moment bends no gap between vertebrae
    beyond 60° per link or 0.7/r (r the largest hole radius there: the inner cable piece keeps
    30 % of its length), and the robot by at most a random share of 1.5 turns (linear theory);
    then set the bounds (a fifth at their upper bound, a tenth slack)."""
    gaps = [(s["length"], s["elements"]) for s in segments for _ in range(s["count"])]
    scale, total = np.inf, 0.0
    for gap, (length, elements) in enumerate(gaps, start=1):
        moment, widest = np.zeros(2), 0.0
        for c in cables:
            if c["from"] <= gap <= c["to"]:
                angle = math.radians(c["angle_deg"])
                moment += c["tension"] * c["radius"] * np.array([math.cos(angle), math.sin(angle)])
                widest = max(widest, c["radius"])
        curvature = float(np.linalg.norm(moment)) / EI
        if curvature > 0.0:
            scale = min(scale, min(TURN * elements / length, 0.7 / widest) / curvature)
            total += curvature * length
    scale = 1.0 if total == 0.0 else min(scale * float(rng.uniform(0.6, 1.3)),
                                         float(rng.uniform(0.2, 1.0)) * TURNS / total)
    for c in cables:
        c["tension"] *= scale
        u = rng.random()
        c["min_tension"] = 0.0
        c["max_tension"] = c["tension"] if u < 0.2 else c["tension"] * float(rng.uniform(1, 3))
        if u > 0.9:
            c["tension"] = 0.0


@dataclass(frozen=True)
class Check:
    """What :func:`representable` found on the refined reference."""

    converged: bool
    largest_turn: float = math.nan     # largest rotation of an original link (rad)
    total_turn: float = math.nan       # sum of the rotations along the robot (rad)
    shortest_piece: float = math.nan   # shortest cable piece / its rest length
    tip: np.ndarray | None = None      # the reference's tip position

    @property
    def ok(self) -> bool:
        return self.converged and self.largest_turn <= TURN and self.total_turn <= TURNS and \
            self.shortest_piece >= PIECE


def refined(scene: dict, factor: int = REFINE) -> dict:
    """The scene with ``factor`` × the links per repetition."""
    return dict(scene, segment=[dict(s, elements=s["elements"] * factor) for s in scene["segment"]])


def _relative_turns(quaternions: np.ndarray) -> np.ndarray:
    conjugate = quaternions[:-1] * np.array([1.0, -1.0, -1.0, -1.0])
    return np.linalg.norm(qlog(qmul(conjugate, quaternions[1:])), axis=1)


def representable(scene: dict) -> Check:
    """The independent check of :func:`tendon_robot`'s draws (module docstring)."""
    reference = solver.build_model(solver.parse_scene(refined(scene)))
    result = reference.solve(load_steps=20, max_iterations=200, raise_on_failure=False)
    if not result.converged:
        return Check(False)
    state = result.state
    turns = _relative_turns(state.quaternions[::REFINE])      # every REFINE-th frame ends an original link
    trunk = reference.trunk
    shortest = 1.0
    if trunk.actuators.n_cables:
        lengths = trunk.cables.spans(state.positions, qmatrix(state.quaternions))[2]
        shortest = float(np.min(lengths / trunk.rest_piece_lengths))
    return Check(True, float(turns.max()), float(_relative_turns(state.quaternions).sum()), shortest,
                 state.positions[-1].copy())


def draw_representable(rng, attempts: int = 100) -> tuple[dict, Check, int]:
    """(scene, its check, draws taken): the first :func:`tendon_robot` that passes :func:`representable`."""
    for draw in range(1, attempts + 1):
        scene = tendon_robot(rng)
        check = representable(scene)
        if check.ok:
            return scene, check, draw
    raise RuntimeError(f"no representable robot in {attempts} draws")


def control_robot(rng, *, gravity: bool) -> dict:
    """A random robot of a control experiment's size (module docstring) with a tip effector."""
    n_vertebrae = int(rng.integers(3, 7))
    spacing = float(rng.uniform(0.02, 0.04))
    radius = _log_uniform(rng, 5e-4, 2e-3)
    youngs = _log_uniform(rng, 5e8, 1e11)
    EI = youngs * math.pi * radius ** 4 / 4
    length = n_vertebrae * spacing
    hole = float(rng.uniform(0.008, 0.02))
    ends = sorted(rng.choice(np.arange(2, n_vertebrae + 1), int(rng.integers(1, min(4, n_vertebrae - 1) + 1)),
                             replace=False).tolist())
    # one tendon alone at its bound would bend the robot by 2–6 rad (linear theory)
    largest = float(rng.uniform(2.0, 6.0)) * EI / (hole * length)
    cables = [{"name": f"t{4 * g + j + 1}", "radius": hole, "angle_deg": 90.0 * j + 22.5 * g, "from": 1, "to": end,
               "tension": 0.0, "min_tension": 0.0, "max_tension": largest}
              for g, end in enumerate(ends) for j in range(4)]
    density = min(float(rng.uniform(1000, 8000)), EI / (9.81 * math.pi * radius ** 2 * length ** 3))
    heaviest = 2.0 * EI / length ** 2 / 9.81 / n_vertebrae - density * math.pi * radius ** 2 * spacing
    mass = min(float(rng.uniform(0.002, 0.01)), max(heaviest * float(rng.uniform(0.1, 1.0)), 0.0))
    scene = dict(name="random-control-robot", cable=cables, effector=[dict(name="tip", vertebra=-1)],
                 segment=[dict(type="beam", count=n_vertebrae, length=spacing, elements=int(rng.integers(2, 4)),
                               youngs_modulus=youngs, poisson_ratio=0.35, section=dict(shape="circle", radius=radius),
                               density=density, vertebra=dict(mass=mass))])
    if gravity:
        scene["gravity"] = {"vector": [0.0, 0.0, -9.81]}
    return scene


def _pattern(model, scene: dict, direction: float, amplitude: float) -> np.ndarray:
    """Tensions pulling towards ``direction`` (rad about the base z axis): ``amplitude·max(0,
    cos(direction − angle))`` on each tendon, clipped to the bounds."""
    angles = np.array([math.radians(c["angle_deg"]) for c in scene["cable"]])
    lower, upper = model.actuator_bounds
    return np.clip(amplitude * np.maximum(0.0, np.cos(direction - angles)), lower, upper)


def _amplitude(model, scene: dict, direction: float, distance: float) -> float:
    """The tension amplitude of :func:`_pattern` that moves the tip ``distance`` from rest
    (bisection, counting an amplitude whose equilibrium cannot be represented as too far;
    the largest bound when that is not enough)."""
    rest = model.effector_positions(model.solve(np.zeros(len(scene["cable"]))).state)[-1]
    low, high = 0.0, float(np.max(model.actuator_bounds[1]))
    for _ in range(40):
        middle = 0.5 * (low + high)
        result = model.solve(_pattern(model, scene, direction, middle), raise_on_failure=False)
        near = result.converged and np.linalg.norm(model.effector_positions(result.state)[-1] - rest) < distance
        low, high = (middle, high) if near else (low, middle)
    return low


def reachable_target(model, scene: dict, rng, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(tip target (1, 3), the tensions that reach it): a forward solution within the bounds
    whose tip lies ``distance`` from rest (or as far as the bounds allow), bending towards a
    random direction."""
    direction = float(rng.uniform(0, 2 * math.pi))
    tensions = _pattern(model, scene, direction, _amplitude(model, scene, direction, distance))
    return model.effector_positions(model.solve(tensions).state), tensions


def reachable_circle(model, scene: dict, distance: float, n_points: int) -> np.ndarray:
    """(n_points, 1, 3): tip positions of forward solutions bending the robot towards every
    direction around the base's axis with the amplitude that moves the tip ``distance`` from rest
    towards direction 0 — a closed loop every point of which is reachable within the bounds."""
    amplitude = _amplitude(model, scene, 0.0, distance)
    loop, state = [], None
    for direction in np.linspace(0.0, 2 * math.pi, n_points):
        state = model.solve(_pattern(model, scene, direction, amplitude), initial=state).state
        loop.append(model.effector_positions(state))
    return np.array(loop)
