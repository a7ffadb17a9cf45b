"""Linear elasticity of one segment with scikit-fem, rigid end faces, condensation.

Rigid coupling (paper eq. 1–3). The displacement of every FE node on an end face
follows the 6-DoF frame of that face: ``u = t + θ × (x - c)`` with ``c`` the
face centre on the axis, i.e. ``u_face = T q_frame``. The reduced unknowns are
the interior DoFs ``u_i`` and the frame DoFs ``q``; the reduced stiffness is
``Pᵀ K P`` with ``P = diag(I, T)`` (a Galerkin master–slave reduction — not
``skfem.utils.mpc``, which drops the slave rows). We never form it:
with ``K_iq = K_it T`` and ``K_qq = Tᵀ K_tt T`` the frame DoFs are condensed by
a Schur complement

    S = K_qq − K_qiᵀ K_ii⁻¹ K_iq        (frame stiffness; C = S⁻¹, paper eq. 2)

which needs ``K_ii⁻¹`` applied to 6 (+ one per cavity) right-hand sides only;
``K_ii`` is a Dirichlet elasticity matrix, so AMG with rigid-body modes fits.

Cavities. Unit pressure in cavity k loads the cavity walls (``-dot(n, v)`` with
the solid's outward normal ``n``) and the two rigid caps that seal it (the
vertebrae: force ``A_cap`` along the cavity's outward normal, applied to the
frames). The same linear form measures the volume growth of the cavity
(``ΔV = ∫ u·n_cav`` over walls and caps), so the (6+n)×(6+n) compliance
``[[C, G], [Gᵀ, V]]`` is symmetric by Maxwell–Betti. The cap areas and first
moments come from the wall integrals by the divergence theorem, so the discrete
pressure load is exactly self-equilibrated (a rigid motion of the whole segment
does no work against it) — the condition for the condensed link to be exact
when frame a is not clamped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.core.errors import GeometryError
from vertebra.designer.linsolve import get_solver
from vertebra.designer.surface import Surface


def rigid_map(doflocs: np.ndarray, components: np.ndarray, centre) -> np.ndarray:
    """T (n_dofs × 6): displacement component of each DoF for frame motion ``[t; θ]`` at ``centre``:
    ``u = t + θ × (x − c)``."""
    r = doflocs - np.asarray(centre, dtype=float)[:, None]          # (3, n)
    n = components.size
    T = np.zeros((n, 6))
    T[np.arange(n), components] = 1.0
    rx, ry, rz = r
    # θ × r = (θy rz − θz ry, θz rx − θx rz, θx ry − θy rx)
    rot = np.zeros((n, 3))
    c0, c1, c2 = components == 0, components == 1, components == 2
    rot[c0, 1], rot[c0, 2] = rz[c0], -ry[c0]
    rot[c1, 0], rot[c1, 2] = -rz[c1], rx[c1]
    rot[c2, 0], rot[c2, 1] = ry[c2], -rx[c2]
    T[:, 3:] = rot
    return T


def rigid_body_modes(doflocs: np.ndarray, components: np.ndarray) -> np.ndarray:
    """(n_dofs × 6) rigid-body modes (translations, rotations about the origin)."""
    return rigid_map(doflocs, components, np.zeros(3))


@dataclass
class SegmentFE:
    """Assembled FE model of one segment: stiffness, face maps, cavity loads, mass data."""

    mesh: object
    basis: object                   # scalar scikit-fem basis (P1/P2) on the mesh
    doflocs: np.ndarray             # (3, n_dofs) location of each displacement DoF
    K: object                       # full sparse stiffness (n_dofs × n_dofs)
    length: float
    order: int
    faces: dict                     # "bottom"/"top" -> dict(dofs, T (n×6), centre)
    cavity_loads: list              # per cavity: full load vector of unit pressure on the walls
    cap_wrenches: list              # per cavity: {"bottom": 6-vector on frame a, "top": 6-vector on frame b}
    cavity_volumes: np.ndarray
    mass: float
    center_of_mass: np.ndarray
    components: np.ndarray          # component (0, 1, 2) of each DoF
    node_dofs: np.ndarray = None    # (n_nodes, 3) DoFs of each mesh node
    cavity_surfaces: list = field(default_factory=list)   # per cavity: designer.surface.Surface of its walls
    timings: dict = field(default_factory=dict)

    @property
    def n_dofs(self) -> int:
        return self.K.shape[0]

    @property
    def n_cavities(self) -> int:
        return len(self.cavity_loads)

    def interior(self, faces=("bottom", "top")) -> np.ndarray:
        mask = np.ones(self.n_dofs, dtype=bool)
        for name in faces:
            mask[self.faces[name]["dofs"]] = False
        return np.flatnonzero(mask)


def _facet_index(mesh, corner: np.ndarray, name: str, unique: bool = True) -> np.ndarray:
    """Indices into ``mesh.facets`` of the triangles ``corner`` (n × 3 vertex indices)."""
    nv = np.int64(mesh.t.max() + 1)
    f = np.sort(mesh.facets, axis=0).astype(np.int64)
    keys = (f[0] * nv + f[1]) * nv + f[2]
    c = np.sort(corner, axis=1).astype(np.int64)
    wanted = (c[:, 0] * nv + c[:, 1]) * nv + c[:, 2]
    order = np.argsort(keys)
    pos = np.searchsorted(keys, wanted, sorter=order)
    pos = np.clip(pos, 0, keys.size - 1)
    found = order[pos]
    if not np.all(keys[found] == wanted):
        raise GeometryError(f"group {name!r}: {int(np.sum(keys[found] != wanted))} boundary triangles "
                            "do not match mesh facets")
    return np.unique(found) if unique else found


def vector_element_dofs(scalar_basis) -> np.ndarray:
    """(3·nb, nel) DoFs of the vector field: scikit-fem's ``ElementVector`` numbers the DoF of
    component ``c`` at scalar DoF ``s`` as ``3 s + c`` and local DoF ``(a, c)`` as ``3 a + c``
    (checked against ``Basis(mesh, ElementVector(e))`` in tests/test_designer_fem.py)."""
    e = scalar_basis.element_dofs
    return (3 * e[:, None, :] + np.arange(3)[None, :, None]).reshape(-1, e.shape[1])


def assemble_elasticity(scalar_basis, lam: float, mu: float):
    """Isotropic linear elasticity stiffness, vectorised over elements and quadrature points.

    Same matrix as ``skfem.models.elasticity.linear_elasticity`` (checked to round-off in
    tests/test_designer_fem.py) but ~40× faster for P2: with ``u = φ_a e_i``,
    ``K[(a,i),(b,j)] = ∫ λ ∂_iφ_a ∂_jφ_b + μ (δ_ij ∇φ_a·∇φ_b + ∂_jφ_a ∂_iφ_b)``.
    Local vector DoF ``(a, i)`` is ``3a + i`` (:func:`vector_element_dofs`). Building only the
    scalar basis also saves the vector basis' own isoparametric set-up.
    """
    from scipy.sparse import coo_matrix

    grads = np.array([b[0].grad for b in scalar_basis.basis])           # (nb, 3, nel, nq)
    M = np.einsum("aieq,bjeq,eq->eabij", grads, grads, scalar_basis.dx, optimize=True)
    trace = np.einsum("eabkk->eab", M)
    local = lam * M + mu * np.swapaxes(M, 3, 4) + mu * trace[..., None, None] * np.eye(3)
    nb = grads.shape[0]
    local = local.transpose(0, 1, 3, 2, 4).reshape(-1, 3 * nb, 3 * nb)
    dofs = vector_element_dofs(scalar_basis).T                              # (nel, 3nb)
    rows = np.broadcast_to(dofs[:, :, None], local.shape).ravel()
    cols = np.broadcast_to(dofs[:, None, :], local.shape).ravel()
    n = 3 * scalar_basis.N
    return coo_matrix((local.ravel(), (rows, cols)), shape=(n, n)).tocsr()


def build_fe(mesh_data, youngs_modulus: float, poisson_ratio: float, density: float,
             n_cavities: int, length: float) -> SegmentFE:
    """Assemble the segment: scikit-fem mesh from the gmsh arrays, P1/P2 vector basis,
    stiffness, rigid face maps, cavity loads, cap wrenches, rest volumes, mass."""
    from skfem import Basis, ElementTetP1, ElementTetP2, Functional, MeshTet1, MeshTet2, asm
    from skfem.models.elasticity import lame_parameters

    start = time.perf_counter()
    order = mesh_data.order
    mesh_cls, element = (MeshTet1, ElementTetP1()) if order == 1 else (MeshTet2, ElementTetP2())
    mesh = mesh_cls(np.ascontiguousarray(mesh_data.nodes.T), np.ascontiguousarray(mesh_data.tets.T))
    intorder = 2 * order
    scalar = Basis(mesh, element, intorder=intorder)
    K = assemble_elasticity(scalar, *lame_parameters(youngs_modulus, poisson_ratio))
    n_dofs = 3 * scalar.N
    doflocs = np.repeat(scalar.doflocs, 3, axis=1)                       # location of each vector DoF
    # node (mesh numbering) -> its three displacement DoFs
    element_dofs = vector_element_dofs(scalar)
    node_dofs = np.empty((mesh_data.nodes.shape[0], 3), dtype=np.int64)
    for a in range(mesh_data.tets.shape[1]):
        for c in range(3):
            node_dofs[mesh_data.tets[:, a], c] = element_dofs[3 * a + c]
    components = np.empty(n_dofs, dtype=np.int64)
    components[node_dofs] = np.arange(3)[None, :]

    def surface(name):
        triangles = mesh_data.facets[name]
        facets = _facet_index(mesh, triangles[:, :3], name, unique=False)
        tets = mesh.t[:, mesh.f2t[0, facets]]
        opposite = tets.sum(axis=0) - triangles[:, :3].sum(axis=1)     # the tet vertex off the face
        return Surface.build(mesh_data.nodes, triangles, mesh_data.nodes[opposite])

    faces = {}
    for name, centre in (("bottom", (0.0, 0.0, 0.0)), ("top", (0.0, 0.0, length))):
        dofs = np.sort(node_dofs[np.unique(mesh_data.facets[name])].reshape(-1))
        faces[name] = {"dofs": dofs, "centre": np.array(centre),
                       "T": rigid_map(doflocs[:, dofs], components[dofs], centre)}

    cavity_loads, cap_wrenches, volumes, cavity_surfaces = [], [], [], []
    for k in range(n_cavities):
        walls = surface(f"cavity_{k}")
        cavity_surfaces.append(walls)
        cavity_loads.append(walls.load(node_dofs, n_dofs))          # −∫ n·v dA, unit pressure
        wrench_a, wrench_b, volume = _caps(walls, length)
        cap_wrenches.append({"bottom": wrench_a, "top": wrench_b})
        volumes.append(volume)

    one = Functional(lambda w: density + 0.0 * w.x[0])
    mass = float(asm(one, scalar))
    vol = float(asm(Functional(lambda w: 1.0 + 0.0 * w.x[0]), scalar))
    centroid = np.array([float(asm(Functional(lambda w, i=i: w.x[i]), scalar)) for i in range(3)]) / vol
    timings = {"assemble_s": time.perf_counter() - start}
    return SegmentFE(mesh=mesh, basis=scalar, doflocs=doflocs, K=K, length=length, order=order, faces=faces,
                     cavity_loads=cavity_loads, cap_wrenches=cap_wrenches,
                     cavity_volumes=np.array(volumes, dtype=float), mass=mass, center_of_mass=centroid,
                     components=components, timings=timings, node_dofs=node_dofs,
                     cavity_surfaces=cavity_surfaces)


def _caps(walls, length: float):
    """Cap wrenches of unit pressure and the rest volume of one cavity, from wall integrals.

    ``n_c = −n`` is the cavity's outward normal on the walls; on the caps it is
    ``+e_z`` (top, z = L) and ``−e_z`` (bottom, z = 0). Divergence theorem on the
    closed cavity (walls + caps), with the fields (x/2, y/2, 0), (0, 0, z),
    (x²/2, 0, 0) and (0, 0, x z) / (0, 0, x (z − L)) giving the volume, the top
    cap area, ∫ x dV and the caps' first moments. Exact on the discrete geometry.
    """
    x = walls.x
    zero = np.zeros(x.shape[:2])

    def flux_c(fx, fy, fz):                     # ∫ F·n_c dA over the walls
        return -walls.flux(np.stack([fx + zero, fy + zero, fz + zero], axis=-1))

    X, Y, Z = x[..., 0], x[..., 1], x[..., 2]
    V = flux_c(0.5 * X, 0.5 * Y, 0.0)
    A_top = (V - flux_c(0.0, 0.0, Z)) / length
    A_bot = A_top + flux_c(0.0, 0.0, 1.0)       # net force on the closed cavity is zero
    first = {}
    for axis, C in (("x", X), ("y", Y)):
        Q = flux_c(0.5 * C ** 2, 0.0, 0.0) if axis == "x" else flux_c(0.0, 0.5 * C ** 2, 0.0)   # ∫ C dV
        first[("top", axis)] = (Q - flux_c(0.0, 0.0, C * Z)) / length
        first[("bot", axis)] = (Q - flux_c(0.0, 0.0, C * (Z - length))) / length
    # wrench of unit pressure on frame b (at (0,0,L)): force A e_z, moment ∫ (x, y, 0) × e_z dA
    wrench_b = np.array([0.0, 0.0, A_top, first[("top", "y")], -first[("top", "x")], 0.0])
    # on frame a (at the origin): force −A e_z, moment ∫ (x, y, 0) × (−e_z) dA
    wrench_a = np.array([0.0, 0.0, -A_bot, -first[("bot", "y")], first[("bot", "x")], 0.0])
    return wrench_a, wrench_b, V


@dataclass
class Condensation:
    """Result of condensing a segment onto its frame(s)."""

    stiffness: np.ndarray           # S (6m × 6m), m = number of free frames
    pressure_wrench: np.ndarray     # g (6m × n): condensed unit-pressure loads on the frames
    interior_volume: np.ndarray     # F_iᵀ K_ii⁻¹ F_i (n × n)
    info: dict
    solve_s: float

    def compliance(self) -> np.ndarray:
        """[[C, G], [Gᵀ, V]] (clamped frame a, one free frame b)."""
        C = np.linalg.inv(self.stiffness)
        C = 0.5 * (C + C.T)
        G = C @ self.pressure_wrench
        V = self.interior_volume + self.pressure_wrench.T @ G
        V = 0.5 * (V + V.T)
        return np.block([[C, G], [G.T, V]])


def _asymmetry(A: np.ndarray) -> float:
    """max |A − Aᵀ| relative to the diagonal scale (0 for an empty matrix)."""
    if A.size == 0:
        return 0.0
    d = np.sqrt(np.abs(np.diag(A)))
    return float(np.max(np.abs(A - A.T) / np.outer(d, d)))


def condense(fe: SegmentFE, frames=("top",), linear_solver: str = "auto", amg_threshold: int | None = None,
             extra_rhs: np.ndarray | None = None) -> Condensation:
    """Schur complement onto the frames in ``frames`` (the other end face, if any, is clamped).

    ``frames=("top",)`` gives the clamped-a compliance; ``("bottom", "top")`` the
    free-free 12×12 frame stiffness (with its six rigid-body modes).
    """
    start = time.perf_counter()
    interior = fe.interior()
    K = fe.K
    Kii = K[interior][:, interior]
    blocks = []
    for name in frames:
        face = fe.faces[name]
        blocks.append((K[interior][:, face["dofs"]] @ face["T"]))
    Kiq = np.hstack(blocks)
    m6 = 6 * len(frames)
    Kqq = np.zeros((m6, m6))
    for a, na in enumerate(frames):
        for b, nb in enumerate(frames):
            fa, fb_ = fe.faces[na], fe.faces[nb]
            Kqq[6 * a:6 * a + 6, 6 * b:6 * b + 6] = fa["T"].T @ (K[fa["dofs"]][:, fb_["dofs"]] @ fb_["T"])
    n = fe.n_cavities
    Fi = np.column_stack([f[interior] for f in fe.cavity_loads]) if n else np.zeros((interior.size, 0))
    Fq = np.zeros((m6, n))
    for k, f in enumerate(fe.cavity_loads):
        for a, name in enumerate(frames):
            face = fe.faces[name]
            Fq[6 * a:6 * a + 6, k] = face["T"].T @ f[face["dofs"]] + fe.cap_wrenches[k][name]
    rhs = np.hstack([Kiq, Fi] + ([extra_rhs[interior]] if extra_rhs is not None else []))
    solver = get_solver(linear_solver, interior.size, amg_threshold)
    modes = rigid_body_modes(fe.doflocs[:, interior], fe.components[interior])
    X, info = solver.solve(Kii, rhs, modes)
    Xq, Xf = X[:, :m6], X[:, m6:m6 + n]
    S = Kqq - Kiq.T @ Xq
    g = Fq - Kiq.T @ Xf
    Vi = Fi.T @ Xf
    info = dict(info, interior_dofs=int(interior.size), asymmetry_S=_asymmetry(S), asymmetry_V=_asymmetry(Vi))
    S = 0.5 * (S + S.T)
    Vi = 0.5 * (Vi + Vi.T)
    return Condensation(stiffness=S, pressure_wrench=g, interior_volume=Vi, info=info,
                        solve_s=time.perf_counter() - start)


def face_load(fe: SegmentFE, name: str, pressures) -> np.ndarray:
    """Generalised load on the frame of face ``name`` from cavity pressures (walls + cap)."""
    face = fe.faces[name]
    out = np.zeros(6)
    for k, p in enumerate(np.reshape(pressures, -1) if fe.n_cavities else []):
        out += p * (face["T"].T @ fe.cavity_loads[k][face["dofs"]] + fe.cap_wrenches[k][name])
    return out


def displacement_field(fe: SegmentFE, q_top, pressures=None, q_bottom=None) -> np.ndarray:
    """Full nodal displacement for given frame motions and cavity pressures (direct solve):
    faces follow their frames rigidly, the interior solves ``K_ii u_i = F_i p − K_i,faces u_faces``.
    ``q_top`` (6,) or (6, m) for m load cases at once (then ``pressures`` (n, m))."""
    from scipy.sparse.linalg import splu

    q_top = np.asarray(q_top, float)
    single = q_top.ndim == 1
    Q = q_top.reshape(6, -1)
    m = Q.shape[1]
    u = np.zeros((fe.n_dofs, m))
    u[fe.faces["top"]["dofs"]] = fe.faces["top"]["T"] @ Q
    if q_bottom is not None:
        u[fe.faces["bottom"]["dofs"]] = fe.faces["bottom"]["T"] @ np.asarray(q_bottom, float).reshape(6, -1)
    interior = fe.interior()
    rhs = -(fe.K @ u)[interior]
    if pressures is not None:
        P = np.asarray(pressures, float).reshape(fe.n_cavities, -1)
        for k in range(fe.n_cavities):
            rhs += fe.cavity_loads[k][interior][:, None] * P[k][None, :]
    u[interior] = splu(fe.K[interior][:, interior].tocsc(), permc_spec="MMD_AT_PLUS_A").solve(rhs)
    return u[:, 0] if single else u
