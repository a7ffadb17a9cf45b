"""Solve orders of workspace samples: which already solved neighbour each sample starts from.

Nearness is measured in the linear response of the trunk at rest, ``q ≈ K⁻¹ B λ``
(translations in m, rotations times the trunk length), projected on its principal directions;
:data:`ORDERINGS` names the orders (see :mod:`vertebra.solver.workspace`); each sample's
*generation* (its depth in the forest of parents) says which batch it is solved in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

NEIGHBOURS = 10          # k of the nearest-neighbour graph the spanning tree is taken from
RESPONSE_RANK = 1e-6     # response directions below this fraction of the largest are dropped


def response_coordinates(model, actuations: np.ndarray) -> np.ndarray:
    """Coordinates of each actuation in the trunk's linear response at rest, ``K⁻¹ B λ``
    (translations m, rotations × trunk length), on its principal directions: Euclidean
    distances there approximate how far apart two samples' equilibria are."""
    actuations = np.asarray(actuations, float)
    lower = np.asarray(model.actuator_bounds[0], float)
    lower = np.where(np.isfinite(lower), lower, 0.0)         # given actuations need no finite box
    lin = model.linearise(model.rest_state, lower)
    response = lin.solve(lin.actuator_forces)                         # (n_dof, n_act)
    response = response.reshape(-1, 6, response.shape[1])
    response[:, 3:] *= model.length_scale
    _, s, vt = np.linalg.svd(response.reshape(-1, response.shape[2]), full_matrices=False)
    keep = s > RESPONSE_RANK * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    if not np.any(keep):
        return np.zeros((len(actuations), 1))
    return (actuations - lower) @ (vt[keep].T * s[keep])


@dataclass(frozen=True)
class SolveOrder:
    """The order to solve the samples in, and whose equilibrium each one starts from
    (``parent[i] = -1``: from rest)."""

    order: np.ndarray
    parent: np.ndarray

    def __post_init__(self):
        n = self.parent.size
        if self.order.shape != (n,) or not np.array_equal(np.sort(self.order), np.arange(n)):
            raise ValueError("order must be a permutation of the samples")
        position = np.empty(n, int)
        position[self.order] = np.arange(n)
        has = self.parent >= 0
        if np.any(position[self.parent[has]] >= position[has]):
            raise ValueError("every sample's parent must be solved before it")


def generations(order: SolveOrder) -> np.ndarray:
    """Each sample's depth in the forest of parents (0: from rest): the samples of one
    generation start from equilibria of earlier ones and are solved together."""
    depth = [0] * order.parent.size
    parent = order.parent.tolist()
    for i in order.order.tolist():
        if parent[i] >= 0:
            depth[i] = depth[parent[i]] + 1
    return np.array(depth, int)


def _squared_norms(coordinates: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", coordinates, coordinates)


def order_sampled(coordinates: np.ndarray) -> SolveOrder:
    """The order the sequence drew the samples in, each from the previous one."""
    n = len(coordinates)
    return SolveOrder(np.arange(n), np.arange(n) - 1)


def order_chain(coordinates: np.ndarray) -> SolveOrder:
    """Greedy nearest-neighbour chain from the least deformed sample (k-d tree queries
    widened until an unvisited neighbour appears)."""
    from scipy.spatial import cKDTree

    n = len(coordinates)
    tree = cKDTree(coordinates)
    visited = np.zeros(n, bool)
    order = np.empty(n, int)
    current = int(np.argmin(_squared_norms(coordinates)))
    for i in range(n):
        order[i] = current
        visited[current] = True
        if i == n - 1:
            break
        k = NEIGHBOURS
        while True:
            _, near = tree.query(coordinates[current], k=min(k, n))
            near = np.atleast_1d(near)
            free = near[~visited[near]]
            if free.size:
                current = int(free[0])
                break
            k *= 4        # k ≥ n returns every sample, unvisited ones included
    parent = np.empty(n, int)
    parent[order[0]] = -1
    parent[order[1:]] = order[:-1]
    return SolveOrder(order, parent)


def order_tree(coordinates: np.ndarray) -> SolveOrder:
    """Depth-first visit of the minimum spanning tree of the k-nearest-neighbour graph from
    the least deformed sample; each sample's parent is its tree neighbour on the way from
    that root. Pieces the graph leaves disconnected start from rest."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, depth_first_order, minimum_spanning_tree
    from scipy.spatial import cKDTree

    n = len(coordinates)
    if n == 1:
        return SolveOrder(np.zeros(1, int), np.full(1, -1))
    k = min(NEIGHBOURS, n - 1)
    distance, near = cKDTree(coordinates).query(coordinates, k=k + 1)
    rows = np.repeat(np.arange(n), k)
    # coincident samples are still neighbours: a zero weight would read as "no edge"
    weights = np.maximum(distance[:, 1:].ravel(), np.finfo(float).tiny)
    graph = coo_matrix((weights, (rows, near[:, 1:].ravel())), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T))
    tree = tree.maximum(tree.T)
    _, label = connected_components(tree, directed=False)
    squared = _squared_norms(coordinates)
    order, parent = [], np.full(n, -1)
    for component in np.unique(label):
        members = np.flatnonzero(label == component)
        root = int(members[np.argmin(squared[members])])
        visit, predecessor = depth_first_order(tree, root, directed=False)
        order.append(visit)
        parent[visit[1:]] = predecessor[visit[1:]]
    return SolveOrder(np.concatenate(order), parent)


LEVELS = (512, 64, 8)    # the "levels" order: every 512th sample from rest, then every 64th, every 8th, the others


def order_levels(coordinates: np.ndarray) -> SolveOrder:
    """Coarse to fine, for solving in batches: every 512th sample (of a low-discrepancy sequence:
    spread over the box) starts from rest; every other 64th sample from the nearest of those;
    every other 8th from the nearest of all these, and every other sample from the nearest of
    all (k-d tree queries). Up to four generations, each one batch of independent solves."""
    from scipy.spatial import cKDTree

    n = len(coordinates)
    parent = np.full(n, -1)
    solved = np.arange(0, n, LEVELS[0])
    order = [solved]
    for stride in LEVELS[1:] + (1,):
        level = np.setdiff1d(np.arange(0, n, stride), solved, assume_unique=True)
        if level.size:
            _, near = cKDTree(coordinates[solved]).query(coordinates[level])
            parent[level] = solved[np.asarray(near, int)]
            order.append(level)
            solved = np.union1d(solved, level)
    return SolveOrder(np.concatenate(order), parent)


ORDERINGS: dict[str, Callable[[np.ndarray], SolveOrder]] = {
    "levels": order_levels,
    "tree": order_tree,
    "chain": order_chain,
    "sampled": order_sampled,
}
