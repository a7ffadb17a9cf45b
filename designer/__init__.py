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

Heavy imports (gmsh, scikit-fem, pyamg, meshio) happen inside the functions; ``prepare`` reads
the runtime's scenes as data (the designer never imports the solver).
"""

from vertebra.designer.families import (FAMILIES, Family, Parameter, canonical_parameters, register_family,
                                        resolve_mesh_size)
from vertebra.designer.keys import entry_key
from vertebra.designer.preparation import PrepareReport, prepare
from vertebra.designer.segment import design_segment
from vertebra.designer.vertebra import VERTEBRA_PARAMETERS, vertebra_properties, vertebra_snippet

__all__ = [
    "FAMILIES", "Family", "Parameter", "register_family",
    "canonical_parameters", "entry_key", "design_segment", "resolve_mesh_size",
    "VERTEBRA_PARAMETERS", "vertebra_properties", "vertebra_snippet",
    "PrepareReport", "prepare",
]
