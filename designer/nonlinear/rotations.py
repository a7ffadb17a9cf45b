"""Rotations and rigid motions for the nonlinear FE models (numpy only).

Conventions: rotation vectors ``w`` (radians, axis × angle), ``R = exp(ŵ)``;
twists ``ξ = [v; ω]`` with ``exp(ξ^) = (exp(ω̂), V(ω) v)``, i.e. the pose
``(R, t)`` acting on points as ``x ↦ t + R x``; quaternions ``[w, x, y, z]``.
Every function takes a single vector/matrix; the series branches near zero
angle keep them accurate for tiny rotations (the small-load limit of the FE
models is tested at rotations of 1e-8 rad).
"""

from __future__ import annotations

import numpy as np

_SMALL = 1e-4     # below this angle the trigonometric coefficients use their Taylor series


def skew(v) -> np.ndarray:
    """``v̂`` with ``v̂ a = v × a``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _coefficients(theta):
    """a = sin θ/θ, b = (1 − cos θ)/θ², c = (θ − sin θ)/θ³ (accurate near θ = 0; θ scalar or array)."""
    theta = np.asarray(theta, dtype=float)
    t2 = theta * theta
    small = theta < _SMALL
    safe = np.where(small, 1.0, theta)
    half = np.sin(0.5 * safe)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - t2 / 24.0, 2.0 * half * half / safe ** 2)
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (safe - np.sin(safe)) / safe ** 3)
    if theta.ndim == 0:
        return float(a), float(b), float(c)
    return a, b, c


def exp_so3_minus_identity(w) -> np.ndarray:
    """``exp(ŵ) − I`` computed without cancellation (small rotations of faces)."""
    w = np.asarray(w, dtype=float)
    a, b, _ = _coefficients(float(np.linalg.norm(w)))
    W = skew(w)
    return a * W + b * (W @ W)


def exp_so3(w) -> np.ndarray:
    return np.eye(3) + exp_so3_minus_identity(w)


def log_so3(R) -> np.ndarray:
    """Rotation vector of ``R`` (angle in [0, π])."""
    R = np.asarray(R, dtype=float)
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def exp_se3(xi):
    """``(R, t)`` of the twist ``xi = [v; ω]``: ``R = exp(ω̂)``, ``t = V(ω) v``."""
    xi = np.asarray(xi, dtype=float)
    v, w = xi[:3], xi[3:]
    a, b, c = _coefficients(float(np.linalg.norm(w)))
    W = skew(w)
    WW = W @ W
    R = np.eye(3) + a * W + b * WW
    V = np.eye(3) + b * W + c * WW
    return R, V @ v


def log_se3(R, t) -> np.ndarray:
    """Twist ``[v; ω]`` with ``exp_se3([v; ω]) = (R, t)`` (rotation angle < π)."""
    w = log_so3(R)
    theta = float(np.linalg.norm(w))
    _, b, c = _coefficients(theta)
    W = skew(w)
    V = np.eye(3) + b * W + c * (W @ W)
    return np.concatenate([np.linalg.solve(V, np.asarray(t, dtype=float)), w])


def exp_se3_scaled_apply(xi, phi: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``exp(φ_i ξ^) x_i`` for points ``x_i`` (n, 3) and scalars ``φ_i`` (n,): each point moved by its
    own fraction of the rigid motion ``exp(ξ^)`` (a smooth rigid blend between frames)."""
    xi = np.asarray(xi, dtype=float)
    v, w = xi[:3], xi[3:]
    phi = np.asarray(phi, dtype=float)
    a, b, c = _coefficients(np.abs(phi) * float(np.linalg.norm(w)))
    W = skew(w)
    WW = W @ W
    rotated = points + (a * phi)[:, None] * (points @ W.T) + (b * phi ** 2)[:, None] * (points @ WW.T)
    shift = phi[:, None] * v + (b * phi ** 2)[:, None] * (W @ v) + (c * phi ** 3)[:, None] * (WW @ v)
    return rotated + shift


def ad_se3(xi) -> np.ndarray:
    """Adjoint action matrix ``ad_ξ`` (6×6) of the twist ``ξ = [v; ω]``: ``[[ω̂, v̂], [0, ω̂]]``."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = skew(xi[3:])
    out[:3, 3:] = skew(xi[:3])
    return out


def quaternion_from_matrix(R) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` of ``R`` (w ≥ 0)."""
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def matrix_from_quaternion(q) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    w, x, y, z = np.asarray(q, dtype=float)
    return Rotation.from_quat([x, y, z, w]).as_matrix()
