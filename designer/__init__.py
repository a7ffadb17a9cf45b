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

__all__ = [
    "FAMILIES", "Family", "Parameter", "register_family",
    "canonical_parameters", "entry_key", "design_segment", "resolve_mesh_size",
    "VERTEBRA_PARAMETERS", "vertebra_properties", "vertebra_snippet",
    "PrepareReport", "prepare",
]


def __getattr__(name: str):
    """The public API, loaded on first use (PEP 562): importing one designer module alone — a
    pool worker unpickling its initializer from ``designer.executors`` — must not first load the
    whole designer (seconds of numpy/scipy imports during which a worker of a killed parent
    could not yet notice it is orphaned)."""
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    # lazy: the public API's modules load at the first use of any of its names (docstring)
    from vertebra.designer import families, keys, preparation, segment, vertebra
    for module in (families, keys, preparation, segment, vertebra):
        if hasattr(module, name):
            globals()[name] = value = getattr(module, name)
            return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
