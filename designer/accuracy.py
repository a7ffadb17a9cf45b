"""The discretisation error of a segment's compliance, estimated from a second solve of the same
segment (:data:`ACCURACY_ESTIMATORS`, one per element order): first order by raising the order
on the same mesh, second order by Richardson extrapolation from a coarser mesh.

The estimators know nothing of meshing: they ask a ``solve(mesh_size=…, order=…)`` for a
:class:`Solved` (``designer.linear.EstimateSolves`` solves the segment again), and compare
compliances with :func:`relative_error`.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Protocol

import numpy as np
from scipy.linalg import eigh

from vertebra.core.errors import GeometryError

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


@dataclasses.dataclass(frozen=True)
class Solved:
    """What an accuracy estimator uses of a solve (small and picklable: it may come from a
    worker process)."""

    compliance: np.ndarray
    dofs: int
    mean_edge_length: float
    tets: np.ndarray


class Solve(Protocol):
    """The segment solved again at another mesh size or element order (GeometryError when that
    mesh cannot be made)."""

    def __call__(self, *, mesh_size: float, order: int | None = None) -> Solved: ...


def _say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


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
    return float(np.max(np.abs(eigh(C_other - C, C, eigvals_only=True))))


def richardson(C: np.ndarray, C_coarse: np.ndarray, ratio: float, exponent: float) -> np.ndarray:
    """Richardson extrapolation to h → 0 of a compliance ``C`` at mesh size h from ``C_coarse`` at
    ``ratio`` × h, for an error ≈ A h^exponent: C + (C − C_coarse) / (ratio^exponent − 1)."""
    return C + (C - C_coarse) / (ratio ** exponent - 1.0)


def estimate_by_richardson(solve: Solve, compliance: np.ndarray, mesh, progress=None) -> dict:
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


def estimate_by_order_raising(solve: Solve, compliance: np.ndarray, mesh, progress=None) -> dict:
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


def estimate(solve: Solve, compliance: np.ndarray, mesh, progress=None) -> dict:
    """The ``entry.accuracy`` of a compliance computed on ``mesh`` (``geometry.MeshData``; its
    order picks the estimator of ``ACCURACY_ESTIMATORS``), the second solve made by ``solve``.

    Returns ``{"method": "order-raising" | "richardson", "relative_error": estimated error of the
    stored compliance (:func:`relative_error` against the better value), "relative_error_C" (6×6
    block), "extrapolated_compliance": the better value, "basis": one line saying how, "estimate_s",
    and the method's own fields}``, or ``{"method": "unavailable", "reason": …}`` when the solves it
    needs could not be made.
    """
    start = time.perf_counter()
    accuracy = ACCURACY_ESTIMATORS[mesh.order](solve, compliance, mesh, progress)
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
