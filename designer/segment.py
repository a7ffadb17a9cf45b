"""Design one segment: parameters → gmsh → scikit-fem → condensed catalogue entry.

``design_segment`` is safe in a worker process: gmsh is initialised and
finalised inside (one gmsh per process), BLAS threads are pinned to one, every
gmsh option is set explicitly with a fixed seed. It does not write anywhere;
``store.catalogue.add_entry(path, entry)`` does.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import json
import math
import platform
import socket
import time
import warnings
from importlib import metadata

import numpy as np

from vertebra import __version__
from vertebra.designer.families import FAMILIES, Family
from vertebra.store.entry import SegmentEntry, content_key
from vertebra.core.errors import GeometryError

#: bump when a change in designer/ changes the numbers of an entry (part of the key)
ALGORITHM_VERSION = "designer-4"   # 4: P1 accuracy by raising the order; Richardson size ratio by edge lengths
#: bump when a change in the nonlinear FE, the sampling or the fit changes a nonlinear entry's ψ
NONLINEAR_VERSION = "nonlinear-1"
#: the materials of ``design_segment``: ``linear`` (small strain, the condensation alone) and the
#: hyperelastic models of designer.nonlinear (an energy ψ(s, p) is sampled and fitted)
LINEAR = "linear"
#: layout of the key payload
KEY_SCHEMA = 1
#: the Richardson estimate solves the segment again on a mesh this much COARSER (cheap: ~1/3.4 of
#: the elements); the next ratios serve when gmsh cannot mesh that size or the mesh is not
#: coarser (small features fix the element size)
COARSENING = (1.5, 2.0, 1.25)
#: a coarser mesh must have elements this much larger (mean edge length) to be used
MIN_SIZE_RATIO = 1.08
#: exponent p of the compliance error of second-order tetrahedra, error ≈ A h^p, used to
#: extrapolate (measured on every family, ν up to 0.49: benchmarks/bench_accuracy.py, docs/designer.md)
CONVERGENCE_ORDER = 2.0
#: element order whose compliance on the SAME mesh measures the error of a first-order one
RAISED_ORDER = 2
#: Poisson ratio above which P1 tetrahedra lock (measured: ν = 0.499 P1 lateral 1.24 vs P2 2.89)
LOCKING_POISSON = 0.45


class LockingWarning(UserWarning):
    """First-order tetrahedra lock for nearly incompressible material: use order=2."""


def family_of(family) -> Family:
    if isinstance(family, Family):
        return family
    if family not in FAMILIES:
        raise GeometryError(f"unknown family {family!r} (known: {', '.join(sorted(FAMILIES))})")
    return FAMILIES[family]


def canonical_parameters(family, parameters: dict) -> dict:
    """Validated parameters with defaults filled (GeometryError before any meshing)."""
    return family_of(family).canonical(dict(parameters))


def _round(x: float, digits: int = 6) -> float:
    return float(f"{x:.{digits}g}")


def resolve_mesh_size(family, parameters: dict, mesh_size: float | None = None) -> float:
    """The mesh size used: given, or the family's default (rounded to 6 significant digits)."""
    fam = family_of(family)
    if mesh_size is None:
        return _round(fam.default_mesh_size(canonical_parameters(fam, parameters)))
    mesh_size = float(mesh_size)
    if not (mesh_size > 0 and math.isfinite(mesh_size)):
        raise GeometryError(f"parameter 'mesh_size': must be a positive number, got {mesh_size}")
    return mesh_size


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.lru_cache(maxsize=1)
def _result_versions() -> tuple:
    return (("gmsh", _version("gmsh")), ("scikit-fem", _version("scikit-fem")),
            ("algorithm", ALGORITHM_VERSION), ("key_schema", KEY_SCHEMA))


def result_versions() -> dict:
    """Versions that change the numbers of an entry (part of the content key); package
    metadata is read once per process (planning a 10k-task sweep asks 10k times)."""
    return dict(_result_versions())


def check_material(material: str) -> str:
    from vertebra.designer.nonlinear.materials import MATERIALS
    from vertebra.core.errors import OptionError

    if material != LINEAR and material not in MATERIALS:
        raise OptionError(f"unknown material {material!r} (known: {', '.join(sorted(set(MATERIALS) | {LINEAR}))})",
                          field="material")
    return material


