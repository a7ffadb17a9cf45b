"""Mesh a segment with gmsh (OpenCASCADE kernel) into plain arrays.

One gmsh per process (gmsh is not thread-safe): :func:`mesh_segment` initialises gmsh,
sets every option it relies on explicitly (one thread, fixed seed, algorithms,
sizes, element order), builds the family's solid, names the physical groups
(``bottom``, ``top``, ``cavity_k``, ``wall`` and always ``volume``), meshes,
reads nodes/elements straight from the gmsh API and finalises gmsh — so it is
safe to call in a worker process and leaves no global state behind.

The boundary triangles of every physical group are returned with the mesh:
scikit-fem loses the tags of second-order meshes, so :mod:`designer.fem`
builds its facet sets from these triangles instead of re-reading a file.
"""

from __future__ import annotations

import math
import signal
import time
from dataclasses import dataclass, field

import numpy as np

from vertebra.core.errors import GeometryError
from vertebra.designer.families import canonical_parameters, family_of, resolve_mesh_size

# gmsh tetra10 node order -> scikit-fem/VTK order (edges (0,1),(1,2),(0,2),(0,3),(1,3),(2,3))
_GMSH_TET10_TO_SKFEM = [0, 1, 2, 3, 4, 5, 6, 7, 9, 8]
_TET_TYPE = {1: 4, 2: 11}      # gmsh element type of a tetrahedron of order 1 / 2
_TRI_TYPE = {1: 2, 2: 9}

GMSH_OPTIONS = {
    "General.Terminal": 0,
    "General.Verbosity": 2,
    "General.NumThreads": 1,
    "Geometry.Tolerance": 1e-10,
    "Geometry.OCCFixDegenerated": 0,
    "Geometry.OCCFixSmallEdges": 0,
    "Geometry.OCCFixSmallFaces": 0,
    "Mesh.RandomSeed": 1,
    "Mesh.Algorithm": 6,            # Frontal-Delaunay (2D)
    "Mesh.Algorithm3D": 1,          # Delaunay (3D)
    "Mesh.MeshSizeFromPoints": 0,
    "Mesh.MeshSizeFromCurvature": 0,
    "Mesh.MeshSizeExtendFromBoundary": 1,
    "Mesh.MeshSizeFactor": 1.0,
    "Mesh.Optimize": 1,
    "Mesh.OptimizeNetgen": 0,
    "Mesh.HighOrderOptimize": 0,
    "Mesh.SecondOrderLinear": 0,    # second-order nodes on the curved geometry
    "Mesh.MaxNumThreads1D": 1,
    "Mesh.MaxNumThreads2D": 1,
    "Mesh.MaxNumThreads3D": 1,
}


#: default cap on the estimated number of tetrahedra (second-order assembly holds ~22 kB per
#: tetrahedron: 300,000 of them need ~6.5 GB; the default designs have ~1,000-20,000)
DEFAULT_MAX_ELEMENTS = 300_000
#: tetrahedra per unit volume / h³ and per unit boundary area / h² of gmsh's Delaunay meshes,
#: fitted on every family from 5,000 to 720,000 tetrahedra (within a factor 1.5 there)
ELEMENTS_PER_VOLUME = 4.5
ELEMENTS_PER_AREA = 1.5


def estimate_elements(volume: float, area: float, mesh_size: float) -> int:
    """Tetrahedra gmsh will make for a solid of ``volume`` and boundary ``area`` at ``mesh_size``
    (consistent units), before meshing."""
    return int(ELEMENTS_PER_VOLUME * volume / mesh_size ** 3 + ELEMENTS_PER_AREA * area / mesh_size ** 2)


@dataclass
class MeshData:
    """A tetrahedral mesh as arrays. Vertices come first in ``nodes``.

    ``tets``: (n_tets, 4) or (n_tets, 10) node indices in scikit-fem order;
    ``facets``: group name -> (n, 3) or (n, 6) node indices of its boundary triangles
    (gmsh order: corners, then edge nodes (0,1), (1,2), (2,0)).
    """

    nodes: np.ndarray
    tets: np.ndarray
    n_vertices: int
    facets: dict
    order: int
    mesh_size: float
    gmsh_version: str
    mesh_s: float = 0.0
    groups: list = field(default_factory=list)

    def mean_edge_length(self) -> float:
        """The element size gmsh achieved: the mean over tetrahedra of their mean edge length
        (corner to corner). Unlike (volume / elements)^(1/3) it measures flat elements in a thin
        wall by their in-wall size, which is what refining the mesh there reduces."""
        corners = self.nodes[self.tets[:, :4]]                          # (n, 4, 3)
        i, j = np.triu_indices(4, k=1)
        return float(np.linalg.norm(corners[:, i] - corners[:, j], axis=2).mean())

    def __post_init__(self):
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise ValueError(f"nodes: shape {self.nodes.shape}, expected (n, 3)")
        expected = 4 if self.order == 1 else 10
        if self.tets.ndim != 2 or self.tets.shape[1] != expected:
            raise ValueError(f"tets: shape {self.tets.shape}, expected (n, {expected}) for order {self.order}")


