"""Cavity volume on a deformed mesh: a closed-surface integral over the walls and the two caps.

By the divergence theorem ``V = ⅓ ∮ x·n dA`` with ``n`` out of the cavity. The walls are P2
triangles (curved): ``x·(x_ξ × x_η)`` is a polynomial of degree 4, integrated exactly by a
6-point rule. Each cap is flat (it lies on a rigid vertebra) and bounded by the wall's rim, so
``∫_cap x·n dA = x₀·a`` with ``x₀`` any rim point and ``a = ½ ∮ x × dx`` the cap's vector area,
integrated exactly along the P2 rim edges. Only deformed node positions enter; nothing assumes
how the vertebrae moved.
"""

from __future__ import annotations

import numpy as np

# Dunavant degree-4 rule on the reference triangle (weights sum to 1; times the area ½)
_A, _B = 0.445948490915965, 0.091576213509771
_TRI_POINTS = np.array([[_A, _A], [1 - 2 * _A, _A], [_A, 1 - 2 * _A],
                        [_B, _B], [1 - 2 * _B, _B], [_B, 1 - 2 * _B]])
_TRI_WEIGHTS = 0.5 * np.array([0.223381589678011] * 3 + [0.109951743655322] * 3)
# 3-point Gauss–Legendre on [0, 1]
_LINE_POINTS = 0.5 + 0.5 * np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])
_LINE_WEIGHTS = 0.5 * np.array([5.0, 8.0, 5.0]) / 9.0


def _tri6_derivatives(points):
    xi, eta = points[:, 0], points[:, 1]
    lam = [1 - xi - eta, xi, eta]
    dl = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
    N = np.stack([lam[0] * (2 * lam[0] - 1), lam[1] * (2 * lam[1] - 1), lam[2] * (2 * lam[2] - 1),
                  4 * lam[0] * lam[1], 4 * lam[1] * lam[2], 4 * lam[2] * lam[0]], axis=1)
    dN = np.zeros((points.shape[0], 6, 2))
    for i in range(3):
        dN[:, i] = (4 * lam[i] - 1)[:, None] * dl[i]
    for j, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        dN[:, 3 + j] = 4 * (lam[a][:, None] * dl[b] + lam[b][:, None] * dl[a])
    return N, dN


_N, _DN = _tri6_derivatives(_TRI_POINTS)


def wall_flux(x: np.ndarray, triangles: np.ndarray) -> float:
    """∫ x·n dA over P2 triangles (normal by the right-hand rule of their node order)."""
    X = x[triangles]                                             # (n, 6, 3)
    pos = np.einsum("qk,tkd->tqd", _N, X)
    t1 = np.einsum("qk,tkd->tqd", _DN[:, :, 0], X)
    t2 = np.einsum("qk,tkd->tqd", _DN[:, :, 1], X)
    return float(np.einsum("tqd,tqd,q->", pos, np.cross(t1, t2), _TRI_WEIGHTS))


def rim_area_vector(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """½ ∮ x × dx along oriented P2 edges (a, b, mid): the vector area the loop encloses."""
    a, b, m = x[edges[:, 0]], x[edges[:, 1]], x[edges[:, 2]]
    out = np.zeros(3)
    for t, w in zip(_LINE_POINTS, _LINE_WEIGHTS):
        r = a * (1 - t) * (1 - 2 * t) + m * 4 * t * (1 - t) + b * t * (2 * t - 1)
        dr = a * (4 * t - 3) + m * (4 - 8 * t) + b * (4 * t - 1)
        out += w * 0.5 * np.cross(r, dr).sum(axis=0)
    return out


def cavity_volume(x: np.ndarray, cavity) -> float:
    """Volume enclosed by the cavity's walls and caps, node positions ``x`` (n, 3).

    The walls are oriented with their normal into the cavity (out of the solid); their rim loops
    then run so that ``−½ ∮ x × dx`` is the cap's vector area with the normal into the cavity too.
    """
    inward = wall_flux(x, cavity.triangles)
    for edges in cavity.rims.values():
        inward += x[edges[0, 0]] @ (-rim_area_vector(x, edges))
    return -inward / 3.0


def cap_area_vector(x: np.ndarray, cavity, end: str) -> np.ndarray:
    """Vector area of one cap, normal out of the cavity (toward the vertebra it loads)."""
    return rim_area_vector(x, cavity.rims[end])
