"""Design one segment: parameters → a condensed catalogue entry, by the condenser of its material.

Two condensers implement :class:`Condenser`: ``linear`` (:class:`~vertebra.designer.linear.LinearCondenser`:
gmsh → scikit-fem → the compliance onto the segment's two frames, with the estimate of its
discretisation error) and the hyperelastic materials
(:class:`~vertebra.designer.nonlinear_condensation.NonlinearCondenser`: the linear entry, then its
energy ψ(s, p) sampled with the nonlinear FE on the same mesh and fitted).

``design_segment`` is safe in a worker process: gmsh is initialised and finalised inside (one gmsh
per process), BLAS threads are pinned to one, every gmsh option is set explicitly with a fixed
seed. It does not write anywhere; ``store.catalogue.add_entry(path, entry)`` does.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import Protocol

from vertebra.core.errors import OptionError
from vertebra.designer.keys import LINEAR, SegmentDesign, sampling_settings
from vertebra.designer.linear import LinearCondenser, LockingWarning, locking_message
from vertebra.designer.nonlinear_condensation import NonlinearCondenser
from vertebra.designer.threads import pin_blas_threads
from vertebra.store.entry import SegmentEntry


class Condenser(Protocol):
    """Makes the catalogue entry of a resolved segment design."""

    def condense(self, design: SegmentDesign, progress=None) -> SegmentEntry: ...


def condenser_for(material: str, *, linear_solver: str = "auto", amg_threshold: int | None = None,
                  max_elements: int | None = None, estimate_accuracy: bool = True, estimate_alongside: bool = False,
                  executor: str = "serial", workers: int | None = None, scheduler: str | None = None) -> Condenser:
    """The condenser of ``material`` with these options (see :func:`design_segment`)."""
    linear = LinearCondenser(linear_solver=linear_solver, amg_threshold=amg_threshold, max_elements=max_elements,
                             estimate_accuracy=estimate_accuracy, estimate_alongside=estimate_alongside)
    if material == LINEAR:
        return linear
    return NonlinearCondenser(linear, executor=executor, workers=workers, scheduler=scheduler)


def with_nonlinear_mesh(sampling, nonlinear_mesh_size: float, material: str):
    """``sampling`` (None, a dict or ``SamplingSettings``) with ``nonlinear_mesh_size`` set; an
    OptionError for a linear material (nothing nonlinear to sample) or a conflicting setting."""
    if material == LINEAR:
        raise OptionError("a linear entry has no nonlinear part: choose a hyperelastic --material",
                          field="nonlinear_mesh_size")
    settings = sampling_settings(sampling)
    if settings.nonlinear_mesh_size not in (None, nonlinear_mesh_size):
        raise OptionError(f"{nonlinear_mesh_size!r} differs from sampling.nonlinear_mesh_size = "
                          f"{settings.nonlinear_mesh_size!r}", field="nonlinear_mesh_size")
    return dataclasses.replace(settings, nonlinear_mesh_size=nonlinear_mesh_size)


def design_segment(family, parameters: dict, *, mesh_size=None, order: int = 2, name: str | None = None,
                   linear_solver: str = "auto", estimate_accuracy: bool = True, progress=None,
                   amg_threshold: int | None = None, max_elements: int | None = None, material: str = LINEAR,
                   sampling=None, executor: str = "serial", workers: int | None = None,
                   scheduler: str | None = None, estimate_alongside: bool = False,
                   nonlinear_mesh_size: float | None = None) -> SegmentEntry:
    """Condensed catalogue entry of one segment (docs/catalogue.md).

    ``progress``: optional callable receiving one-line status messages.
    ``linear_solver``: "auto" | "direct" | "amg" (auto: direct below
    ``designer.linsolve.AUTO_THRESHOLD`` interior unknowns, overridable with ``amg_threshold``).
    ``estimate_accuracy``: also estimate the compliance's discretisation error and store it in
    ``entry.accuracy`` (:func:`designer.linear.estimate_accuracy_of`: second order on the same
    mesh for a first-order entry, Richardson extrapolation from a coarser mesh for a second-order one).
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
    ``nonlinear_mesh_size`` (m, ``sampling.nonlinear_mesh_size``): multi-fidelity, the energy's
    nonlinear part sampled and fitted on this coarser mesh of the segment, its linear part
    the exact one of ``mesh_size``'s mesh, its held-out error measured on ``mesh_size``'s mesh
    (``sampling.check_paths`` paths; designer.nonlinear_condensation.check_on_mesh).
    """
    pin_blas_threads(1)
    if nonlinear_mesh_size is not None:
        sampling = with_nonlinear_mesh(sampling, nonlinear_mesh_size, material)
    design = SegmentDesign.resolve(family, parameters, mesh_size=mesh_size, order=order, material=material,
                                   sampling=sampling, name=name, started=time.perf_counter())
    message = locking_message(design.parameters, order)
    if message is not None:
        warnings.warn(message, LockingWarning, stacklevel=2)
        if progress is not None:
            progress(f"warning: {message}")
        design = dataclasses.replace(design, warnings=(message,))
    condenser = condenser_for(material, linear_solver=linear_solver, amg_threshold=amg_threshold,
                              max_elements=max_elements, estimate_accuracy=estimate_accuracy,
                              estimate_alongside=estimate_alongside, executor=executor, workers=workers,
                              scheduler=scheduler)
    return condenser.condense(design, progress)
