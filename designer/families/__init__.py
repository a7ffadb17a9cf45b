"""Geometry families of intervertebral segments: the registry (:mod:`.base`: the base class,
its parameters and checks), one module per family, and the look-ups every caller shares
(:func:`family_of`, :func:`canonical_parameters`, :func:`resolve_mesh_size`).

Adding a family touches one module (a :class:`Family` subclass decorated with
``@register_family``) and the import line below that registers it.
"""

from __future__ import annotations

import math

from vertebra.core.errors import GeometryError
from vertebra.designer.families.base import (AXISYMMETRIC, FAMILIES, MATERIAL, Family, Parameter, SegmentSymmetry,
                                            register_family, require)
# importing a family's module registers it (in this order: the order of FAMILIES)
from vertebra.designer.families import rod, tube, bellows, pneumatic, tapered_pneumatic  # noqa: F401

__all__ = ["AXISYMMETRIC", "FAMILIES", "MATERIAL", "Family", "Parameter", "SegmentSymmetry", "register_family",
           "require", "family_of", "canonical_parameters", "resolve_mesh_size"]


def family_of(family) -> Family:
    """The registered family named ``family`` (a :class:`Family` is returned as it is)."""
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
