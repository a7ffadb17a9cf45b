"""Links that store a nonlinear entry's fitted energy: the 20-link forward solve of a trunk of
a coarse neo-Hookean rod entry against the same trunk with the entry's linear part."""

from __future__ import annotations

import dataclasses
from pathlib import Path

ROD = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
MESH = 0.008                      # a coarse P2 rod (~1.1k DoFs)
SAMPLING = {"degree": 6}          # the default sampling of a degree-6 fit
TIP_FORCE = 0.3                   # N along x: a large bend of the 20 links


class Entries:
    """A trunk of 20 repetitions of the rod entry under a tip force, solved from rest, with the
    fitted energy (``nonlinear``) and without it (``linear``: the entry's compliance only). The
    entry is designed once per run (``setup_cache``)."""

    params = ["nonlinear", "linear"]
    param_names = ["entry"]
    timeout = 600

    def setup_cache(self):
        from vertebra import designer
        from vertebra.store import catalogue

        path = Path("nonlinear-rod.h5").resolve()
        entry = designer.design_segment("rod", ROD, mesh_size=MESH, material="neo_hookean", sampling=SAMPLING,
                                        estimate_accuracy=False, executor="serial", name="rod-d6")
        catalogue.add_entry(path, entry)
        return str(path), entry.key

    def setup(self, cache, kind):
        from vertebra import solver
        from vertebra.store import catalogue

        path, key = cache
        with catalogue.open_catalogue(path) as cat:
            entry = cat.load(key)
        if kind == "linear":          # the compliance alone: no energy, no record of the nonlinear design
            entry = dataclasses.replace(entry, energy=None, provenance={
                k: v for k, v in entry.provenance.items() if k != "nonlinear"})
        scene = solver.parse_scene({
            "catalogue": {"path": path},
            "segment": [{"type": "entry", "entry": entry.name, "count": 20}],
            "load": [{"vertebra": -1, "force": [TIP_FORCE, 0.0, 0.0]}],
            "effector": [{"name": "tip", "vertebra": -1}]})
        self.model = solver.build_model(scene, {entry.name: entry})
        self.model.solve()

    def time_solve(self, cache, kind):
        self.model.solve()

    def track_iterations(self, cache, kind):
        return self.model.solve().iterations

    track_iterations.unit = "iterations"
