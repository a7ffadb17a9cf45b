"""What ``vertebra design`` and ``vertebra catalogue show`` say about an entry's nonlinear mesh:
the coarser mesh its nonlinear part came from (asked for or chosen by the design), the check on
the entry's mesh and its verdict, or the chosen mesh that was dropped after a failed check."""

from __future__ import annotations

import math


def _load_max(held) -> float:
    return float(held.get("load_max", math.nan)) if isinstance(held, dict) else math.nan


def nonlinear_mesh_lines(energy) -> list[str]:
    """The lines (without a label) describing ``energy``'s nonlinear mesh; none for an entry
    sampled on its own mesh from the start."""
    sampling = energy.sampling if isinstance(energy.sampling, dict) else {}
    fit_error = energy.fit_error if isinstance(energy.fit_error, dict) else {}
    coarse, fallback = sampling.get("nonlinear_mesh"), sampling.get("nonlinear_mesh_fallback")
    lines = []
    if isinstance(coarse, dict):
        how = (f"chosen by the design (this mesh about {coarse.get('estimated_entry_dofs', 0):,} DoFs, "
               f"≥ {coarse.get('auto_dofs', 0):,})" if coarse.get("chosen") else "asked for")
        lines.append(f"nonlinear part sampled on a coarser mesh, {how}: h = {coarse.get('mesh_size')} m, "
                     f"{coarse.get('dofs')} DoFs (held-out load error there "
                     f"{_load_max(fit_error.get('nonlinear_mesh_held_out')):.3g}); linear part and held-out "
                     f"check on this mesh")
        verdict = (sampling.get("entry_mesh_check") or {}).get("verdict")
        if isinstance(verdict, dict):
            lines.append(f"check on this mesh passed: {verdict.get('why')}")
    elif isinstance(fallback, dict):
        mesh = fallback.get("nonlinear_mesh", {})
        verdict = fallback.get("entry_mesh_check", {}).get("verdict", {})
        lines.append(f"nonlinear part sampled on this mesh: the coarser mesh chosen (h = {mesh.get('mesh_size')} m, "
                     f"{mesh.get('dofs')} DoFs) failed the check here ({verdict.get('why')}; held-out load error "
                     f"{_load_max(fallback.get('held_out')):.3g} on this mesh, "
                     f"{_load_max(fallback.get('nonlinear_mesh_held_out')):.3g} on its own)")
    return lines
