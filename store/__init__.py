"""The HDF5 catalogue of condensed segments: entry types, schema, safe writing."""

from vertebra.store.entry import SegmentEntry, canonical_json, content_key
from vertebra.store.errors import CatalogueError, ConvergenceError, GeometryError, SceneError, VertebraError

__all__ = [
    "SegmentEntry", "canonical_json", "content_key",
    "VertebraError", "SceneError", "CatalogueError", "GeometryError", "ConvergenceError",
]
