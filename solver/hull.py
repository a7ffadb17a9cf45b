"""Convex hulls of effector point clouds in their affine span (scipy's Qhull)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Hull:
    """Convex hull of a point cloud in its affine span: ``dimension`` 3 gives ``volume`` (m³)
    and ``area`` (surface, m²); 2 (a planar cloud) gives ``area`` (m²) and no volume; 1 or 0
    neither. ``simplices`` index the cloud's points (triangles in 3D, edges in 2D)."""

    dimension: int
    volume: float | None
    area: float | None
    simplices: np.ndarray
    vertices: np.ndarray


def affine_dimension(points: np.ndarray, *, tolerance: float = 1e-9) -> int:
    """Dimension of the affine span of ``points``: singular values of the centred cloud above
    ``tolerance`` × its extent × √(number of points) count."""
    if len(points) < 2:
        return 0
    centred = points - points.mean(0)
    s = np.linalg.svd(centred, compute_uv=False)
    scale = max(float(np.ptp(points, axis=0).max()), np.finfo(float).tiny)
    return int(np.sum(s > tolerance * scale * math.sqrt(len(points))))


def convex_hull(points: np.ndarray) -> Hull:
    """Convex hull of a 3D point cloud; of a planar cloud, taken in its plane."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, float)
    dimension = affine_dimension(points)
    if dimension == 3:
        try:
            hull = ConvexHull(points)
            return Hull(3, float(hull.volume), float(hull.area), hull.simplices, hull.vertices)
        except QhullError:        # nearly flat beyond what the rank test caught
            dimension = 2
    if dimension == 2:
        centred = points - points.mean(0)
        basis = np.linalg.svd(centred, full_matrices=False)[2][:2]
        try:
            hull = ConvexHull(centred @ basis.T)
            return Hull(2, None, float(hull.volume), hull.simplices, hull.vertices)   # 2D: volume = area
        except QhullError:
            dimension = 1
    return Hull(dimension, None, None, np.zeros((0, 3), int), np.zeros(0, int))
