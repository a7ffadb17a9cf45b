"""A trunk as one tetrahedral mesh: segment meshes stacked along z, rigid vertebrae between them.

Vertebra ``j`` (0 … m) sits at height ``z[j]``; it ties the top face of segment ``j − 1`` and the
bottom face of segment ``j`` (vertebra 0 is the clamped base, vertebra m the tip). Segment meshes
come from :func:`vertebra.designer.geometry.mesh_segment` unchanged (the same meshes the project's
FE uses); only their nodes are shifted to the segment's height and their tetrahedra oriented
(positive corner volume, the orientation CalculiX requires).

Each cavity (segment ``s``, cavity ``k``) is sealed by two caps on the rigid vertebrae below and
above; a cap is the flat region enclosed by the rim of the cavity wall on the end plane. The rim is
kept as oriented P2 edges (corner, corner, mid) so that the cap's vector area and the cavity volume
are exact on the discrete (curved) geometry.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# corners of the four faces of a tetrahedron, in CalculiX order (face k = label "Pk")
TET_FACES = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
# swapping corners 1 <-> 2 of a tet10 (scikit-fem / CalculiX edge order 01, 12, 02, 03, 13, 23)
_FLIP = np.array([0, 2, 1, 3, 6, 5, 4, 7, 9, 8])
# P2 triangle edges (gmsh order: corners, then edge nodes (0,1), (1,2), (2,0))
_TRI_EDGES = np.array([[0, 1, 3], [1, 2, 4], [2, 0, 5]])


@dataclass
class Cavity:
    """One sealed cavity of the trunk mesh (global node numbering)."""

    segment: int
    index: int
    triangles: np.ndarray           # (n, 6) wall triangles, oriented with normal out of the solid
    faces: np.ndarray               # (n, 2) tet number and CalculiX face number (1..4) of each triangle
    rims: dict                      # "bottom"/"top" -> (n_e, 3) rim edges (a, b, mid), oriented
    vertebrae: dict                 # "bottom"/"top" -> vertebra number
    rest_volume: float = 0.0

    @property
    def wall_nodes(self) -> np.ndarray:
        return np.unique(self.triangles)


@dataclass
class TrunkMesh:
    nodes: np.ndarray               # (n, 3) rest coordinates, m
    tets: np.ndarray                # (ne, 10) positively oriented tet10 connectivity
    segment_of_tet: np.ndarray      # (ne,)
    z: np.ndarray                   # (m + 1,) vertebra heights
    face_nodes: list                # per vertebra: node numbers tied to it
    cavities: list = field(default_factory=list)
    segment_node_ranges: list = field(default_factory=list)   # per segment: (start, stop) in ``nodes``

    @property
    def n_segments(self) -> int:
        return len(self.z) - 1

    @property
    def dofs(self) -> int:
        """Displacement unknowns of the solid plus 6 per free vertebra."""
        return 3 * self.nodes.shape[0] + 6 * self.n_segments

    def cavity(self, segment: int, index: int) -> Cavity:
        for c in self.cavities:
            if c.segment == segment and c.index == index:
                return c
        raise KeyError(f"no cavity {index} in segment {segment}")


def _orient(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    x = nodes[tets[:, :4]]
    volume6 = np.einsum("ij,ij->i", np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), x[:, 3] - x[:, 0])
    if np.any(np.abs(volume6) <= 0):
        raise ValueError("degenerate tetrahedron in the mesh")
    out = tets.copy()
    out[volume6 < 0] = tets[volume6 < 0][:, _FLIP]
    return out


def _face_lookup(tets: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 2): the tet holding each boundary triangle and that tet's face number 1..4."""
    n_nodes = np.int64(tets.max() + 1)

    def key(c):
        c = np.sort(c, axis=1).astype(np.int64)
        return (c[:, 0] * n_nodes + c[:, 1]) * n_nodes + c[:, 2]

    face_keys = np.concatenate([key(tets[:, f]) for f in TET_FACES])           # face-major
    order = np.argsort(face_keys)
    wanted = key(triangles[:, :3])
    pos = np.clip(np.searchsorted(face_keys, wanted, sorter=order), 0, face_keys.size - 1)
    hit = order[pos]
    if not np.all(face_keys[hit] == wanted):
        raise ValueError("cavity triangles not found among the tetrahedra's faces")
    n_tets = tets.shape[0]
    return np.column_stack([hit % n_tets, hit // n_tets + 1])


def _oriented_walls(nodes, tets, triangles, faces):
    """Wall triangles re-ordered so that (x1 − x0) × (x2 − x0) points out of the solid."""
    tet = tets[faces[:, 0]]
    opposite = tet[:, :4].sum(axis=1) - triangles[:, :3].sum(axis=1)
    x = nodes[triangles[:, :3]]
    normal = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    outward = np.einsum("ij,ij->i", normal, x.mean(axis=1) - nodes[opposite]) > 0
    out = triangles.copy()
    flip = ~outward
    out[flip] = triangles[flip][:, [0, 2, 1, 5, 4, 3]]      # reverse: corners 0,2,1; edges (0,2),(2,1),(1,0)
    return out


def _rim(nodes, triangles, z_plane, tol):
    edges = triangles[:, _TRI_EDGES].reshape(-1, 3)
    on = np.all(np.abs(nodes[edges[:, :2], 2] - z_plane) < tol, axis=1)
    return edges[on]


def stack(meshes: list, lengths: list, n_cavities: list) -> TrunkMesh:
    """Stack segment meshes (``designer.geometry.MeshData``, order 2) bottom to top."""
    z = np.concatenate([[0.0], np.cumsum(lengths)])
    all_nodes, all_tets, seg_of, ranges, cavities = [], [], [], [], []
    face_nodes = [[] for _ in z]
    offset = 0
    for s, mesh in enumerate(meshes):
        if mesh.order != 2:
            raise ValueError("CalculiX C3D10 needs second-order meshes")
        nodes = mesh.nodes + np.array([0.0, 0.0, z[s]])
        tets = mesh.tets + offset
        all_nodes.append(nodes)
        all_tets.append(tets)
        seg_of.append(np.full(tets.shape[0], s))
        ranges.append((offset, offset + nodes.shape[0]))
        face_nodes[s].append(np.unique(mesh.facets["bottom"]) + offset)
        face_nodes[s + 1].append(np.unique(mesh.facets["top"]) + offset)
        offset += nodes.shape[0]
    nodes = np.concatenate(all_nodes)
    tets = _orient(nodes, np.concatenate(all_tets))
    trunk = TrunkMesh(nodes=nodes, tets=tets, segment_of_tet=np.concatenate(seg_of), z=z,
                      face_nodes=[np.unique(np.concatenate(f)) for f in face_nodes], segment_node_ranges=ranges)
    for s, mesh in enumerate(meshes):
        start = ranges[s][0]
        tol = 1e-9 * lengths[s]
        for k in range(n_cavities[s]):
            triangles = mesh.facets[f"cavity_{k}"] + start
            faces = _face_lookup(tets, triangles)
            walls = _oriented_walls(nodes, tets, triangles, faces)
            rims = {"bottom": _rim(nodes, walls, z[s], tol), "top": _rim(nodes, walls, z[s + 1], tol)}
            cavity = Cavity(segment=s, index=k, triangles=walls, faces=faces, rims=rims,
                            vertebrae={"bottom": s, "top": s + 1})
            from ccx.volume import cavity_volume
            cavity.rest_volume = cavity_volume(nodes, cavity)
            cavities.append(cavity)
    trunk.cavities = cavities
    return trunk
