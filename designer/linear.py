"""The linear condensation of a segment: mesh (gmsh) → assemble (scikit-fem) → condense onto its
two frames and its cavities (paper eqs. 1–3), and the catalogue entry of it with the estimate of
its discretisation error (:mod:`designer.accuracy`).

:class:`LinearCondenser` is the condenser of ``material = "linear"``; the nonlinear one
(``designer.nonlinear_condensation.NonlinearCondenser``) starts from its entry.
"""

from __future__ import annotations

import dataclasses
import datetime
import multiprocessing
import platform
import socket
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from vertebra import __version__
from vertebra.core.errors import GeometryError
from vertebra.designer import accuracy
from vertebra.designer.accuracy import COARSENING, RAISED_ORDER, Solved
from vertebra.designer.executors import terminate_pool
from vertebra.designer.families import canonical_parameters, family_of, resolve_mesh_size
from vertebra.designer.fem import build_fe, condense
from vertebra.designer.geometry import DEFAULT_MAX_ELEMENTS, mesh_segment
from vertebra.designer.keys import SegmentDesign, package_version, result_versions
from vertebra.designer.threads import pin_blas_threads
from vertebra.store.entry import SegmentEntry

#: Poisson ratio above which P1 tetrahedra lock (measured: ν = 0.499 P1 lateral 1.24 vs P2 2.89)
LOCKING_POISSON = 0.45


class LockingWarning(UserWarning):
    """First-order tetrahedra lock for nearly incompressible material: use order=2."""


def locking_message(parameters: dict, order: int) -> str | None:
    """Why first-order elements would underestimate this segment's compliance (None if they do not lock)."""
    if order == 1 and parameters["poisson_ratio"] >= LOCKING_POISSON:
        return (f"poisson_ratio = {parameters['poisson_ratio']} with order 1: linear tetrahedra lock as ν → 0.5 "
                "(the compliance is underestimated, by what the accuracy estimate records); use order 2")
    return None


def _say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


def solve_segment(family, parameters: dict, *, mesh_size=None, order: int = 2, linear_solver: str = "auto",
                  amg_threshold: int | None = None, progress=None, max_elements: int | None = None,
                  meshed=None):
    """Mesh, assemble and condense. Returns ``(compliance, fe, mesh_data, condensation, timings)``.
    ``max_elements``: cap on the estimated tetrahedra (default ``geometry.DEFAULT_MAX_ELEMENTS``).
    ``meshed``: called with the mesh once it exists (before assembly)."""
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


def solved_summary(family, parameters: dict, **options) -> Solved:
    """:func:`solve_segment`, summarised for an accuracy estimator."""
    compliance, fe, mesh_data, _, _ = solve_segment(family, parameters, **options)
    return Solved(compliance, int(fe.n_dofs), float(mesh_data.mean_edge_length()), mesh_data.tets)


def _solved_in_worker(family, parameters: dict, options: dict):
    """:func:`solved_summary` in a worker process (one BLAS thread); a GeometryError comes back
    as its message (``("geometry", message)``), a result as ``("ok", Solved)``."""
    pin_blas_threads(1)
    try:
        return "ok", solved_summary(family, parameters, **options)
    except GeometryError as error:
        return "geometry", str(error)


class EstimateSolves:
    """The solves of an accuracy estimate (``solve(mesh_size=…, order=…)`` → :class:`Solved`, an
    :class:`accuracy.Solve`), the first of them possibly started early in a worker process
    (:meth:`start_early`) so that it runs on the other core while the design solves its own mesh."""

    def __init__(self, family, parameters: dict, *, order: int, **options):
        self.family, self.parameters, self.order, self.options = family, parameters, order, options
        self._early = None          # ((mesh_size, order), future, pool)

    @staticmethod
    def first(order: int, mesh_size: float) -> tuple[float, int]:
        """(mesh size, order) of the first solve the estimator of ``order`` asks for."""
        return (mesh_size, RAISED_ORDER) if order == 1 else (mesh_size * COARSENING[0], order)

    def start_early(self, mesh_size: float) -> None:
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
            terminate_pool(self._early[2])
            self._early = None


