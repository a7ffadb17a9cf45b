"""Cartesian compliance of the effectors at an equilibrium: ``C = J K⁻¹ Jᵀ``.

``K`` is the tangent stiffness of the linearisation (links, cable tensions, gravity and
follower terms included, so ``C`` is the incremental compliance of the loaded trunk, not
of the unloaded one), applied through the banded factor: ``K⁻¹ Jᵀ`` is one banded solve
with six right-hand sides per effector.

For effector ``k`` on frame ``f`` at the world point ``p`` (a point effector's point; an
axis effector's frame origin), ``J`` stacks

* the translation rows ``∂p/∂q`` (the effector Jacobian ``Je`` of a point effector): ``δx_f
  + δφ_f × (p − x_f)``, and
* the rotation rows ``∂θ/∂q``: the frame's world rotation increment ``δφ_f``.

So ``full[k]`` (6×6) maps a small wrench ``[f; m]`` applied at ``p`` (force N and moment
N m, world axes) to the effector's displacement ``[Δp; Δθ]`` (m and rad, world axes):
units ``[[m/N, m/(N m)], [rad/N, rad/(N m)]]``. ``translational[k] = full[k][:3, :3]``
(m/N) is ``Je K⁻¹ Jeᵀ``. Both are symmetric when the loads are conservative (no dead
moments); an effector on the clamped base has zero compliance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vertebra.core.errors import ConvergenceError

CHUNK_VALUES = 2**22        # numbers of K⁻¹ Jᵀ held at once (32 MiB)


@dataclass(frozen=True)
class EffectorCompliance:
    """Compliance of every effector at one equilibrium (see the module docstring)."""

    names: tuple
    full: np.ndarray          # (n_eff, 6, 6): [Δp; Δθ] per [f; m] at the effector point, world axes

    def __post_init__(self):
        if self.full.shape != (len(self.names), 6, 6):
            raise ValueError(f"full has shape {self.full.shape}, expected ({len(self.names)}, 6, 6)")

    @property
    def translational(self) -> np.ndarray:
        """(n_eff, 3, 3) m/N: displacement of the effector point per unit force on it."""
        return self.full[:, :3, :3]

    def __getitem__(self, name: str) -> np.ndarray:
        """The 6×6 compliance of effector ``name``."""
        return self.full[self.names.index(name)]

    def report(self) -> dict:
        """Per effector ``{"translational": 3×3, "full": 6×6}`` as nested lists (JSON-ready)."""
        return {name: {"translational": self.full[k, :3, :3].tolist(), "full": self.full[k].tolist()}
                for k, name in enumerate(self.names)}


def effector_wrench_jacobian(model, state, linearisation) -> np.ndarray:
    """``J`` (6·n_eff, n_dof): rows ``[∂p/∂q; ∂θ/∂q]`` of every effector (module docstring)."""
    n_eff = len(model.effector_names)
    frames = np.asarray(model.effector_frames, int)
    is_axis = np.asarray(model.effector_is_axis, bool)
    J = np.zeros((n_eff, 6, model.n_frames, 6))
    translation = np.asarray(linearisation.effector_jacobian).reshape(n_eff, 3, model.n_frames - 1, 6)
    points = ~is_axis
    J[points, :3, 1:] = translation[points]                       # Je: δx + δφ × (p − x)
    J[is_axis, :3, frames[is_axis], :3] = np.eye(3)              # an axis effector's frame origin
    J[np.arange(n_eff), 3:, frames, 3:] = np.eye(3)              # the frame's rotation increment
    return J[:, :, 1:].reshape(6 * n_eff, model.n_dof)            # the clamped base carries no DoF


def effector_compliance(model, state, actuation=None, *, linearisation=None) -> EffectorCompliance:
    """Compliance of every effector at the equilibrium ``state`` under ``actuation`` (None:
    the scene's). Pass the ``linearisation`` of that state when it is at hand."""
    lin = model.linearise(state, actuation) if linearisation is None else linearisation
    n_eff = len(model.effector_names)
    J = effector_wrench_jacobian(model, state, lin)
    if n_eff == 0:
        return EffectorCompliance((), np.zeros((0, 6, 6)))
    # only the diagonal blocks J_k K⁻¹ J_kᵀ are wanted: solve for a chunk of effectors at a time,
    # so that K⁻¹ Jᵀ never holds more than CHUNK_VALUES numbers (not the (6 n_eff)² product)
    chunk = max(1, CHUNK_VALUES // (6 * model.n_dof))
    rows = J.reshape(n_eff, 6, model.n_dof)
    full = np.empty((n_eff, 6, 6))
    for start in range(0, n_eff, chunk):
        part = rows[start:start + chunk]
        KJ = lin.solve(part.reshape(-1, model.n_dof).T)            # K⁻¹ Jᵀ, (n_dof, 6 · chunk)
        full[start:start + chunk] = part @ KJ.T.reshape(len(part), 6, model.n_dof).transpose(0, 2, 1)
    return EffectorCompliance(tuple(model.effector_names), full)


def compliance_report(model, result) -> dict:
    """Each effector's compliance at the equilibrium of a forward ``result`` as JSON-ready
    ``{name: {"translational": 3×3, "full": 6×6}}``; ``{}`` when the solve did not converge
    (no equilibrium to linearise) or the tangent there is singular (no finite compliance)."""
    if not result.converged:
        return {}
    try:
        return effector_compliance(model, result.state, result.actuation).report()
    except ConvergenceError:
        return {}