def gmsh_version() -> str:
    import gmsh
    return str(gmsh.__version__)


def _classify_surfaces(gmsh, family, p, volumes) -> dict[str, list[int]]:
    length = family.length(p)
    tol = 1e-7 * max(length, 1e-12)
    boundary = gmsh.model.getBoundary(volumes, combined=True, oriented=False, recursive=False)
    groups: dict[str, list[int]] = {}
    for dim, tag in boundary:
        # end faces: planar with normal ±z, at z = 0 or z = length (OCC pads bounding boxes by an
        # absolute ~1e-7 m, so they are no good for tiny segments; the normal is scale-free)
        lo, hi = gmsh.model.getParametrizationBounds(dim, tag)
        uv = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])]
        point = gmsh.model.getValue(dim, tag, uv)
        normal = gmsh.model.getNormal(tag, uv)
        flat = gmsh.model.getType(dim, tag) == "Plane" and abs(abs(normal[2]) - 1.0) < 1e-9
        if flat and abs(point[2]) < tol:
            name = "bottom"
        elif flat and abs(point[2] - length) < tol:
            name = "top"
        else:
            name = family.classify(tuple(point), p)
        groups.setdefault(name, []).append(abs(tag))
    return groups


def _initialize_gmsh(gmsh) -> None:
    """``gmsh.initialize`` resets SIGPIPE to its default action (terminate) behind Python's
    back; Python ignores it and reports ``BrokenPipeError`` instead. Restore that, or any later
    write to a closed pipe — e.g. to a sweep worker that died — kills this whole process."""
    previous = signal.getsignal(signal.SIGPIPE)
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        signal.signal(signal.SIGPIPE, previous if previous is not None else signal.SIG_IGN)
    except ValueError:      # not the main thread: signal dispositions can only be set there
        pass


def mesh_segment(family, p: dict, mesh_size: float, order: int = 2, *,
                 max_elements: int = DEFAULT_MAX_ELEMENTS, progress=None) -> MeshData:
    """Build and mesh ``family`` with canonical parameters ``p``. Runs gmsh in-process.

    Before meshing, the number of tetrahedra is estimated from the solid's volume and boundary
    area (:func:`estimate_elements`); above ``max_elements`` a GeometryError gives the estimate
    and how to raise the cap, instead of a mesh that would not end. ``progress`` receives the
    estimate."""
    import gmsh

    if order not in _TET_TYPE:
        raise GeometryError(f"parameter 'order': must be 1 or 2, got {order}")
    if not (mesh_size > 0 and math.isfinite(mesh_size)):
        raise GeometryError(f"parameter 'mesh_size': must be a positive number, got {mesh_size}")
    if not (isinstance(max_elements, int) and max_elements > 0):
        raise GeometryError(f"parameter 'max_elements': must be a positive integer, got {max_elements!r}")
    start = time.perf_counter()
    # mesh in units of the segment length: OCC and gmsh/tetgen work with absolute tolerances
    # (~1e-7), so a 20 µm segment failed where the same shape at 20 mm meshed. Scaled, the mesh
    # is the same for every unit scale; coordinates are scaled back after meshing.
    scale = float(family.length(p))
    p = {spec.name: (p[spec.name] / scale if spec.unit == "m" else p[spec.name]) for spec in family.parameters}
    _initialize_gmsh(gmsh)
    try:
        for name, value in GMSH_OPTIONS.items():
            gmsh.option.setNumber(name, value)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(mesh_size) / scale)
        gmsh.option.setNumber("Mesh.ElementOrder", int(order))
        gmsh.model.add(f"{family.name}")
        try:
            volumes = family.build(gmsh.model.occ, p)
            gmsh.model.occ.synchronize()
        except Exception as error:
            raise GeometryError(f"family {family.name!r}: gmsh/OpenCASCADE could not build the geometry "
                                f"({error})") from None
        volumes = [dt for dt in volumes if dt[0] == 3]
        if len(volumes) != 1:
            raise GeometryError(f"family {family.name!r}: the geometry is not one connected solid "
                                f"({len(volumes)} volumes); check the parameters")
        h = float(mesh_size) / scale
        volume = sum(gmsh.model.occ.getMass(3, tag) for _, tag in volumes)
        area = sum(gmsh.model.occ.getMass(2, abs(tag)) for _, tag in
                   gmsh.model.getBoundary(volumes, combined=True, oriented=False, recursive=False))
        estimate = estimate_elements(volume, area, h)
        if progress is not None:
            progress(f"{family.name}: about {estimate:,} tetrahedra expected at mesh_size = {mesh_size:.4g} m")
        if estimate > max_elements:
            raise GeometryError(
                f"family {family.name!r}: mesh_size = {mesh_size:.4g} m would give about {estimate:,} tetrahedra "
                f"(estimated from the solid's volume and surface), more than max_elements = {max_elements:,}; "
                "use a larger mesh size, or raise the cap (vertebra design --max-elements N) if the machine "
                "can take it")
        groups = _classify_surfaces(gmsh, family, p, volumes)
        n_cav = family.n_cavities(p)
        for required in ["bottom", "top"] + [f"cavity_{k}" for k in range(n_cav)]:
            if required not in groups:
                raise GeometryError(f"family {family.name!r}: no surface found for group {required!r}; "
                                    "check the parameters")
        for name, tags in sorted(groups.items()):
            gmsh.model.addPhysicalGroup(2, tags, name=name)
        gmsh.model.addPhysicalGroup(3, [t for _, t in volumes], name="volume")
        try:
            gmsh.model.mesh.generate(3)
            if order == 2:
                gmsh.model.mesh.setOrder(2)
        except Exception as error:      # gmsh raises plain Exception with its last error message
            raise GeometryError(f"family {family.name!r}: gmsh could not mesh the geometry with mesh_size = "
                                f"{mesh_size:.4g} m ({error}); a mesh size that resolves the thinnest wall "
                                "usually helps") from None
        data = _extract(gmsh, order, groups)
        data.nodes *= scale
        data.mesh_size = float(mesh_size)
        data.gmsh_version = gmsh_version()
        data.mesh_s = time.perf_counter() - start
        return data
    finally:
        gmsh.finalize()