def sampling_settings(sampling=None):
    """``designer.energy_sampling.SamplingSettings`` from None (defaults), a dict or settings."""
    from vertebra.designer.energy_sampling import SamplingSettings

    return sampling if isinstance(sampling, SamplingSettings) else SamplingSettings.from_dict(sampling)


def key_payload(family, parameters: dict, *, mesh_size=None, order: int = 2, material: str = LINEAR,
                sampling=None) -> dict:
    """What the content key hashes. A nonlinear material adds ``material`` and ``nonlinear``
    (the sampling and fit settings and the nonlinear algorithm version); a linear entry's
    payload (and key) is the same as before nonlinear entries existed."""
    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    if order not in (1, 2):
        raise GeometryError(f"parameter 'order': must be 1 or 2, got {order!r}")
    payload = {"family": fam.name, "parameters": p,
               "mesh": {"mesh_size": resolve_mesh_size(fam, p, mesh_size), "order": int(order)},
               "versions": result_versions()}
    if check_material(material) != LINEAR:
        payload["material"] = material
        settings = sampling_settings(sampling).resolved(fam.n_cavities(p), material)
        payload["nonlinear"] = {"sampling": settings.describe(), "version": NONLINEAR_VERSION}
    return payload


def entry_key(family, parameters: dict, *, mesh_size=None, order: int = 2, material: str = LINEAR,
              sampling=None) -> str:
    """Content key of the entry WITHOUT meshing (store.content_key of the key payload)."""
    return content_key(key_payload(family, parameters, mesh_size=mesh_size, order=order, material=material,
                                   sampling=sampling))


def compliance_change(C_ref: np.ndarray, C: np.ndarray) -> float:
    """Scale-free difference of two compliances: max |ΔC_ij| / sqrt(C_ii C_jj) (with C_ref's diagonal),
    so translations, rotations and volumes are compared in their own units."""
    d = np.sqrt(np.abs(np.diag(C_ref)))
    return float(np.max(np.abs(C - C_ref) / np.outer(d, d)))


def relative_error(C: np.ndarray, C_other: np.ndarray) -> float:
    """Largest relative difference of two compliances over all loads, relative to the first:
    max over w of |wᵀ (C_other − C) w| / wᵀ C w (the extreme generalised eigenvalue of
    (C_other − C, C)). Scale-free and independent of units: wrenches, moments and pressures
    are compared through the work they do. ``C`` must be positive definite."""
    from scipy.linalg import eigh

    return float(np.max(np.abs(eigh(C_other - C, C, eigvals_only=True))))


def richardson(C: np.ndarray, C_coarse: np.ndarray, ratio: float, exponent: float) -> np.ndarray:
    """Richardson extrapolation to h → 0 of a compliance ``C`` at mesh size h from ``C_coarse`` at
    ``ratio`` × h, for an error ≈ A h^exponent: C + (C − C_coarse) / (ratio^exponent − 1)."""
    return C + (C - C_coarse) / (ratio ** exponent - 1.0)


def _say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


def solve_segment(family, parameters: dict, *, mesh_size=None, order: int = 2, linear_solver: str = "auto",
                  amg_threshold: int | None = None, progress=None, max_elements: int | None = None,
                  meshed=None):
    """Mesh, assemble and condense. Returns ``(compliance, fe, mesh_data, condensation, timings)``.
    ``max_elements``: cap on the estimated tetrahedra (default ``geometry.DEFAULT_MAX_ELEMENTS``).
    ``meshed``: called with the mesh once it exists (before assembly)."""
    from vertebra.designer.fem import build_fe, condense
    from vertebra.designer.geometry import DEFAULT_MAX_ELEMENTS, mesh_segment

    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    h = resolve_mesh_size(fam, p, mesh_size)
    start = time.perf_counter()
    _say(progress, f"{fam.name}: meshing (h = {h:.4g} m, order {order})")
    mesh_data = mesh_segment(fam, p, h, order, max_elements=max_elements or DEFAULT_MAX_ELEMENTS,
                             progress=progress)
    if meshed is not None:
        meshed(mesh_data)
    _say(progress, f"{fam.name}: {mesh_data.tets.shape[0]} tetrahedra, {3 * mesh_data.nodes.shape[0]} DoFs; assembling")
    fe = build_fe(mesh_data, p["youngs_modulus"], p["poisson_ratio"], p["density"], fam.n_cavities(p), fam.length(p))
    _say(progress, f"{fam.name}: condensing ({linear_solver} linear solver)")
    cond = condense(fe, ("top",), linear_solver=linear_solver, amg_threshold=amg_threshold)
    compliance = cond.compliance()
    timings = {"mesh_s": mesh_data.mesh_s, "assemble_s": fe.timings["assemble_s"], "solve_s": cond.solve_s,
               "total_s": time.perf_counter() - start}
    return compliance, fe, mesh_data, cond, timings


