"""designer/: parametrised segments and vertebrae → gmsh → scikit-fem → condensed catalogue entries.

Public API::

    designer.FAMILIES                                  # name -> family (rod, tube, bellows, pneumatic, tapered_pneumatic)
    designer.canonical_parameters(family, parameters)  # validated, defaults filled (GeometryError before meshing)
    designer.entry_key(family, parameters, mesh_size=None, order=2)   # content key without meshing
    designer.design_segment(family, parameters, ...)   # -> store.entry.SegmentEntry
    designer.vertebra_properties(parameters)           # rigid vertebra disc: mass, centre of mass, inertia
    designer.prepare(scene, catalogue=None, build_model=None, ...)   # -> (resolved scene, PrepareReport):
                                                       #    design what a scene's design segments miss, nonlinear
                                                       #    ones sampled over the scene's range (docs/prepare.md)

Heavy imports (gmsh, scikit-fem, pyamg, meshio) happen inside the functions; ``prepare``
(which uses the runtime's scenes) is imported on first use, so sweep workers do not load the
runtime.
"""

from vertebra.designer.families import FAMILIES, Family, Parameter, register_family
from vertebra.designer.segment import canonical_parameters, design_segment, entry_key, resolve_mesh_size
from vertebra.designer.vertebra import VERTEBRA_PARAMETERS, vertebra_properties, vertebra_snippet

__all__ = [
    "FAMILIES", "Family", "Parameter", "register_family",
    "canonical_parameters", "entry_key", "design_segment", "resolve_mesh_size",
    "VERTEBRA_PARAMETERS", "vertebra_properties", "vertebra_snippet",
    "PrepareReport", "prepare",
]


def __getattr__(name):
    """``prepare`` and ``PrepareReport`` from :mod:`vertebra.designer.preparation`, imported on first use."""
    if name in ("prepare", "PrepareReport"):
        from vertebra.designer import preparation
        return getattr(preparation, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