def estimate_accuracy_of(family, parameters: dict, compliance: np.ndarray, mesh, *, linear_solver: str = "auto",
                         amg_threshold: int | None = None, progress=None, max_elements: int | None = None,
                         solves: EstimateSolves | None = None) -> dict:
    """The ``entry.accuracy`` of a compliance computed on ``mesh`` (``geometry.MeshData``):
    :func:`accuracy.estimate` with the segment solved again by ``solves`` (an
    :class:`EstimateSolves`, possibly started early; by default a new one with these options)."""
    if solves is None:
        solves = EstimateSolves(family_of(family), parameters, order=mesh.order, linear_solver=linear_solver,
                                amg_threshold=amg_threshold, progress=None, max_elements=max_elements)
    try:
        return accuracy.estimate(solves, compliance, mesh, progress)
    finally:
        solves.close()


@dataclasses.dataclass(frozen=True)
class LinearCondenser:
    """The condenser of ``material = "linear"``: the segment's compliance (:func:`solve_segment`)
    and, with ``estimate_accuracy``, the estimate of its discretisation error, as a catalogue entry.

    ``linear_solver``: "auto" | "direct" | "amg" (auto: direct below
    ``designer.linsolve.AUTO_THRESHOLD`` interior unknowns, overridable with ``amg_threshold``).
    ``max_elements``: cap on the estimated tetrahedra, checked before meshing
    (``geometry.DEFAULT_MAX_ELEMENTS`` when None).
    ``estimate_alongside``: start the estimate's first solve in a worker process once the
    design's mesh exists, so that the two solves run on two cores."""

    linear_solver: str = "auto"
    amg_threshold: int | None = None
    max_elements: int | None = None
    estimate_accuracy: bool = True
    estimate_alongside: bool = False

    def condense(self, design: SegmentDesign, progress=None) -> SegmentEntry:
        fam, p, h, order = design.family, design.parameters, design.mesh_size, design.order
        solves = None
        if self.estimate_accuracy:
            solves = EstimateSolves(fam, p, order=order, linear_solver=self.linear_solver,
                                    amg_threshold=self.amg_threshold, progress=None, max_elements=self.max_elements)
        try:     # (alongside: the estimate starts once the design's own mesh exists; a refused mesh starts nothing)
            compliance, fe, mesh_data, cond, timings = solve_segment(
                fam, p, mesh_size=h, order=order, linear_solver=self.linear_solver,
                amg_threshold=self.amg_threshold, progress=progress, max_elements=self.max_elements,
                meshed=(lambda _: solves.start_early(h)) if self.estimate_accuracy and self.estimate_alongside
                else None)
        except BaseException:
            if solves is not None:
                solves.close()
            raise
        estimated, estimate_start = {"method": "none"}, time.perf_counter()
        if self.estimate_accuracy:
            estimated = estimate_accuracy_of(fam, p, compliance, mesh_data, progress=progress, solves=solves)
        estimated["warnings"] = list(design.warnings)
        timings["accuracy_s"] = time.perf_counter() - estimate_start if self.estimate_accuracy else 0.0
        timings["total_s"] = time.perf_counter() - design.started       # everything, accuracy estimate included
        n = fe.n_cavities
        date = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()
        provenance = {
            "versions": {**result_versions(), "numpy": np.__version__, "scipy": package_version("scipy"),
                         "pyamg": package_version("pyamg"), "python": platform.python_version(),
                         "vertebra": package_version("vertebra")},
            "vertebra_version": __version__,
            "date": date, "host": socket.gethostname(),
            "linear_solver": {k: v for k, v in cond.info.items() if k != "iterations"}
            | ({"max_iterations": max(cond.info["iterations"])} if "iterations" in cond.info else {}),
        }
        mesh = {"nodes": int(mesh_data.nodes.shape[0]), "elements": int(mesh_data.tets.shape[0]),
                "dofs": int(fe.n_dofs), "interior_dofs": int(cond.info["interior_dofs"]),
                "order": int(order), "mesh_size": float(h), "element": "tetra10" if order == 2 else "tetra4",
                "mesher": f"gmsh {mesh_data.gmsh_version} OCC"}
        return SegmentEntry(
            key=design.key, name=design.name, family=fam.name, parameters=p,
            compliance=compliance, cavity_volumes=fe.cavity_volumes.reshape(n), mass=fe.mass,
            center_of_mass=fe.center_of_mass, rest_translation=np.array([0.0, 0.0, fam.length(p)]),
            rest_quaternion=np.array([1.0, 0.0, 0.0, 0.0]), mesh=mesh, accuracy=estimated,
            timings={k: float(v) for k, v in timings.items()}, provenance=provenance)