@dataclasses.dataclass(frozen=True)
class Solved:
    """What an accuracy estimator uses of a solve (small and picklable: it may come from a
    worker process)."""

    compliance: np.ndarray
    dofs: int
    mean_edge_length: float
    tets: np.ndarray


def solved_summary(family, parameters: dict, **options) -> Solved:
    """:func:`solve_segment`, summarised for an accuracy estimator."""
    compliance, fe, mesh_data, _, _ = solve_segment(family, parameters, **options)
    return Solved(compliance, int(fe.n_dofs), float(mesh_data.mean_edge_length()), mesh_data.tets)


def _solved_in_worker(family, parameters: dict, options: dict):
    """:func:`solved_summary` in a worker process (one BLAS thread); a GeometryError comes back
    as its message (``("geometry", message)``), a result as ``("ok", Solved)``."""
    from vertebra.designer.threads import pin_blas_threads

    pin_blas_threads(1)
    try:
        return "ok", solved_summary(family, parameters, **options)
    except GeometryError as error:
        return "geometry", str(error)


class EstimateSolves:
    """The solves of an accuracy estimate (``solve(mesh_size=…, order=…)`` → :class:`Solved`),
    the first of them possibly started early in a worker process (:meth:`start_early`) so that
    it runs on the other core while the design solves its own mesh."""

    def __init__(self, family, parameters: dict, *, order: int, **options):
        self.family, self.parameters, self.order, self.options = family, parameters, order, options
        self._early = None          # ((mesh_size, order), future, pool)

    @staticmethod
    def first(order: int, mesh_size: float) -> tuple[float, int]:
        """(mesh size, order) of the first solve the estimator of ``order`` asks for."""
        return (mesh_size, RAISED_ORDER) if order == 1 else (mesh_size * COARSENING[0], order)

    def start_early(self, mesh_size: float) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        args = self.first(self.order, mesh_size)
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        options = {**self.options, "mesh_size": args[0], "order": args[1]}
        self._early = (args, pool.submit(_solved_in_worker, self.family.name, self.parameters, options), pool)

    def __call__(self, *, mesh_size: float, order: int | None = None) -> Solved:
        order = self.order if order is None else order
        if self._early is not None and self._early[0] == (mesh_size, order):
            _, future, pool = self._early
            self._early = None
            try:
                status, value = future.result()
            finally:
                pool.shutdown()
            if status == "geometry":
                raise GeometryError(value)
            return value
        return solved_summary(self.family, self.parameters, mesh_size=mesh_size, order=order, **self.options)

    def close(self) -> None:
        """Stop an early solve nobody asked for (its worker process is terminated: the design
        failed, or the estimate did not need it)."""
        if self._early is not None:
            from vertebra.designer.executors import terminate_pool

            terminate_pool(self._early[2])
            self._early = None


def estimate_by_richardson(solve, compliance: np.ndarray, mesh, progress=None) -> dict:
    """Richardson extrapolation from one coarser mesh (``COARSENING``) with ``CONVERGENCE_ORDER``.
    The size ratio is the one gmsh achieved, measured by mean edge lengths
    (:meth:`MeshData.mean_edge_length`): where a thin wall fixes the elements' thickness, coarsening
    makes them larger in the wall only, which an element count (∝ h⁻² there, not h⁻³) understates."""
    failures = []
    size = mesh.mean_edge_length()
    for factor in COARSENING:
        h_coarse = mesh.mesh_size * factor
        _say(progress, f"accuracy estimate: solving on a coarser mesh (h = {h_coarse:.4g} m)")
        try:
            solved = solve(mesh_size=h_coarse)
        except GeometryError as error:
            failures.append(f"h = {h_coarse:.4g} m: {error}")
            continue
        coarse, ratio = solved.compliance, solved.mean_edge_length / size
        if ratio < MIN_SIZE_RATIO:
            failures.append(f"h = {h_coarse:.4g} m gives elements only {ratio:.3g} times larger (mean edge length)")
            continue
        extrapolated = richardson(compliance, coarse, ratio, CONVERGENCE_ORDER)
        return {"method": "richardson", "extrapolated_compliance": extrapolated,
                "convergence_order": CONVERGENCE_ORDER, "coarse_mesh_size": h_coarse,
                "coarse_dofs": solved.dofs, "size_ratio": ratio,
                "basis": f"Richardson extrapolation from h = {h_coarse:.4g} m, size ratio {ratio:.3g}"}
    return {"method": "unavailable", "reason": "; ".join(failures)}


