"""Poses of a chain of frames from the strains of its links: ``T_k = T_0 ∘ exp(ξ_1^) ∘ … ∘ exp(ξ_k^)``.

Each transform is packed as ``diag(L(q), [[R, p], [0, 1]])`` (8×8; ``L(q)`` multiplies
quaternions, so the product carries the quaternion along with the homogeneous transform) and
the prefix products are taken by doubling for short chains (log₂N batched products) and in √N
blocks for long ones (O(N) work in about 2√N products). A batch of chains composes its
quaternions link after link over the batch (:func:`_batch`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from vertebra.core.lie import (
    EXP_SERIES_LIMIT,
    EXP_TABLE,
    L_TABLE,
    R_TABLE,
    SERIES,
    exp_coefficients,
    exp_translation,
    powers,
    terms,
)
from vertebra.core.errors import ConvergenceError

CARRY_ANGLE = 0.99 * math.pi     # largest link rotation whose strain a composed state carries
_CHAIN_TABLE = np.concatenate([SERIES, EXP_TABLE], 1)     # link coefficients and exp coefficients


def _pose_table() -> np.ndarray:
    """(24, 64): ``diag(L(q), [[R(q), p], [0, 1]]).ravel() = [q, q⊗q, p, 1] @ T``."""
    table = np.zeros((24, 8, 8))
    table[:4, :4, :4] = L_TABLE.reshape(4, 4, 4)
    table[4:20, 4:7, 4:7] = R_TABLE.reshape(16, 3, 3)
    table[20 + np.arange(3), 4 + np.arange(3), 7] = 1.0
    table[23, 7, 7] = 1.0
    return table.reshape(24, 64)


_POSE_TABLE = _pose_table()
_IDENTITY_FEATURES = np.zeros(24)
_IDENTITY_FEATURES[[0, 4, 23]] = 1.0


@functools.lru_cache(maxsize=64)
def _feature_template(rows: int) -> np.ndarray:
    """Pose features of identity transforms (what the unused padding rows keep)."""
    return np.tile(_IDENTITY_FEATURES, (rows, 1))


@dataclass
class Chain:
    """Poses composed by :func:`chain_poses`, with what :meth:`Links.of_strains` reuses."""

    quaternions: np.ndarray    # (N, 4) world
    positions: np.ndarray      # (N, 3) world
    rotations: np.ndarray      # (N, 3, 3) world rotation matrices (the same products)
    translations: np.ndarray   # (n, 3) relative translations p of the links, in a's axes
    link_coefficients: np.ndarray | None   # (n, 31) lie.coefficients() of the strains, when carried
    largest_turn2: float = 0.0             # the largest θ² of the links' rotations
    largest_turns2: np.ndarray | None = None   # (B,) per chain of a batch (None: one chain)


def chain_poses(q0: np.ndarray, x0: np.ndarray, xi: np.ndarray) -> Chain:
    """World quaternions (n+1, 4) and positions (n+1, 3) of a chain from its base pose and the
    strains ``ξ`` (n, 6) of its links. When every link turns less than :data:`CARRY_ANGLE`, the
    links' logarithm-side coefficients come from the same product as the exponentials.

    ``ξ`` may carry leading batch axes (B, n, 6): B chains from the same base, composed by the
    same products over the batch (their rows of link coefficients flattened, (B·n, 31);
    ``largest_turns2`` per chain)."""
    lead = xi.shape[:-2]
    n = xi.shape[-2]
    N = n + 1
    flat = xi.reshape(-1, 6)
    rho, phi = flat[:, :3], flat[:, 3:]
    theta2 = (phi[:, None, :] @ phi[:, :, None])[:, 0, 0]
    largest = float(np.maximum.reduce(theta2)) if theta2.size else 0.0
    if not largest < math.inf:                   # NaN, or a rotation whose square overflows
        raise ConvergenceError("non-finite values appeared in the retraction (a step of non-finite or "
                               "overflowing size)")
    link_coef = None
    if largest <= EXP_SERIES_LIMIT:
        carry = largest < CARRY_ANGLE ** 2
        count = max(terms(largest) if carry else 0, 16 if largest > 1e-2 else 8)
        coef = powers(theta2, count).dot(_CHAIN_TABLE[:count])
        expc = coef[:, 31:]
        if carry:
            link_coef = coef[:, :31]
    else:
        expc = exp_coefficients(theta2)
    if lead:
        return _batch(q0, x0, expc, phi, rho, lead, n, link_coef, largest, theta2)
    doubling = N <= 64
    c = 1 if doubling else math.isqrt(N - 1) + 1
    m = N if doubling else -(-N // c)
    F = _feature_template(m * c).copy()                 # features [q, q⊗q, p, 1] of each factor
    F[0, :4], F[0, 20:23] = q0, x0
    F[1:N, 0] = expc[:, 0]
    F[1:N, 1:4] = expc[:, 1:2] * phi
    F[1:N, 20:23] = exp_translation(expc, phi, rho)
    quats = F[:N, :4]
    F[:N, 4:20] = (quats[:, :, None] * quats[:, None, :]).reshape(N, 16)
    if doubling:
        M = F.dot(_POSE_TABLE).reshape(N, 8, 8)
        shift = 1
        while shift < N:
            M[shift:] = M[:-shift] @ M[shift:]
            shift *= 2
    else:
        M = F.dot(_POSE_TABLE).reshape(m, c, 8, 8)
        for j in range(1, c):
            M[:, j] = M[:, j - 1] @ M[:, j]
        for i in range(1, m):
            M[i] = M[i - 1, -1] @ M[i]
        M = M.reshape(m * c, 8, 8)[:N]
    quaternions = M[..., :4, 0]
    quaternions = quaternions / np.sqrt(quaternions[..., None, :] @ quaternions[..., :, None])[..., 0]
    return Chain(quaternions, M[..., 4:7, 7].copy(), M[..., 4:7, 4:7], F[..., 1:N, 20:23], link_coef, largest)


def _batch(q0, x0, expc, phi, rho, lead, n, link_coef, largest, theta2) -> Chain:
    """The poses of a batch of chains (:func:`chain_poses` with leading batch axes ``lead``): the
    quaternions composed one link after the other, each step one product of the batch's 4×4
    quaternion-product matrices ``L(q_{k−1})`` with the links' exponentials ``q_k = q_{k−1} ⊗ e_k``
    (the batch, not the chain, fills the arrays); then every frame's rotation matrix in one table
    product, and the positions as running sums ``x_k = x_{k−1} + R_{k−1} t_k`` of the links'
    translations turned into the world."""
    N = n + 1
    count = int(np.prod(lead)) if lead else 1
    e = np.empty((count, n, 4))
    e[:, :, 0] = expc[:, 0].reshape(count, n)
    e[:, :, 1:] = (expc[:, 1:2] * phi).reshape(count, n, 3)
    t = exp_translation(expc, phi, rho).reshape(count, n, 3)
    q = np.empty((count, N, 4))
    q[:, 0] = q0
    for k in range(n):
        np.matmul(q[:, k].dot(L_TABLE).reshape(count, 4, 4), e[:, k, :, None], out=q[:, k + 1, :, None])
    q /= np.sqrt(q[:, :, None, :] @ q[:, :, :, None])[..., 0]
    R = (q[:, :, :, None] * q[:, :, None, :]).reshape(count * N, 16).dot(R_TABLE).reshape(count, N, 3, 3)
    x = np.empty((count, N, 3))
    x[:, 0] = x0
    np.matmul(R[:, :-1], t[:, :, :, None], out=x[:, 1:, :, None])
    np.cumsum(x, axis=1, out=x)
    chain = Chain(q.reshape(lead + (N, 4)), x.reshape(lead + (N, 3)), R.reshape(lead + (N, 3, 3)),
                  t.reshape(lead + (n, 3)), link_coef, largest)
    chain.largest_turns2 = np.maximum.reduce(theta2.reshape(lead + (n,)), -1) if n else np.zeros(lead)
    return chain
