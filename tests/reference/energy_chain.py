"""A chain of segments given by their energies ψ_i(s_i, p_i), solved by Newton — a check of fitted
energies (tests and benchmarks; not part of the installed package).

The runtime solver (its ``nonlinear-entry`` link kind) is the product; this chain is an
independent yardstick for it: the strains are the unknowns, Newton is dense and none of
``vertebra.solver`` is used (only the energy kernel they share), so the runtime's kinematics,
chambers and Newton are checked against it (tests/test_solver_fitted.py). The chain is
clamped at the base (frame a of segment 1 at the origin, axis +z); vertebra ``i`` sits at
``T_i = T_{i−1} exp(ξ₀ᵢ + s_i)``; loads are dead forces at points of vertebrae (conservative:
moments come from lever arms) and cavity pressures. The unknowns are the strains ``s = (s_1, …, s_n)``; the potential

    E(s) = Σ_i ψ_i(s_i, p_i) − Σ_loads F · x(s)

is minimised by Newton with a backtracking line search, its Hessian the segments' Hessians
plus the loads' (central differences of their closed-form gradient). The reference it is
measured against is the full nonlinear FE of the same trunk
(:class:`designer.nonlinear.fe_trunk.NonlinearTrunk`, same meshes and material).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from vertebra.core.energy import EnergyFit, EnergyModel, EnergyRange, linear_terms
from vertebra.core.lie import se3_left_jacobian_inverse as inverse_left_jacobian
from vertebra.designer.energy_fit import pose_of_strain
from vertebra.core.errors import ConvergenceError


class SegmentEnergy(Protocol):
    rest_translation: np.ndarray
    n_cavities: int

    def evaluate(self, s: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """``(ψ, ∂ψ/∂s (6,), ∂²ψ/∂s² (6, 6), ΔV (m,))`` at strain ``s`` and pressures ``p``."""


class EntryEnergy:
    """A :class:`SegmentEnergy` from a catalogue entry: the ψ it carries (core.energy), or for a
    linear entry (or with ``linear_only``) ψ_lin alone."""

    def __init__(self, entry, linear_only: bool = False):
        self.rest_translation = np.asarray(entry.rest_translation, dtype=float)
        self.n_cavities = entry.n_cavities
        fit = entry.energy
        if fit is None or linear_only:
            m = entry.n_cavities
            wide = np.full(4, 1e300)
            lower = np.array([0.0, -1e300, 0.0, -1e300])
            fit = EnergyFit(exponents=np.zeros((0, 6 + m), dtype=np.int64), coefficients=np.zeros(0),
                            scales=np.ones(6 + m), range=EnergyRange(lower, wide, lower, wide, np.full(m, -1e300),
                                                                      np.full(m, 1e300)))
        self.model = EnergyModel(fit, *linear_terms(entry.compliance, entry.rest_translation))
        self.left_range = False

    def evaluate(self, s, p):
        values = self.model.evaluate(s[None], p[None])
        self.left_range |= not bool(values.in_range[0])
        return float(values.energy[0]), values.gradient[0], values.hessian[0], values.volume_growth[0]


@dataclass(frozen=True)
class PointLoad:
    """A dead force (world axes, N) at ``offset`` (m, in the vertebra's frame) on vertebra
    ``vertebra`` (1…n; −1: the tip)."""

    vertebra: int
    force: tuple
    offset: tuple = (0.0, 0.0, 0.0)


@dataclass
class ChainResult:
    strains: np.ndarray                # (n, 6)
    rotations: np.ndarray              # (n + 1, 3, 3) vertebrae, base first
    positions: np.ndarray              # (n + 1, 3)
    volume_growth: list                # per segment, (m_i,)
    iterations: int
    converged: bool
    left_range: bool = False
    history: list = field(default_factory=list)

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[-1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[-1]

    def tip_angle(self) -> float:
        """Angle (rad) between the tip's axis and the base's (+z)."""
        return float(np.arccos(np.clip(self.rotations[-1][2, 2], -1.0, 1.0)))


def _poses(segments, s):
    n = len(segments)
    rotations = np.empty((n + 1, 3, 3))
    positions = np.empty((n + 1, 3))
    rotations[0], positions[0] = np.eye(3), np.zeros(3)
    for i, seg in enumerate(segments):
        R, t = pose_of_strain(s[i][None], seg.rest_translation)
        rotations[i + 1] = rotations[i] @ R[0]
        positions[i + 1] = positions[i] + rotations[i] @ t[0]
    return rotations, positions


def _load_terms(segments, s, loads, scale):
    """(−Σ F·x, gradient (n, 6)) of the dead loads at strains ``s``."""
    n = len(segments)
    rotations, positions = _poses(segments, s)
    xi = s + np.concatenate([np.array([seg.rest_translation for seg in segments]), np.zeros((n, 3))], axis=1)
    Jr = np.linalg.inv(inverse_left_jacobian(-xi))             # J_r(ξ) = J_l(−ξ)
    potential = 0.0
    grad = np.zeros((n, 6))
    for load in loads:
        k = n if load.vertebra == -1 else load.vertebra
        force = scale * np.asarray(load.force, dtype=float)
        x = positions[k] + rotations[k] @ np.asarray(load.offset, dtype=float)
        potential -= float(force @ x)
        for i in range(k):                                     # segment i+1 ends at vertebra i+1
            R, t = rotations[i + 1], positions[i + 1]
            # δx = R η_ρ + (R η_φ) × (x − t), η = J_r δs: ∂(F·x)/∂η = [Rᵀ F; Rᵀ((x − t) × F)]
            dual = np.concatenate([R.T @ force, R.T @ np.cross(x - t, force)])
            grad[i] -= Jr[i].T @ dual
    return potential, grad


def solve_chain(segments: list, loads: list[PointLoad] = (), pressures: list | None = None, *, steps: int = 4,
                tolerance: float = 1e-10, max_iterations: int = 60, initial: np.ndarray | None = None) -> ChainResult:
    """Equilibrium of the chain under ``loads`` and per-segment ``pressures`` (each (m_i,)), reached in
    ``steps`` equal load increments (loads and pressures scaled together), each solved by Newton
    until the largest strain update is below ``tolerance`` (in units of the segment length for
    translations, radians for rotations)."""
    n = len(segments)
    pressures = [np.zeros(seg.n_cavities) if pressures is None else np.asarray(pressures[i], dtype=float)
                 for i, seg in enumerate(segments)]
    lengths = np.array([np.linalg.norm(seg.rest_translation) for seg in segments])
    unit = np.concatenate([np.repeat(lengths[:, None], 3, 1), np.ones((n, 3))], axis=1)      # (n, 6)
    s = np.zeros((n, 6)) if initial is None else np.array(initial, dtype=float)
    iterations, history = 0, []

    def energy_terms(s, scale, hessian=True):
        total, grad, hess, volumes = 0.0, np.zeros((n, 6)), np.zeros((6 * n, 6 * n)), []
        for i, seg in enumerate(segments):
            e, g, H, dv = seg.evaluate(s[i], scale * pressures[i])
            total += e
            grad[i] = g
            hess[6 * i:6 * i + 6, 6 * i:6 * i + 6] = H
            volumes.append(dv)
        potential, load_grad = _load_terms(segments, s, loads, scale)
        total += potential
        grad += load_grad
        if hessian and loads:
            h = 1e-6 * unit.reshape(-1)
            for j in range(6 * n):
                step = np.zeros(6 * n)
                step[j] = h[j]
                plus = _load_terms(segments, s + step.reshape(n, 6), loads, scale)[1].reshape(-1)
                minus = _load_terms(segments, s - step.reshape(n, 6), loads, scale)[1].reshape(-1)
                hess[:, j] += (plus - minus) / (2 * h[j])
            hess = 0.5 * (hess + hess.T)
        return total, grad, hess, volumes

    volumes = None
    converged = False
    for k in range(1, steps + 1):
        scale = k / steps
        total, grad, hess, volumes = energy_terms(s, scale)
        converged = False
        for _ in range(max_iterations):
            iterations += 1
            try:
                ds = -np.linalg.solve(hess, grad.reshape(-1)).reshape(n, 6)
            except np.linalg.LinAlgError:
                raise ConvergenceError("chain: singular Hessian") from None
            slope = float(grad.reshape(-1) @ ds.reshape(-1))
            if slope > 0:                                  # not a descent direction: use the gradient
                ds = -grad / np.max(np.abs(grad) / unit)
                slope = float(grad.reshape(-1) @ ds.reshape(-1))
            alpha = 1.0
            while True:
                trial = s + alpha * ds
                t_total, t_grad, t_hess, t_volumes = energy_terms(trial, scale)
                if t_total <= total + 1e-4 * alpha * slope + 1e-13 * abs(total) or alpha < 1e-6:
                    break
                alpha *= 0.5
            s, total, grad, hess, volumes = trial, t_total, t_grad, t_hess, t_volumes
            history.append(float(np.max(np.abs(alpha * ds) / unit)))
            if history[-1] <= tolerance:
                converged = True
                break
        if not converged:
            raise ConvergenceError(f"chain: no convergence at load step {k}/{steps} (last update {history[-1]:.3g})")
    rotations, positions = _poses(segments, s)
    return ChainResult(strains=s, rotations=rotations, positions=positions, volume_growth=volumes,
                       iterations=iterations, converged=converged,
                       left_range=any(getattr(seg, "left_range", False) for seg in segments), history=history)