def estimate_by_order_raising(solve, compliance: np.ndarray, mesh, progress=None) -> dict:
    """The compliance of ``RAISED_ORDER`` elements on the same mesh (gmsh meshes deterministically:
    the same tetrahedra, with edge nodes on the curved geometry) as the better value. First-order
    tetrahedra are pre-asymptotic where they lock (ν → 0.5): a coarser, equally locked mesh does
    not see their error, a higher order does (its own error is typically 20–50× smaller)."""
    _say(progress, f"accuracy estimate: solving with order {RAISED_ORDER} elements on the same mesh")
    try:
        raised = solve(mesh_size=mesh.mesh_size, order=RAISED_ORDER)
    except GeometryError as error:
        return {"method": "unavailable", "reason": f"order {RAISED_ORDER} on the same mesh: {error}"}
    return {"method": "order-raising", "extrapolated_compliance": raised.compliance, "raised_order": RAISED_ORDER,
            "raised_dofs": raised.dofs,
            "same_mesh": bool(np.array_equal(raised.tets[:, :mesh.tets.shape[1]], mesh.tets)),
            "basis": f"order {RAISED_ORDER} on the same mesh ({raised.dofs} DoFs)"}


#: how the discretisation error of a compliance is estimated, per element order
ACCURACY_ESTIMATORS = {1: estimate_by_order_raising, 2: estimate_by_richardson}


def estimate_accuracy_of(family, parameters: dict, compliance: np.ndarray, mesh, *, linear_solver: str = "auto",
                         amg_threshold: int | None = None, progress=None, max_elements: int | None = None,
                         solves: EstimateSolves | None = None) -> dict:
    """The ``entry.accuracy`` of a compliance computed on ``mesh`` (``geometry.MeshData``; its
    order picks the estimator of ``ACCURACY_ESTIMATORS``): first order by raising the order on the
    same mesh, second order by Richardson extrapolation from a coarser mesh.

    Returns ``{"method": "order-raising" | "richardson", "relative_error": estimated error of the
    stored compliance (:func:`relative_error` against the better value), "relative_error_C" (6×6
    block), "extrapolated_compliance": the better value, "basis": one line saying how, "estimate_s",
    and the method's own fields}``, or ``{"method": "unavailable", "reason": …}`` when the solves it
    needs could not be made. ``solves``: the :class:`EstimateSolves` to use (one started early).
    """
    start = time.perf_counter()
    if solves is None:
        solves = EstimateSolves(family_of(family), parameters, order=mesh.order, linear_solver=linear_solver,
                                amg_threshold=amg_threshold, progress=None, max_elements=max_elements)
    try:
        accuracy = ACCURACY_ESTIMATORS[mesh.order](solves, compliance, mesh, progress)
    finally:
        solves.close()
    if accuracy["method"] == "unavailable":
        return accuracy
    better = accuracy["extrapolated_compliance"]
    error = relative_error(compliance, better)
    _say(progress, f"accuracy estimate: relative compliance error {error:.3g} ({accuracy['basis']})")
    return {**accuracy, "relative_error": error, "relative_error_C": relative_error(compliance[:6, :6], better[:6, :6]),
            "extrapolated_compliance": better.tolist(), "estimate_s": time.perf_counter() - start}


def estimated_error(accuracy: dict) -> float | None:
    """The estimated relative error an ``entry.accuracy`` records (None if it records none): the
    estimate (Richardson or raised order), or for older entries the change against a refined mesh."""
    value = accuracy.get("relative_error", accuracy.get("relative_change"))
    return float(value) if isinstance(value, (int, float)) else None


