"""vertebra: model and control continuum robots built from rigid vertebrae.

Subpackages::

    vertebra.designer   parametrised segments → gmsh → scikit-fem → condensed catalogue entries
    vertebra.store      the HDF5 catalogue (entries, schema, safe concurrent writing)
    vertebra.solver     the lightweight runtime (numpy/scipy): forward and inverse simulation
    vertebra.cli        the ``vertebra`` command

Subpackages are imported on first use (``from vertebra import solver``), so importing
``vertebra`` alone loads nothing heavy.
"""

__version__ = "0.2.0"

__all__ = ["__version__"]
