"""The designer on small, coarse entries: ``design_segment`` (gmsh mesh, scikit-fem assembly,
condensation) and ``vertebra prepare`` of a scene of design segments (first run into an empty
catalogue, second run on the filled one: planning only)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

ROD = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
PNEUMATIC = {"outer_radius": 0.02, "chamber_radius": 0.005, "chamber_offset": 0.011, "length": 0.02,
             "youngs_modulus": 1e6, "poisson_ratio": 0.45, "density": 1100.0}
FAMILIES = {"rod": ROD, "pneumatic": PNEUMATIC}


class Design:
    """One coarse entry (h = 8 mm on the rod, 5 mm on the pneumatic slice), with and without the
    accuracy estimate (a second solve: a coarser mesh for P2, P2 on the same mesh for P1); P1 on
    the rod only (linear tetrahedra lock at the slice's ν = 0.45)."""

    params = (["rod", "pneumatic"], [1, 2], [False, True])
    param_names = ["family", "order", "estimate"]
    number = 1
    repeat = (3, 10, 20.0)
    timeout = 180

    def setup(self, family, order, estimate):
        from vertebra.designer.segment import design_segment

        if family == "pneumatic" and order == 1:
            raise NotImplementedError("P1 locks at ν = 0.45")
        self.design = design_segment
        self.mesh_size = 0.008 if family == "rod" else 0.005

    def time_design(self, family, order, estimate):
        self.design(family, FAMILIES[family], mesh_size=self.mesh_size, order=order, estimate_accuracy=estimate)


def _scene():
    from vertebra import solver

    segment = {"type": "design", "family": "rod", "mesh_size": 0.008, "order": 2}
    return solver.parse_scene({"name": "two coarse rods", "segment": [
        dict(segment, parameters=ROD, count=2),
        dict(segment, parameters=dict(ROD, radius=0.009), count=1)]})


class Prepare:
    """``prepare`` of a scene of two coarse P2 rod designs (three segments), serial, no accuracy
    estimate: the first run designs both entries, the second finds them in the catalogue."""

    number = 1
    repeat = (3, 10, 20.0)
    timeout = 180

    def setup(self):
        from vertebra.designer import prepare

        self.prepare = prepare
        self.scene = _scene()
        self.tmp = Path(tempfile.mkdtemp(prefix="vertebra-asv-"))
        self.filled = self.tmp / "filled.h5"
        prepare(self.scene, self.filled, executor="serial", workers=1, estimate_accuracy=False, progress=False)
        self.count = 0

    def teardown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def time_first_run(self):
        self.count += 1
        self.prepare(self.scene, self.tmp / f"empty-{self.count}.h5", executor="serial", workers=1,
                     estimate_accuracy=False, progress=False)

    def time_second_run(self):
        self.prepare(self.scene, self.filled, executor="serial", workers=1, progress=False)
