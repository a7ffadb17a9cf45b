"""What a state gives out: effector positions, cable lengths, chamber volume growth, and the
linearisation the inverse uses (paper eqs. 10–12)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from vertebra.solver.banded import BandedFactor
from vertebra.solver.potential import Evaluation, LoadCases, chamber_forces, evaluate, tangent, volume_growth
from vertebra.solver.state import kinematics
from vertebra.core.lie import HAT_TABLE, qmatrix, qrotate
from vertebra.core.errors import ConvergenceError

LINEARISATION_SHIFTS = (0.0, 1e-8, 1e-6, 1e-4)   # μ tried when the tangent at a state is singular


@dataclass
class Linearisation:
    """Tangent of the equilibrium at a state (paper eqs. 10–12); see docs/solver-api.md."""

    residual: np.ndarray
    factor: object
    actuator_forces: np.ndarray
    actuator_jacobian: np.ndarray
    effector_jacobian: np.ndarray
    effector_positions: np.ndarray
    actuator_displacements: np.ndarray
    energy: float = 0.0          # total potential at the state (dead moments excluded)
    shift: float = 0.0           # μ of the factor (0: the tangent itself; > 0: it was singular)
    # actuator_forces = actuator_jacobianᵀ · diag(force_scale): −1 per cable, −k per taut tendon
    # (0 when slack), +1 per chamber
    force_scale: np.ndarray | None = None

    @property
    def cholesky(self):
        """The factor when it is a banded Cholesky factor ``K = L Lᵀ`` (its ``forward`` applies
        ``L⁻¹``, its ``backward`` ``L⁻ᵀ``), else None (LU, or updated by a dense term)."""
        factor = self.factor
        return factor if isinstance(factor, BandedFactor) and factor.pivots is None else None

    def solve(self, rhs: np.ndarray, *, overwrite: bool = False) -> np.ndarray:
        """``K⁻¹ rhs`` with the banded factor, for ``rhs`` of shape (n_dof,) or (n_dof, k): the
        LAPACK solve itself. With ``overwrite`` a Fortran-ordered float ``rhs`` is overwritten by
        the solution (no copy)."""
        return self.factor.solve(rhs, overwrite=True) if overwrite else self.factor.solve(rhs)


def effector_points(trunk, state) -> tuple[np.ndarray, np.ndarray]:
    """World offsets (``R r``: lever arms, or the axes) and positions of the effectors. A state
    that carries its strains keeps them (read-only) for the next call with the same effectors: a
    control tick reports the effectors where the next tick linearises."""
    effectors = trunk.effectors
    f = effectors.frames
    origins = effectors.at_origins
    if origins is not None:         # every effector a point at its frame's origin
        return origins, state.positions.take(f, 0)
    record = state.carried_strains()
    if record is None:
        turned = qrotate(state.quaternions[f], effectors.offsets)
        return turned, state.positions[f] * effectors.point_mask + turned
    kept = record.effector_points
    if kept is not None and kept[0] is effectors:
        return kept[1], kept[2]
    turned = (record.chain.rotations[f] @ effectors.offsets[:, :, None])[:, :, 0]   # no quaternion algebra
    positions = state.positions[f] * effectors.point_mask + turned
    turned.flags.writeable = positions.flags.writeable = False
    record.effector_points = (effectors, turned, positions)
    return turned, positions


def cable_lengths(trunk, state, pieces=None) -> np.ndarray:
    """Length of every cable (``pieces``: their kinematics at ``state`` when known)."""
    if not trunk.actuators.n_cables:
        return np.zeros(0)
    if pieces is None:
        pieces = trunk.cables.pieces(state.positions, qmatrix(state.quaternions))
    return trunk.cables.lengths(pieces)


def chamber_volume_growth(trunk, state, pressures: np.ndarray, loads: LoadCases, links=None) -> np.ndarray:
    """Volume growth of every chamber, ``−∂ψ/∂p`` summed over the links it covers (``loads``:
    the model's load cases, whose link energies may have prepared these pressures)."""
    if not trunk.actuators.n_chambers:
        return np.zeros(0)
    if links is None:
        links = kinematics(state)
    pressures = np.asarray(pressures, float)
    return volume_growth(trunk, links, pressures, loads.link_loads(pressures))


def actuator_displacements(trunk, state, actuation: np.ndarray, loads: LoadCases, *, links=None,
                           pieces=None) -> np.ndarray:
    """Cable strokes ``L − L0``, then chamber volume growths."""
    strokes = cable_lengths(trunk, state, pieces) - trunk.rest_cable_lengths
    if not trunk.actuators.n_chambers:
        return strokes
    growth = chamber_volume_growth(trunk, state, actuation[trunk.actuators.n_cables:], loads, links)
    return np.concatenate([strokes, growth])


_NEGATIVE_HAT = -HAT_TABLE       # (−v̂).ravel() = v @ _NEGATIVE_HAT


@functools.lru_cache(maxsize=32)
def _unit_scale(n_cables: int, n_chambers: int) -> np.ndarray:
    """The actuator forces' scale per unit of each actuator's value without taut tendons: −1 per
    cable, +1 per chamber (read-only)."""
    scale = np.ones(n_cables + n_chambers)
    scale[:n_cables] = -1.0
    scale.flags.writeable = False
    return scale


def linearise(trunk, state, actuation: np.ndarray, loads: LoadCases, previous=None, factor=None) -> Linearisation:
    """Tangent stiffness factor, actuator and effector Jacobians at ``state`` under ``actuation``
    (``previous``: an evaluation or trial the caller holds, reused where it is of the same state
    and load case). ``factor``: the factor of an earlier state's tangent to use instead of this
    state's (a chord step: the tangent is neither assembled nor factored)."""
    load = loads(actuation, 1.0)
    if (isinstance(previous, Evaluation) and previous.load is load and previous.record is not None
            and previous.record is state.carried_strains()):
        ev = previous          # (the evaluation of this very state and load: its gradient too)
    else:
        ev = evaluate(trunk, state, load, previous)
    if not math.isfinite(ev.energy):
        raise ConvergenceError("non-finite values appeared in the linearisation (the state or the actuation "
                               "is not finite)")
    if factor is None:
        matrix = tangent(trunk, ev)
        for shift in LINEARISATION_SHIFTS:
            factor, _ = matrix.factor(shift, symmetric=not trunk.loads.unsymmetric)
            if factor is not None:
                break
        if factor is None:
            raise ConvergenceError("tangent stiffness is singular at this state")
    else:
        shift = 0.0
    n_frames, n_dof = trunk.frames.count, trunk.n_dof
    n_cables, n_chambers = trunk.actuators.n_cables, trunk.actuators.n_chambers
    n_act = n_cables + n_chambers
    links, pieces = ev.links, ev.pieces
    if n_cables and pieces is None:                   # slack cables: not evaluated for the forces
        pieces = trunk.cables.pieces(state.positions, qmatrix(state.quaternions))
    if n_chambers or not n_cables:
        jac = np.zeros((n_act, n_frames, 6))
        if n_cables:
            jac[:n_cables] = trunk.cables.jacobian(pieces)
    else:
        jac = trunk.cables.jacobian(pieces)
    if n_chambers:
        g = links.gradient(chamber_forces(trunk, ev))  # (n_links, chamber, 12)
        chamber_jac = jac[n_cables:]
        chamber_jac[:, :-1] += np.moveaxis(g[..., :6], 1, 0)
        chamber_jac[:, 1:] += np.moveaxis(g[..., 6:], 1, 0)
    jacobian = jac[:, 1:].reshape(n_act, n_dof)
    # per unit of each actuator's value: a cable −τ ∂L/∂q, a tendon −k ∂L/∂q per unit stroke while
    # taut, a chamber ∂r/∂p = (∂ξ/∂q)ᵀ (−∂²ψ/∂ξ∂p) = Jaᵀ
    tendons = ev.load.tendons
    scale = _unit_scale(n_cables, n_chambers)
    if tendons is not None:
        scale = scale.copy()
        scale[tendons.cables] = -tendons.stiffness * (ev.parts.elongation > 0.0)
    # (new C-ordered arrays: their transposes are in the banded solves' order)
    forces = np.negative(jacobian) if n_chambers == 0 and tendons is None else jacobian * scale[:, None]
    free, where, turning = trunk.effectors.free_jacobian
    turned, positions = effector_points(trunk, state)
    if trunk.effectors.at_origins is not None:      # points at their frames' origins: no turning part
        Je = free
    else:
        Je = free.copy()
        Je.put(where, (turned if turning is None else turned[turning]).dot(_NEGATIVE_HAT))    # −[R r]ˣ on dφ
    return Linearisation(
        residual=-ev.gradient[1:].reshape(-1), factor=factor,
        actuator_forces=forces.T,
        actuator_jacobian=jacobian,
        effector_jacobian=Je,
        effector_positions=positions,
        actuator_displacements=actuator_displacements(trunk, state, actuation, loads, links=links, pieces=pieces),
        energy=ev.energy, force_scale=scale, shift=shift)
