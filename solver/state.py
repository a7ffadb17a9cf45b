"""States of a trunk: the pose of every frame, and the link strains a composed state carries.

A state the solver composes from link strains (:func:`compose`: the rest state, a Newton step,
a solve's result) keeps those strains: evaluations then use them as they are instead of
taking logarithms of rounded poses (docs/solver.md, "States carry their strains"). Its arrays
are read-only so that they cannot drift from the record; ``copy()`` gives writeable ones, and a
copy whose poses no longer match the record is evaluated from its poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vertebra.solver.chain import Chain, chain_poses
from vertebra.core.lie import pose_matrix
from vertebra.solver.links import Links


@dataclass
class StrainRecord:
    """Link strains ``ξ`` of a composed state, the chain products, and the poses they gave."""

    xi: np.ndarray
    chain: Chain
    positions: np.ndarray
    quaternions: np.ndarray
    # the effector points of these poses, once asked for: (the trunk's Effectors, turned offsets,
    # positions), read-only (solver.outputs.effector_points)
    effector_points: tuple | None = field(default=None, repr=False, compare=False)
    _links: Links | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def links(self) -> Links:
        """Link kinematics from the strains and the chain's products (no logarithms), computed
        when first asked for and kept (the record's arrays are read-only: it cannot go stale)."""
        if self._links is None:
            self._links = Links.of_strains(self.chain.rotations[:-1], self.xi,
                                           self.positions[1:] - self.positions[:-1], self.chain.link_coefficients)
        return self._links


@dataclass
class State:
    """Pose of every frame; frame 0 is the clamped base."""

    positions: np.ndarray     # (n_frames, 3) world
    quaternions: np.ndarray   # (n_frames, 4) [w, x, y, z]
    strains: StrainRecord | None = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        tip = ", ".join(f"{v:.6g}" for v in self.positions[-1])
        return f"State({len(self.positions)} frames, tip at [{tip}] m)"

    def copy(self) -> "State":
        return State(self.positions.copy(), self.quaternions.copy(), self.strains)

    def transforms(self) -> np.ndarray:
        """The pose of every frame as a 4×4 homogeneous transform ``(n_frames, 4, 4)``
        (:func:`vertebra.core.lie.pose_matrix`)."""
        return pose_matrix(self.positions, self.quaternions)

    def carried_strains(self) -> StrainRecord | None:
        """The strain record when it still describes these poses, else None. The solver's own
        states hold the record's (read-only) arrays themselves; copies are compared by value."""
        record = self.strains
        if record is None:
            return None
        if record.positions is self.positions and record.quaternions is self.quaternions:
            return record
        if np.array_equal(record.positions, self.positions) and np.array_equal(record.quaternions, self.quaternions):
            return record
        return None


def compose(base_quaternion: np.ndarray, base_position: np.ndarray, xi: np.ndarray) -> State:
    """The state composed from the base pose and link strains ``ξ`` (carrying them when every
    link turns less than :data:`~vertebra.solver.chain.CARRY_ANGLE`, where the logarithm of the
    composed poses returns ξ again to rounding)."""
    chain = chain_poses(base_quaternion, base_position, xi)
    chain.quaternions[0], chain.positions[0] = base_quaternion, base_position
    record = None
    if chain.link_coefficients is not None:
        chain.positions.flags.writeable = False
        chain.quaternions.flags.writeable = False
        record = StrainRecord(xi, chain, chain.positions, chain.quaternions)
    return State(chain.positions, chain.quaternions, record)


def kinematics(state: State) -> Links:
    """Link kinematics of a state: from the strains it carries, else from its poses."""
    record = state.carried_strains()
    if record is not None:
        return record.links
    q, x = state.quaternions, state.positions
    return Links.of(q[:-1], x[:-1], q[1:], x[1:])


def strain_change(dq: np.ndarray, links: Links) -> np.ndarray:
    """The links' linearised strain change ``J_l⁻¹ ζ(dq)`` (n_links, 6) under frame increments
    ``dq`` (``[dx; dφ]`` of every free frame, world axes; ``links``: the state's kinematics)."""
    d = np.zeros((links.xi.shape[0] + 1, 6))
    d[1:] = np.asarray(dq).reshape(-1, 6)
    return links.strain_change(d)


def retract(state: State, dq: np.ndarray, links: Links, change: np.ndarray | None = None) -> State:
    """Retraction in strain space: each link's strain ``ξ = log(T_a⁻¹ T_b)`` moves by its
    linearised change ``J_l⁻¹ ζ(dq)`` (:func:`strain_change`; ``change`` when already computed)
    and the chain is rebuilt from the base by composing ``exp(ξ)``. To first order this is the
    update ``x + dx``, ``exp(dφ) R`` (so Newton keeps its quadratic convergence), but a step
    that predicts no stretch of a link creates none: stiff axial and shear links absorb no
    spurious strain when frames rotate. ``dq`` holds ``[dx; dφ]`` (world axes) of every free
    frame; ``links``: the state's kinematics. Non-finite rotations raise :class:`ConvergenceError`
    (:func:`~vertebra.solver.chain.chain_poses`)."""
    if change is None:
        change = strain_change(dq, links)
    return compose(state.quaternions[0], state.positions[0], links.xi + change)
