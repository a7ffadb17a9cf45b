"""Total-Lagrangian assembly on a segment mesh: strain energy, internal forces, tangent
stiffness (material + geometric), cavity volumes as exact functions of the deformed mesh.

The mesh, scalar basis (P1/P2, curved order-2 geometry), DoF numbering, faces and
cavity surfaces are those of the linear designer (:func:`vertebra.designer.fem.build_fe`);
the vector DoF of component ``c`` at scalar DoF ``s`` is ``3 s + c``. The state is
the nodal displacement ``u`` from the reference coordinates ``X`` (``x = X + u``).

Element terms, vectorised over elements and quadrature points (the linear
designer's rule, order ``2·order``): ``H = Σ_a u_a ⊗ ∇N_a``, the material gives
``W, P, A`` (:mod:`.materials`) and

    energy  U = Σ_e Σ_q w W,
    force   f[(a, i)] = Σ_q w P_iJ ∂_J N_a,
    tangent K[(a, i), (b, k)] = Σ_q w ∂_J N_a A_iJkL ∂_L N_b,

scattered into a CSR pattern built once (``np.bincount`` on precomputed positions).

Cavity volume. The volume of cavity ``k`` enclosed by its deformed walls and the
two planar caps on the rigid end faces is ``V = ⅓ ∮ x·n_c dA`` (``n_c`` out of the
cavity). On the walls (6- or 3-node triangles of the mesh) the integrand
``x·(x_ξ × x_η)`` is a polynomial of degree ≤ 4, integrated exactly; its first and
second derivatives with respect to the nodal positions are exact too:

    ∂T/∂x_a = N_a (x_ξ × x_η) + N_a,ξ (x_η × x) + N_a,η (x × x_ξ),
    ∂²T/∂x_a∂x_b = −ŵ_ab,  w_ab = (N_a N_b,ξ − N_b N_a,ξ) x_η + (N_b N_a,η − N_a N_b,η) x_ξ
                                 + (N_a,ξ N_b,η − N_b,ξ N_a,η) x.

The caps move rigidly with the frames (:mod:`.framed`). A cavity pressure ``p``
enters the potential as ``−p V``: its force (the follower load) and its load
stiffness are exact derivatives, so the pressure load is conservative and the
tangent symmetric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vertebra.designer.fem import SegmentFE, vector_element_dofs
from vertebra.designer.nonlinear.materials import jacobian_minus_one
from vertebra.designer.surface import triangle_rule, triangle_shape

#: quadrature degree on wall triangles: x·(x_ξ × x_η) has degree 4 on 6-node triangles
WALL_RULE_DEGREE = 4


@dataclass
class SubPattern:
    """Rows ``rows`` × columns ``cols`` of a :class:`SparsePattern` (a gather, built once)."""

    positions: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    shape: tuple

    def matrix(self, data: np.ndarray):
        from scipy.sparse import csr_matrix
        return csr_matrix((data[self.positions], self.indices, self.indptr), shape=self.shape)


@dataclass
class SparsePattern:
    """CSR structure of the element DoF couplings (sorted rows and columns)."""

    n: int
    rows: np.ndarray
    cols: np.ndarray
    indptr: np.ndarray

    @classmethod
    def from_elements(cls, element_dofs: np.ndarray, n: int) -> tuple["SparsePattern", np.ndarray]:
        """Pattern of ``element_dofs`` (nel, m) and each element entry's position (nel·m·m)."""
        e = element_dofs.astype(np.int64)
        keys = (e[:, :, None] * n + e[:, None, :]).ravel()
        unique, inverse = np.unique(keys, return_inverse=True)
        rows, cols = np.divmod(unique, n)
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
        return cls(n=n, rows=rows, cols=cols, indptr=indptr), inverse

    @property
    def nnz(self) -> int:
        return self.rows.size

    def positions(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Positions of the entries (rows, cols), which must be in the pattern."""
        keys = self.rows * self.n + self.cols
        wanted = np.asarray(rows, dtype=np.int64) * self.n + np.asarray(cols, dtype=np.int64)
        pos = np.searchsorted(keys, wanted.ravel())
        if np.any(pos >= keys.size) or np.any(keys[np.minimum(pos, keys.size - 1)] != wanted.ravel()):
            raise ValueError("entries outside the element pattern")
        return pos.reshape(np.shape(wanted))

    def matrix(self, data: np.ndarray):
        from scipy.sparse import csr_matrix
        return csr_matrix((data, self.cols, self.indptr), shape=(self.n, self.n))

    def sub(self, rows: np.ndarray, cols: np.ndarray) -> SubPattern:
        """Gather of the block ``rows × cols`` (index arrays into 0..n−1)."""
        row_map = np.full(self.n, -1, dtype=np.int64)
        row_map[rows] = np.arange(rows.size)
        col_map = np.full(self.n, -1, dtype=np.int64)
        col_map[cols] = np.arange(cols.size)
        r, c = row_map[self.rows], col_map[self.cols]
        keep = (r >= 0) & (c >= 0)
        positions = np.flatnonzero(keep)
        r, c = r[keep], c[keep]
        order = np.lexsort((c, r))
        positions, r, c = positions[order], r[order], c[order]
        index = np.int32 if positions.size < 2 ** 31 else np.int64      # scipy's index type for this size
        indptr = np.zeros(rows.size + 1, dtype=index)
        np.cumsum(np.bincount(r, minlength=rows.size), out=indptr[1:])
        return SubPattern(positions=positions, indptr=indptr, indices=c.astype(index), shape=(rows.size, cols.size))


@dataclass
class CavityWall:
    """Quadrature data of one cavity's wall triangles for the volume and its derivatives."""

    dofs: np.ndarray        # (n_tri, k, 3) DoFs of each triangle node
    X: np.ndarray           # (n_tri, k, 3) reference node coordinates
    N: np.ndarray           # (nq, k) shape functions
    dN: np.ndarray          # (nq, k, 2) derivatives in (ξ, η)
    weight: np.ndarray      # (n_tri, nq) quadrature weight × orientation (n_c = out of the cavity) / 3
    coefficients: np.ndarray  # (nq, 3, k, k): c1, c2, c3 of the second derivative
    scatter: np.ndarray     # (n_tri·(3k)²,) positions of the Hessian entries in the pattern

    @classmethod
    def build(cls, surface, node_dofs: np.ndarray, pattern: SparsePattern) -> "CavityWall":
        points, weights = triangle_rule(WALL_RULE_DEGREE)
        k = surface.nodes.shape[1]
        N, dN = triangle_shape(points, k)
        dofs = node_dofs[surface.nodes]                                  # (n_tri, k, 3)
        # Surface.sign orients x_ξ × x_η out of the solid, i.e. into the cavity
        weight = (-surface.sign)[:, None] * weights[None, :] / 3.0
        Nx, Ne = dN[..., 0], dN[..., 1]
        c1 = N[:, :, None] * Nx[:, None, :] - Nx[:, :, None] * N[:, None, :]
        c2 = Ne[:, :, None] * N[:, None, :] - N[:, :, None] * Ne[:, None, :]
        c3 = Nx[:, :, None] * Ne[:, None, :] - Ne[:, :, None] * Nx[:, None, :]
        flat = dofs.reshape(dofs.shape[0], -1)                           # local index 3a + i
        rows = np.broadcast_to(flat[:, :, None], flat.shape + flat.shape[1:])
        cols = np.broadcast_to(flat[:, None, :], rows.shape)
        return cls(dofs=dofs, X=surface.X.copy(), N=N, dN=dN, weight=weight,
                   coefficients=np.stack([c1, c2, c3], axis=1),
                   scatter=pattern.positions(rows, cols).ravel())

    def volume(self, u: np.ndarray, order: int = 2):
        """Wall part of ``V`` and, with ``order`` ≥ 1, its gradient (n_dofs) and, with
        ``order`` = 2, its Hessian entries in pattern order of :attr:`scatter`."""
        x = self.X + u[self.dofs]                                        # (n_tri, k, 3)
        xq = np.einsum("qk,tkd->tqd", self.N, x)
        xs = np.einsum("qk,tkd->tqd", self.dN[..., 0], x)
        xe = np.einsum("qk,tkd->tqd", self.dN[..., 1], x)
        n = np.cross(xs, xe)
        value = float(np.einsum("tq,tqd,tqd->", self.weight, xq, n))
        if order == 0:
            return value, None, None
        w = self.weight[..., None]
        grad_local = (np.einsum("qk,tqd->tkd", self.N, w * n)
                      + np.einsum("qk,tqd->tkd", self.dN[..., 0], w * np.cross(xe, xq))
                      + np.einsum("qk,tqd->tkd", self.dN[..., 1], w * np.cross(xq, xs)))
        grad = np.bincount(self.dofs.ravel(), weights=grad_local.ravel(), minlength=u.size)
        if order == 1:
            return value, grad, None
        c1, c2, c3 = self.coefficients[:, 0], self.coefficients[:, 1], self.coefficients[:, 2]
        wab = (np.einsum("qab,tqd->tabd", c1, w * xe) + np.einsum("qab,tqd->tabd", c2, w * xs)
               + np.einsum("qab,tqd->tabd", c3, w * xq))                 # (n_tri, k, k, 3)
        # block (a, b) = −ŵ_ab; entry [a, i, b, j] = ε_ijl w_l
        hess = np.zeros(wab.shape[:3] + (3, 3))
        hess[..., 0, 1], hess[..., 1, 0] = wab[..., 2], -wab[..., 2]
        hess[..., 1, 2], hess[..., 2, 1] = wab[..., 0], -wab[..., 0]
        hess[..., 2, 0], hess[..., 0, 2] = wab[..., 1], -wab[..., 1]
        return value, grad, hess.transpose(0, 1, 3, 2, 4).ravel()


@dataclass
class SolidEvaluation:
    """Strain energy, gradient and Hessian of the solid plus cavity-wall volumes (full DoF space)."""

    strain_energy: float
    internal_force: np.ndarray          # ∂U/∂u (n_dofs)
    wall_volumes: np.ndarray            # (n_cav,) wall parts of the cavity volumes
    wall_gradients: list                # per cavity: ∂V_wall/∂u (n_dofs), None without derivatives
    hessian_data: np.ndarray | None     # values in the SparsePattern of ∂²(U − Σ p V_wall)/∂u²
    min_jacobian: float


class SolidModel:
    """Hyperelastic total-Lagrangian model of one segment mesh (built once, evaluated many times)."""

    def __init__(self, fe: SegmentFE, material):
        basis = fe.basis
        self.fe = fe
        self.material = material
        self.n_dofs = fe.n_dofs
        grads = np.array([b[0].grad for b in basis.basis])              # (nb, 3, nel, nq)
        self.grads = np.ascontiguousarray(grads.transpose(2, 3, 0, 1))  # (nel, nq, nb, 3)
        self.dx = np.ascontiguousarray(basis.dx)                         # (nel, nq)
        self.element_dofs = np.ascontiguousarray(vector_element_dofs(basis).T)   # (nel, 3nb), local 3a + i
        self.nb = grads.shape[0]
        self.X = fe.doflocs[fe.components, np.arange(fe.n_dofs)].copy()  # reference coordinate per DoF
        self.pattern, self.element_scatter = SparsePattern.from_elements(self.element_dofs, self.n_dofs)
        values = np.array([np.array(b[0]) for b in basis.basis])            # (nb, nel, nq)
        lumped = np.einsum("aeq,eq->ea", values, self.dx)                 # ∫ N_a dV per element
        scalar_mass = np.bincount(basis.element_dofs.T.ravel(), weights=lumped.ravel(), minlength=basis.N)
        self.volume_weights = np.repeat(scalar_mass, 3)                  # ∫ N_a dV at each vector DoF
        self.walls = [CavityWall.build(s, fe.node_dofs, self.pattern) for s in fe.cavity_surfaces]

    @property
    def n_cavities(self) -> int:
        return len(self.walls)

    def gradient_field(self, u: np.ndarray) -> np.ndarray:
        """``H = ∇_X u`` at the quadrature points (nel, nq, 3, 3)."""
        ue = u[self.element_dofs].reshape(-1, self.nb, 3)
        return np.einsum("eai,eqaJ->eqiJ", ue, self.grads, optimize=True)

    def strain_energy(self, u: np.ndarray) -> float:
        W = self.material.energy(self.gradient_field(u))
        return float(np.einsum("eq,eq->", self.dx, W))

    def evaluate(self, u: np.ndarray, pressures=None, order: int = 2) -> SolidEvaluation:
        """Energy (order 0), forces (1) and the tangent of ``U − Σ p V_wall`` (2)."""
        H = self.gradient_field(u)
        W, P, A = self.material.evaluate(H, tangent=order >= 2) if order >= 1 else (self.material.energy(H), None, None)
        energy = float(np.einsum("eq,eq->", self.dx, W))
        min_jacobian = 1.0 + float(np.min(jacobian_minus_one(H)))
        pressures = np.zeros(self.n_cavities) if pressures is None else np.asarray(pressures, dtype=float)
        walls = [wall.volume(u, order) for wall in self.walls]
        if order == 0:
            return SolidEvaluation(energy, None, np.array([w[0] for w in walls]), [None] * len(walls), None,
                                   min_jacobian)
        Pw = P * self.dx[..., None, None]
        local = np.einsum("eqiJ,eqaJ->eai", Pw, self.grads, optimize=True)
        force = np.bincount(self.element_dofs.ravel(), weights=local.ravel(), minlength=self.n_dofs)
        data = None
        if order >= 2:
            data = np.bincount(self.element_scatter, weights=self._element_tangent(A).ravel(),
                               minlength=self.pattern.nnz)
            for p, wall, (_, _, hess) in zip(pressures, self.walls, walls):
                if p != 0.0:
                    data -= p * np.bincount(wall.scatter, weights=hess, minlength=self.pattern.nnz)
        return SolidEvaluation(energy, force, np.array([w[0] for w in walls]), [w[1] for w in walls], data,
                               min_jacobian)

    def _element_tangent(self, A: np.ndarray) -> np.ndarray:
        """(nel, 3nb, 3nb) element tangents ``Σ_q w ∂_J N_a A_iJkL ∂_L N_b``, one quadrature point
        at a time (bounded memory: ~nel·(3nb)² doubles)."""
        nel, nq, nb = self.grads.shape[:3]
        K = np.zeros((nel, nb, 3, 3, nb))                               # [a, i, k, b]
        for q in range(nq):
            G = self.grads[:, q]                                         # (nel, nb, 3)
            Aq = A[:, q] * self.dx[:, q, None, None, None, None]         # (nel, i, J, k, L)
            Aq = Aq.transpose(0, 2, 1, 3, 4).reshape(nel, 3, 27)         # [J, (i k L)]
            T = np.matmul(G, Aq).reshape(nel, nb * 9, 3)                 # [(a i k), L]
            K += np.matmul(T, G.transpose(0, 2, 1)).reshape(nel, nb, 3, 3, nb)
        return K.transpose(0, 1, 2, 4, 3).reshape(nel, 3 * nb, 3 * nb)
