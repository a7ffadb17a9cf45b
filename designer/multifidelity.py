"""Which mesh a nonlinear entry's nonlinear part is sampled on, and whether the entry's mesh accepts it.

A multi-fidelity entry (docs/nonlinear-condensation.md, "Multi-fidelity") keeps its mesh's exact
linear part and takes the nonlinear part ψ_nl of its energy from a coarser mesh of the same
segment, checked on its own mesh. Above :data:`AUTO_DOFS` estimated DoFs the design chooses
that coarser mesh itself (:func:`choose_nonlinear_mesh`), before meshing, so that the content
key says what is designed; below it nothing changes (same settings, same key). The check's
verdict (:func:`check_verdict`) decides whether the chosen mesh is kept or the entry falls back
to sampling its own mesh.

Why these numbers (docs/trade.md (i)): per FE solve, full P2 rod entries cost 0.60 s at 8.4k
DoFs and 12.8 s at 47k (5.6× the DoFs, 21× the cost: the sparse factor's fill and the Newton
iterations per pose grow with the mesh); the CBHA-like slice at 18.4k DoFs 1.46 s, so the
super-linear growth starts between 10k and 20k. The nonlinear part converges with the mesh much
faster than the linear part: a rod's ψ_nl from 5 mm (3.7k DoFs) missed the held-out samples of a
3.5 mm mesh by 0.0057 of the load range (the 3.5 mm entry's own fit 0.0061), from 3.5 mm
(8.4k) a 1.83 mm mesh (47k) by 0.0056 (its own 0.0066), from 8 mm (1.1k, less than one
element across the radius) by 0.0104.
"""

from __future__ import annotations

import math
from dataclasses import replace

#: estimated DoFs of the entry's mesh from which the nonlinear part is sampled on a coarser one
AUTO_DOFS = 15_000
#: estimated DoFs of the chosen coarser mesh
NONLINEAR_DOFS = 6_000
#: DoFs (3 per node) per cell of volume h³ of the segment's bounding cylinder (π R² L): gmsh
#: meshes of rods, tubes and CBHA-like slices at 2-8k+ DoFs have 23-30 (P2) and 4.2-4.6 (P1);
#: coarser meshes more (their surface nodes weigh), so the estimate is low there — far below
#: :data:`AUTO_DOFS`
DOFS_PER_CELL = {1: 4.2, 2: 25.0}
#: the default check: the held-out load (and volume) error on the entry's mesh at most this
#: factor times the coarse fit's own held-out error (the mesh may add half the fit's error)
CHECK_FACTOR = 1.5


def estimated_dofs(family, p: dict, mesh_size: float, order: int) -> int:
    """DoFs of ``family``'s mesh at ``mesh_size`` and ``order``, from the bounding cylinder's
    volume (no meshing: the content key is computed without it)."""
    radius, length = family.outer_radius(p), family.length(p)
    return int(DOFS_PER_CELL[order] * math.pi * radius ** 2 * length / mesh_size ** 3)


def chosen_mesh_size(family, p: dict, order: int) -> float:
    """The mesh size whose estimated DoFs are :data:`NONLINEAR_DOFS` (m, to 0.01 mm)."""
    radius, length = family.outer_radius(p), family.length(p)
    h = (DOFS_PER_CELL[order] * math.pi * radius ** 2 * length / NONLINEAR_DOFS) ** (1.0 / 3.0)
    return round(h, 5)


def choose_nonlinear_mesh(family, p: dict, mesh_size: float, order: int, settings):
    """``settings`` (``SamplingSettings``) with the nonlinear mesh chosen: unchanged when a
    nonlinear mesh is set already, the automatic choice is off (``auto_nonlinear_mesh``), the
    entry's mesh is estimated below :data:`AUTO_DOFS`, or a cavity is sampled under pressure
    (the ballooning near the inflation limit is not converged on a coarser mesh: CBHA-like
    slices at 12 mm with ψ_nl from 16 mm put a four-slice trunk 0.79 % of its length off at 1.5
    bar, bending angle 4.5 %, volume 4.2 %, against 0.17 %, 0.95 %, 1.0 % for the full entry,
    although the check's two held-out paths were within the full entry's held-out error);
    otherwise ``nonlinear_mesh_size`` =
    :func:`chosen_mesh_size` and ``nonlinear_mesh_chosen``."""
    if (settings.nonlinear_mesh_size is not None or not settings.auto_nonlinear_mesh or order not in DOFS_PER_CELL
            or estimated_dofs(family, p, mesh_size, order) < AUTO_DOFS or settings.pressurised(family.n_cavities(p))):
        return settings
    return replace(settings, nonlinear_mesh_size=chosen_mesh_size(family, p, order), nonlinear_mesh_chosen=True)


def check_verdict(check: dict, coarse_held: dict, tolerance: float | None) -> tuple[bool, str]:
    """``(passed, why)`` of a multi-fidelity entry's check on its mesh: ``check`` its held-out
    errors there (``held``: ``fit_errors``' dict), ``stopped`` paths and, for a pressurised
    cavity, ``inflation`` (``entry_mesh`` and ``nonlinear_mesh``: ``inflation_errors``' dicts);
    ``coarse_held`` the coarse fit's own held-out errors. The load (and, for cavities, volume)
    errors and the free inflation response's pose and volume errors must be at most
    ``tolerance``, or by default :data:`CHECK_FACTOR` times the coarse fit's own; a check path
    that stopped on a failed solve (not at a pose cap) fails it."""
    failed = [f"path {i} stopped on the entry's mesh ({reason})" for i, reason in check["stopped"].items()
              if not reason.startswith("pose")]
    what = "the tolerance" if tolerance is not None else f"{CHECK_FACTOR:g} × the coarse fit's"
    inflation = check.get("inflation") or {}
    comparisons = [("held-out", check["held"], coarse_held),
                   ("free inflation", inflation.get("entry_mesh", {}), inflation.get("nonlinear_mesh", {}))]
    for label, fine, own in comparisons:
        for name in ("load_max", "volume_max", "pose_max"):
            if name not in fine:
                continue
            bound = tolerance if tolerance is not None else CHECK_FACTOR * own.get(name, math.inf)
            if not fine[name] <= bound:
                failed.append(f"{label} {name.split('_')[0]} error {fine[name]:.3g} > {bound:.3g} ({what})")
    if failed:
        return False, "; ".join(failed)
    return True, "held-out errors within " + ("the tolerance" if tolerance is not None
                                              else f"{CHECK_FACTOR:g} × the coarse fit's")
