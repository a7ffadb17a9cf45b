"""Canonical target paths for the inverse, shared by tests, benchmarks, examples and the demo.

* :func:`circle` — points on a circle in any plane (a geometric path; whether a robot reaches
  it is the caller's business);
* :func:`pose_circle` — the effector positions of one forward solution rotated about the
  base's z axis through one turn: reachable by an axisymmetric robot up to the discreteness
  of its actuators;
* :func:`bent_circle` — the same, for the pose whose tip is a given distance off the axis
  when the tendons at angle 0 pull;
* :func:`reachable_loop` — a closed loop of forward solutions, reachable by construction.

Tendons around a stiff backbone can bend it but barely shorten it (~1 µm per N), so a
horizontal circle at an arbitrary height is not reachable: the reachable circles are placed at
the height a forward solution reaches.
"""

from __future__ import annotations

import numpy as np

__all__ = ["circle", "pose_circle", "bent_circle", "reachable_loop"]


def circle(center, radius: float, n_points: int, *, normal=(0.0, 0.0, 1.0), turns: float = 1.0) -> np.ndarray:
    """``n_points`` points (n_points, 3) on a circle around ``center`` in the plane ⟂ ``normal``,
    starting along the first in-plane axis and closing after ``turns``."""
    center = np.asarray(center, dtype=float)
    normal = np.asarray(normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    helper = np.zeros_like(normal)
    helper[0 if abs(normal[0]) < 0.9 else 1] = 1.0
    u = helper - normal * (helper @ normal)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    theta = np.linspace(0.0, 2.0 * np.pi * turns, n_points)
    return center + radius * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)


def pose_circle(model, actuation, n_points: int) -> np.ndarray:
    """(n_points, n_effectors, 3): the effector positions of the forward solution under
    ``actuation``, rotated about the base's z axis from 0 through one turn."""
    pose = model.effector_positions(model.solve(np.asarray(actuation, dtype=float)).state)
    theta = np.linspace(0.0, 2.0 * np.pi, n_points)
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.zeros((n_points, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = c, -s, s, c
    rotation[:, 2, 2] = 1.0
    return np.einsum("nij,ej->nei", rotation, pose)


def _bending_actuation(model, scene, tension: float) -> np.ndarray:
    """The tendons at angle 0 pulling: the longest with ``tension``, shorter ones half as much."""
    lam = np.zeros(len(model.actuator_names))
    longest = max(c.last for c in scene.cables)
    for j, cable in enumerate(scene.cables):
        if abs(np.cos(cable.angle) - 1.0) < 1e-9:
            lam[j] = tension if cable.last == longest else 0.5 * tension
    return lam


def bent_circle(model, scene, radius: float, n_points: int) -> np.ndarray:
    """:func:`pose_circle` of the pose whose last effector is ``radius`` off the axis when the
    tendons at angle 0 pull (tension found by bisection within the largest finite bound)."""
    upper = model.actuator_bounds[1]
    lo, hi = 0.0, float(np.max(upper[np.isfinite(upper)]))
    for _ in range(30):  # bisection on the tension for the offset (bound / 2³⁰)
        mid = 0.5 * (lo + hi)
        tip = model.effector_positions(model.solve(_bending_actuation(model, scene, mid)).state)[-1]
        lo, hi = (mid, hi) if np.hypot(tip[0], tip[1]) < radius else (lo, mid)
    return pose_circle(model, _bending_actuation(model, scene, 0.5 * (lo + hi)), n_points)


def reachable_loop(model, scene, n_points: int, base: float = 0.1, amplitude: float = 1.0) -> np.ndarray:
    """(n_points, n_effectors, 3): a closed loop of targets tendons can reach — the effector
    positions of forward solutions with tensions ``base + amplitude·max(0, cos(θ − angle_j))``
    for θ around the circle (tendon ``j`` at ``angle_j``)."""
    angles = np.array([c.angle for c in scene.cables])
    loop, state = [], None
    for theta in np.linspace(0.0, 2 * np.pi, n_points):
        tensions = base + amplitude * np.maximum(0.0, np.cos(theta - angles))
        state = model.solve(tensions, initial=state).state
        loop.append(model.effector_positions(state))
    return np.array(loop)