def design_segment(family, parameters: dict, *, mesh_size=None, order: int = 2, name: str | None = None,
                   linear_solver: str = "auto", estimate_accuracy: bool = True, progress=None,
                   amg_threshold: int | None = None, max_elements: int | None = None, material: str = LINEAR,
                   sampling=None, executor: str = "serial", workers: int | None = None,
                   scheduler: str | None = None, estimate_alongside: bool = False) -> SegmentEntry:
    """Condensed catalogue entry of one segment (docs/catalogue.md).

    ``progress``: optional callable receiving one-line status messages.
    ``linear_solver``: "auto" | "direct" | "amg" (auto: direct below
    ``designer.linsolve.AUTO_THRESHOLD`` interior unknowns, overridable with ``amg_threshold``).
    ``estimate_accuracy``: also estimate the compliance's discretisation error and store it in
    ``entry.accuracy`` (:func:`estimate_accuracy_of`: second order on the same mesh for a
    first-order entry, Richardson extrapolation from a coarser mesh for a second-order one).
    ``max_elements``: cap on the estimated tetrahedra, checked before meshing
    (``geometry.DEFAULT_MAX_ELEMENTS`` when None).
    ``estimate_alongside``: start the estimate's first solve in a worker process once the
    design's mesh exists, so that the two solves run on two cores (for a design running alone, as
    ``vertebra design`` does; a sweep's workers keep the cores busy already).
    ``material``: ``"linear"`` (the condensation alone), ``"svk"`` or ``"neo_hookean"``: the
    segment's energy ψ(s, p) is then sampled with its nonlinear FE on the same mesh and fitted
    (``entry.energy``, designer.nonlinear_condensation) with ``sampling`` settings
    (``designer.energy_sampling.SamplingSettings`` or a dict of them), the FE solves running
    on ``executor`` (``serial``, ``local`` with ``workers``, ``dask`` with ``scheduler``).
    """
    from vertebra.designer.threads import pin_blas_threads

    pin_blas_threads(1)
    start = time.perf_counter()
    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    h = resolve_mesh_size(fam, p, mesh_size)
    check_material(material)
    nonlinear = material != LINEAR
    if nonlinear:
        sampling = sampling_settings(sampling)
    key = entry_key(fam, p, mesh_size=h, order=order, material=material, sampling=sampling)
    warn = []
    if order == 1 and p["poisson_ratio"] >= LOCKING_POISSON:
        message = (f"poisson_ratio = {p['poisson_ratio']} with order 1: linear tetrahedra lock as ν → 0.5 "
                   "(the compliance is underestimated, by what the accuracy estimate records); "
                   "use order 2")
        warnings.warn(message, LockingWarning, stacklevel=2)
        _say(progress, f"warning: {message}")
        warn.append(message)
    solves = None
    if estimate_accuracy:
        solves = EstimateSolves(fam, p, order=order, linear_solver=linear_solver, amg_threshold=amg_threshold,
                                progress=None, max_elements=max_elements)
    try:     # (alongside: the estimate starts once the design's own mesh exists; a refused mesh starts nothing)
        compliance, fe, mesh_data, cond, timings = solve_segment(
            fam, p, mesh_size=h, order=order, linear_solver=linear_solver, amg_threshold=amg_threshold,
            progress=progress, max_elements=max_elements,
            meshed=(lambda _: solves.start_early(h)) if estimate_accuracy and estimate_alongside else None)
    except BaseException:
        if solves is not None:
            solves.close()
        raise
    accuracy, estimate_start = {"method": "none"}, time.perf_counter()
    if estimate_accuracy:
        accuracy = estimate_accuracy_of(fam, p, compliance, mesh_data, progress=progress, solves=solves)
    accuracy["warnings"] = warn
    timings["accuracy_s"] = time.perf_counter() - estimate_start if estimate_accuracy else 0.0
    timings["total_s"] = time.perf_counter() - start       # everything, accuracy estimate included
    n = fe.n_cavities
    date = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()
    provenance = {
        "versions": {**result_versions(), "numpy": np.__version__, "scipy": _version("scipy"),
                     "pyamg": _version("pyamg"), "python": platform.python_version(),
                     "vertebra": _version("vertebra")},
        "vertebra_version": __version__,
        "date": date, "host": socket.gethostname(),
        "linear_solver": {k: v for k, v in cond.info.items() if k != "iterations"}
        | ({"max_iterations": max(cond.info["iterations"])} if "iterations" in cond.info else {}),
    }
    mesh = {"nodes": int(mesh_data.nodes.shape[0]), "elements": int(mesh_data.tets.shape[0]),
            "dofs": int(fe.n_dofs), "interior_dofs": int(cond.info["interior_dofs"]),
            "order": int(order), "mesh_size": float(h), "element": "tetra10" if order == 2 else "tetra4",
            "mesher": f"gmsh {mesh_data.gmsh_version} OCC"}
    entry = SegmentEntry(
        key=key, name=name or f"{fam.name}-{key[:8]}", family=fam.name, parameters=p,
        compliance=compliance, cavity_volumes=fe.cavity_volumes.reshape(n), mass=fe.mass,
        center_of_mass=fe.center_of_mass, rest_translation=np.array([0.0, 0.0, fam.length(p)]),
        rest_quaternion=np.array([1.0, 0.0, 0.0, 0.0]), mesh=mesh, accuracy=accuracy,
        timings={k: float(v) for k, v in timings.items()}, provenance=provenance)
    if not nonlinear:
        return entry
    from vertebra.designer.nonlinear_condensation import FamilySolid, condense_energy, material_constants

    _say(progress, f"{fam.name}: nonlinear condensation with the {material} material")
    spec = FamilySolid(family=fam.name, parameters=json.dumps(p, sort_keys=True), mesh_size=h, order=order,
                       material=material, linear_solver=linear_solver)
    condensed = condense_energy(entry, spec, radius=fam.outer_radius(p), youngs_modulus=p["youngs_modulus"],
                                symmetry=fam.symmetry(p), material=material_constants(material, p),
                                settings=sampling, executor=executor, workers=workers, scheduler=scheduler,
                                progress=progress)
    timings.update({k: v for k, v in condensed.timings.items() if k != "total_s"})
    timings["total_s"] = time.perf_counter() - start
    provenance["nonlinear"] = {"executor": executor, "workers": workers, "version": NONLINEAR_VERSION}
    return dataclasses.replace(entry, energy=condensed.energy, timings={k: float(v) for k, v in timings.items()},
                               provenance=provenance)