def _extract(gmsh, order: int, groups: dict) -> MeshData:
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    coords = np.asarray(coords, dtype=float).reshape(-1, 3)
    tag_to_row = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    tag_to_row[node_tags.astype(np.int64)] = np.arange(node_tags.size)
    _, tet_nodes = gmsh.model.mesh.getElementsByType(_TET_TYPE[order])
    npe = 4 if order == 1 else 10
    tets = tag_to_row[np.asarray(tet_nodes, dtype=np.int64).reshape(-1, npe)]
    if order == 2:
        tets = tets[:, _GMSH_TET10_TO_SKFEM]
    if tets.size == 0:
        raise GeometryError("gmsh produced no tetrahedra (mesh_size too large or geometry degenerate?)")
    # renumber: vertices first, then edge nodes; drop nodes not used by any tetrahedron
    vertices = np.unique(tets[:, :4])
    others = np.setdiff1d(np.unique(tets), vertices)
    new = np.full(coords.shape[0], -1, dtype=np.int64)
    new[vertices] = np.arange(vertices.size)
    new[others] = vertices.size + np.arange(others.size)
    order_rows = np.concatenate([vertices, others])
    nodes = coords[order_rows]
    tets = new[tets]
    facets = {}
    for name, tags in groups.items():
        tris = []
        for tag in tags:
            types, _, tri_nodes = gmsh.model.mesh.getElements(2, tag)
            for etype, nn in zip(types, tri_nodes):
                if etype == _TRI_TYPE[order]:
                    k = 3 if order == 1 else 6
                    tris.append(np.asarray(nn, dtype=np.int64).reshape(-1, k))
        k = 3 if order == 1 else 6
        triangles = new[tag_to_row[np.concatenate(tris)]] if tris else np.zeros((0, k), dtype=np.int64)
        if np.any(triangles < 0) or np.any(triangles[:, :3] >= vertices.size):
            raise GeometryError(f"group {name!r}: boundary triangles not attached to the volume mesh")
        facets[name] = triangles
    return MeshData(nodes=nodes, tets=tets.astype(np.int64), n_vertices=int(vertices.size),
                    facets=facets, order=order, mesh_size=0.0, gmsh_version="", groups=sorted(groups))


def export_mesh(family, parameters: dict, path: str, *, mesh_size=None, order: int = 2,
                max_elements: int | None = None) -> dict:
    """Write the segment mesh to a file meshio can write (e.g. .vtu): the tetrahedra (cell
    data ``group`` = 0) and the boundary triangles of every physical group (``group`` = 1, 2, …).
    Returns the legend ``{group name: id}``. gmsh meshes deterministically (fixed seed and
    options), so this is the mesh ``design_segment`` used for the same settings."""
    import meshio

    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    data = mesh_segment(fam, p, resolve_mesh_size(fam, p, mesh_size), order,
                        max_elements=max_elements or DEFAULT_MAX_ELEMENTS)
    legend = {"volume": 0} | {name: i + 1 for i, name in enumerate(sorted(data.facets))}
    # scikit-fem, VTK and meshio share the tetra10 node order; triangle6 too (corners, then edges)
    cells = [("tetra10" if order == 2 else "tetra", data.tets)]
    groups = [np.zeros(len(data.tets), dtype=np.int32)]
    for name in sorted(data.facets):
        cells.append(("triangle6" if order == 2 else "triangle", data.facets[name]))
        groups.append(np.full(len(data.facets[name]), legend[name], dtype=np.int32))
    meshio.write(path, meshio.Mesh(data.nodes, cells, cell_data={"group": groups}))
    return legend
