"""Integrals over boundary surfaces (cavity walls) on the mesh's own triangles.

scikit-fem's ``FacetBasis`` on a curved (tetra10) mesh locates facet quadrature
points by inverting the isoparametric map with Newton, which fails on coarse,
strongly curved elements ("Newton iteration didn't converge") and is slow. The
trace of a P2 tetrahedron on a face is the 6-node triangle of that face, so we
integrate on the boundary triangles directly: ``x(ξ)`` from the triangle's nodes,
``n dA = x_ξ × x_η dξ dη`` oriented out of the solid, and the trace of the
volume basis = the triangle's shape functions. With a rule exact for the
polynomial degree (``n dA`` is quadratic on a 6-node triangle) the closed-surface
identities (∮ n dA = 0, divergence theorem) hold to round-off on the discrete
geometry — what makes the cavity pressure load exactly self-equilibrated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# symmetric Gauss rules on the reference triangle (0,0), (1,0), (0,1); weights sum to 1/2
_RULES = {}


def triangle_rule(degree: int):
    if degree not in _RULES:
        from skfem.quadrature import get_quadrature
        from skfem.refdom import RefTri
        points, weights = get_quadrature(RefTri, degree)
        _RULES[degree] = (points.T.copy(), weights.copy())
    return _RULES[degree]


def triangle_shape(points: np.ndarray, k: int):
    """Shape functions (nq, k) and derivatives (nq, k, 2) of the 3- or 6-node triangle
    (gmsh order: corners, then edges (0,1), (1,2), (2,0))."""
    xi, eta = points[:, 0], points[:, 1]
    l0, l1, l2 = 1 - xi - eta, xi, eta
    dl = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])          # dλ_i/d(ξ, η)
    if k == 3:
        N = np.stack([l0, l1, l2], axis=1)
        dN = np.broadcast_to(dl, (points.shape[0], 3, 2)).copy()
        return N, dN
    lam = [l0, l1, l2]
    N = np.stack([l0 * (2 * l0 - 1), l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), 4 * l0 * l1, 4 * l1 * l2, 4 * l2 * l0],
                 axis=1)
    dN = np.zeros((points.shape[0], 6, 2))
    for i in range(3):
        dN[:, i, :] = (4 * lam[i] - 1)[:, None] * dl[i]
    for j, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        dN[:, 3 + j, :] = 4 * (lam[a][:, None] * dl[b] + lam[b][:, None] * dl[a])
    return N, dN


@dataclass
class Surface:
    """Quadrature data of a set of boundary triangles, normals out of the solid."""

    nodes: np.ndarray       # (n_tri, k) node indices (mesh numbering)
    N: np.ndarray           # (nq, k) shape functions at the quadrature points
    x: np.ndarray           # (n_tri, nq, 3) quadrature points
    ndA: np.ndarray         # (n_tri, nq, 3) outward normal × area weight (quadrature weight included)
    X: np.ndarray           # (n_tri, k, 3) node coordinates
    sign: np.ndarray        # (n_tri,) orientation factor applied to x_ξ × x_η

    @classmethod
    def build(cls, coordinates: np.ndarray, triangles: np.ndarray, inside_points: np.ndarray,
              degree: int = 6) -> "Surface":
        """``inside_points`` (n_tri, 3): for each triangle the opposite vertex of its tetrahedron;
        the normal is flipped to point away from it."""
        X = coordinates[triangles]                                   # (n_tri, k, 3)
        N, x, nda = cls._geometry(X, degree)
        # orientation from the corner triangle: (X1 − X0) × (X2 − X0) · (X0 − inside) is −6 × the signed
        # volume of the tetrahedron on the triangle, exact whatever the curvature (the curved normal
        # sum tilted one strongly curved 6-node triangle of a coarse chamber wall past the tangent)
        flat = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
        sign = np.sign(np.einsum("td,td->t", flat, X[:, 0] - inside_points))
        sign[sign == 0] = 1.0
        return cls(nodes=triangles, N=N, x=x, ndA=nda * sign[:, None, None], X=X, sign=sign)

    @staticmethod
    def _geometry(X, degree):
        points, weights = triangle_rule(degree)
        N, dN = triangle_shape(points, X.shape[1])
        x = np.einsum("qk,tkd->tqd", N, X)
        dxi = np.einsum("qk,tkd->tqd", dN[:, :, 0], X)
        deta = np.einsum("qk,tkd->tqd", dN[:, :, 1], X)
        return N, x, np.cross(dxi, deta) * weights[None, :, None]

    def with_degree(self, degree: int) -> "Surface":
        """The same triangles with another quadrature rule."""
        N, x, nda = self._geometry(self.X, degree)
        return Surface(nodes=self.nodes, N=N, x=x, ndA=nda * self.sign[:, None, None], X=self.X, sign=self.sign)

    def flux(self, field: np.ndarray) -> float:
        """∫ F·n dA for a vector field given at the quadrature points, ``field`` (n_tri, nq, 3)."""
        return float(np.einsum("tqd,tqd->", field, self.ndA))

    def load(self, node_dofs: np.ndarray, n_dofs: int, sign: float = -1.0) -> np.ndarray:
        """Vector ``sign · ∫ φ_a n_c dA`` at DoF (a, c): the load of unit pressure (sign −1) on
        the solid. ``node_dofs`` (n_nodes, 3) maps a node to its three displacement DoFs."""
        # (n_tri, k, 3): ∫ N_a n_c dA
        local = np.einsum("qk,tqd->tkd", self.N, self.ndA)
        out = np.zeros(n_dofs)
        np.add.at(out, node_dofs[self.nodes].reshape(-1), sign * local.reshape(-1))
        return out

    def interpolate(self, u: np.ndarray, node_dofs: np.ndarray) -> np.ndarray:
        """A nodal displacement vector at the quadrature points (n_tri, nq, 3)."""
        values = u[node_dofs[self.nodes]]                            # (n_tri, k, 3)
        return np.einsum("qk,tkd->tqd", self.N, values)