def entry_document(entry: SegmentEntry) -> dict:
    """The JSON document (docs/json.md) of ``vertebra design --json`` (with ``material``, and for a
    nonlinear entry an ``energy`` summary: degree, terms, fit error, range, sampling, timings)."""
    document = {"key": entry.key, "name": entry.name, "compliance": entry.compliance.tolist(),
                "cavity_volumes": entry.cavity_volumes.tolist(), "mass": entry.mass,
                "dofs": int(entry.mesh.get("dofs", 0)), "accuracy": dict(entry.accuracy),
                "material": LINEAR if entry.energy is None else entry.energy.material.get("model"),
                "timing": {k: float(entry.timings.get(k, 0.0)) for k in ("mesh_s", "assemble_s", "solve_s", "total_s")}}
    if entry.energy is not None:
        energy = entry.energy
        document["energy"] = {"degree": energy.degree, "terms": int(energy.coefficients.size),
                              "fit_error": energy.fit_error, "range": energy.range.to_dict(),
                              "fold_pressure": energy.fold_pressure, "material": energy.material,
                              "sampling": {k: energy.sampling[k] for k in ("samples", "solves", "paths", "held_out_paths")
                                           if k in energy.sampling}}
        document["timing"].update({k: float(entry.timings[k]) for k in ("sampling_s", "fit_s") if k in entry.timings})
    return document


def export_mesh(family, parameters: dict, path: str, *, mesh_size=None, order: int = 2,
                max_elements: int | None = None) -> dict:
    """Write the segment mesh to a file meshio can write (e.g. .vtu): the tetrahedra (cell
    data ``group`` = 0) and the boundary triangles of every physical group (``group`` = 1, 2, …).
    Returns the legend ``{group name: id}``. gmsh meshes deterministically (fixed seed and
    options), so this is the mesh ``design_segment`` used for the same settings."""
    import meshio

    from vertebra.designer.geometry import mesh_segment

    fam = family_of(family)
    p = canonical_parameters(fam, parameters)
    from vertebra.designer.geometry import DEFAULT_MAX_ELEMENTS

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
