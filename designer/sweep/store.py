"""What a sweep needs of a catalogue, and the HDF5 catalogue that provides it.

The parent process asks the store which keys it holds (to resume) and merges what the
workers committed; each worker adds its own entry. A store instance travels to the
workers, so it must pickle: plain data (the catalogue's absolute path), no open handles.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from vertebra.store import catalogue
from vertebra.store.entry import SegmentEntry
from vertebra.core.errors import CatalogueError


@runtime_checkable
class SweepStore(Protocol):
    """A catalogue as a sweep uses it; ``path`` is absolute (workers may run elsewhere)."""

    path: str

    def keys(self) -> set[str] | None:
        """Every key, in one read; ``None``: not available at once, ask :meth:`has` per key."""
        ...

    def has(self, key: str) -> bool:
        """Whether an entry with this key was committed (merged or not)."""
        ...

    def add(self, entry: SegmentEntry) -> str:
        """Commit one entry durably (runs in a worker, concurrently with others); its key."""
        ...

    def consolidate(self) -> None:
        """Merge the entries the workers committed (the parent, every few entries and at the end)."""
        ...


@dataclass(frozen=True)
class CatalogueStore:
    """The HDF5 catalogue (``vertebra.store.catalogue``).

    Workers commit shards (``add_entry(..., consolidate=False)``): durable and visible to
    readers at once, safe with many writers. The parent merges them in batches, because a
    merge rewrites the whole file and merging per entry would cost O(N²) over a sweep.
    """

    path: str

    def keys(self) -> set[str] | None:
        if not os.path.exists(self.path):
            return None               # only shards, or nothing: ``has`` knows how to look
        try:
            with catalogue.open_catalogue(self.path) as cat:
                return set(cat.keys())     # the file's entries and the committed shards
        except (CatalogueError, OSError):
            return None

    def has(self, key: str) -> bool:
        return catalogue.has_entry(self.path, key)

    def add(self, entry: SegmentEntry) -> str:
        return catalogue.add_entry(self.path, entry, consolidate=False)

    def consolidate(self) -> None:
        catalogue.consolidate(self.path)
