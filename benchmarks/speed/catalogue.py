"""The HDF5 catalogue: adding entries (shard, merge under the lock, atomic replace), opening a
1,000-entry catalogue and loading one entry, listing, querying and verifying it."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

ENTRIES = 1000


def make_entry(i: int, seed: int = 0):
    """A seeded bellows entry with one cavity (7×7 compliance)."""
    from vertebra.store.entry import SegmentEntry, content_key

    rng = np.random.default_rng([seed, i])
    a = rng.normal(size=(7, 7))
    return SegmentEntry(
        key=content_key({"seed": seed, "i": i}), name=f"bellows-{seed}-{i}", family="bellows",
        parameters={"outer_radius": 0.01 + 1e-6 * i, "length": 0.04, "wall_thickness": 0.001,
                    "convolutions": 4, "youngs_modulus": 1.2e6, "poisson_ratio": 0.45},
        compliance=a @ a.T + 7 * np.eye(7), cavity_volumes=[1e-6 * (1 + rng.random())],
        mass=0.01, center_of_mass=[0.0, 0.0, 0.02],
        mesh={"order": 2, "size": 0.002, "elements": 12000 + i, "dofs": 60000 + i},
        accuracy={"relative_change": 1e-3, "method": "refined mesh h/2"},
        timings={"mesh_s": 1.2, "assemble_s": 3.4, "solve_s": 5.6, "total_s": 10.2},
        provenance={"vertebra": "0.1.0", "gmsh": "4.15.2", "scikit-fem": "12.0.2", "host": "bench",
                    "date": "2026-11-22T00:00:00Z"})


class Read:
    """Reading a catalogue of 1,000 entries (built once per run by ``setup_cache``)."""

    timeout = 300

    def setup_cache(self):
        from vertebra.store import catalogue

        path = Path("catalogue-read.h5").resolve()
        entries = [make_entry(i) for i in range(ENTRIES)]
        for start in range(0, ENTRIES, 250):
            catalogue.add_entries(path, entries[start:start + 250])
        return str(path), entries[ENTRIES // 2].key

    def setup(self, cache):
        from vertebra.store import catalogue

        self.catalogue = catalogue

    def time_open_and_load(self, cache):
        path, key = cache
        with self.catalogue.open_catalogue(path) as cat:
            cat.load(key)

    def time_load_by_prefix(self, cache):
        path, key = cache
        with self.catalogue.open_catalogue(path) as cat:
            cat.load(key[:12])

    def time_list(self, cache):
        path, _ = cache
        with self.catalogue.open_catalogue(path) as cat:
            cat.list()

    def time_query(self, cache):
        path, _ = cache
        self.catalogue.query(path, ["family=bellows", "outer_radius>0.0105"])

    def time_has_entry(self, cache):
        path, key = cache
        self.catalogue.has_entry(path, key)

    def time_verify(self, cache):
        path, _ = cache
        self.catalogue.verify(path)

    def peakmem_open_and_load(self, cache):
        path, key = cache
        with self.catalogue.open_catalogue(path) as cat:
            cat.load(key)


class Write:
    """Adding entries: one entry into a fresh catalogue (shard + fsync + merge + atomic replace)
    and into one of 1,000 entries (the merge copies the file), the shard alone, 100 at once."""

    number = 1
    repeat = (3, 10, 20.0)
    timeout = 300

    def setup_cache(self):
        from vertebra.store import catalogue

        path = Path("catalogue-write.h5").resolve()
        entries = [make_entry(i, seed=1) for i in range(ENTRIES)]
        for start in range(0, ENTRIES, 250):
            catalogue.add_entries(path, entries[start:start + 250])
        return str(path)

    def setup(self, full):
        from vertebra.store import catalogue

        self.catalogue = catalogue
        self.tmp = Path(tempfile.mkdtemp(prefix="vertebra-asv-"))
        self.full = self.tmp / "full.h5"
        shutil.copy(full, self.full)
        self.count = 0

    def teardown(self, full):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _next(self, seed=2):
        self.count += 1
        return make_entry(self.count, seed=seed)

    def time_add_to_fresh(self, full):
        self.catalogue.add_entry(self.tmp / f"fresh-{self.count}.h5", self._next())

    def time_add_shard_only(self, full):
        self.catalogue.add_entry(self.tmp / "shards.h5", self._next(), consolidate=False)

    def time_add_to_1000(self, full):
        self.catalogue.add_entry(self.full, self._next())

    def time_add_100(self, full):
        self.count += 1
        self.catalogue.add_entries(self.tmp / f"batch-{self.count}.h5",
                                   [make_entry(i, seed=1000 + self.count) for i in range(100)])
