"""The HDF5 catalogue of condensed segments: entry types, schema, safe writing."""

from vertebra.store.entry import SegmentEntry, canonical_json, content_key
from vertebra.core.errors import (CatalogueError, ConvergenceError, GeometryError, InputError, OptionError, SceneError,
                                   SpecError, TrajectoryError, VertebraError)

__all__ = [
    "SegmentEntry", "canonical_json", "content_key",
    "VertebraError", "InputError", "SceneError", "SpecError", "TrajectoryError", "OptionError", "CatalogueError", "GeometryError", "ConvergenceError",
]
