"""Large-deformation trunk cases with a full nonlinear FE reference (importable from benchmarks/).

Each :class:`TrunkCase` fixes the segments (designer family, parameters, mesh size — the same
meshes for every code), the material model, the loads at load factor 1 and the load factors
(``levels``) at which results are compared. Every load scales with the level: dead forces at
vertebra origins and dead moments (world axes, vertebra 1..m, −1 = tip), cavity pressures, and
gravity (with the vertebra masses, centres of mass at the frame origins). The cases span trunks of
2–16 rod or tube segments, E = 1 MPa, ν = 0.3–0.45, length/radius 0.5–4, tip rotations of
20–90°, planar and 3-D loads, both nonlinear materials, and a CBHA-like pneumatic section up to
its inflation limit.

    from nonlinear_cases import CASES, case_meshes, project_trunk, trunk_loads
    case = CASES["rod4_planar_nh"]
    trunk = project_trunk(case)                        # vertebra.designer.nonlinear.NonlinearTrunk
    out = trunk.solve(trunk_loads(case, case.levels[0]))

CalculiX results for these cases (``benchmarks/bench_ccx_crosscheck.py``) are saved in
``benchmarks/results/ccx_crosscheck.json``: per case and level the vertebra positions and
rotation vectors, chamber volumes, and the agreement with the project's trunk solver.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

E = 1.0e6                   # Pa
BAR = 1.0e5                 # Pa


@dataclass(frozen=True)
class SegmentSpec:
    """``count`` identical segments of a designer family (parameters include the material
    constants ``youngs_modulus``, ``poisson_ratio`` and ``density``)."""

    family: str
    parameters: tuple       # sorted (name, value) pairs: hashable
    mesh_size: float
    count: int = 1
    order: int = 2

    @classmethod
    def of(cls, family: str, mesh_size: float, count: int = 1, **parameters) -> "SegmentSpec":
        return cls(family, tuple(sorted(parameters.items())), mesh_size, count)

    @property
    def p(self) -> dict:
        return dict(self.parameters)


@dataclass(frozen=True)
class TrunkCase:
    name: str
    description: str
    material: str                               # "neo_hookean" | "svk"
    segments: tuple                             # SegmentSpec, bottom to top
    levels: tuple                               # load factors compared
    forces: dict = field(default_factory=dict)  # vertebra -> N (3,), at load factor 1
    moments: dict = field(default_factory=dict)  # vertebra -> N m (3,)
    pressures: dict = field(default_factory=dict)   # segment -> Pa per cavity
    gravity: tuple | None = None                # m/s²
    vertebra_mass: float = 0.0                  # kg, every free vertebra, at its frame origin
    tags: tuple = ()
    level_unit: str = ""                        # what a level means, e.g. "bar" for pneumatic cases
    symmetric_xz: bool = False                  # geometry and loads symmetric about the xz-plane

    def specs(self) -> list:
        """One SegmentSpec per segment, bottom to top."""
        return [s for s in self.segments for _ in range(s.count)]

    @property
    def n_segments(self) -> int:
        return sum(s.count for s in self.segments)

    @property
    def length(self) -> float:
        return float(sum(s.p["length"] * s.count for s in self.segments))

    def vertebra(self, k: int) -> int:
        """Vertebra number 1..m of a load key (−1 = tip)."""
        return k + self.n_segments + 1 if k < 0 else k


def _rod(radius, length, nu, h, count, density=0.0):
    return SegmentSpec.of("rod", h, count, radius=radius, length=length, youngs_modulus=E, poisson_ratio=nu,
                          density=density)


def _tube(outer, inner, length, nu, h, count):
    return SegmentSpec.of("tube", h, count, outer_radius=outer, inner_radius=inner, length=length,
                          youngs_modulus=E, poisson_ratio=nu)


CBHA = SegmentSpec.of("pneumatic", 0.012, 4, outer_radius=0.04, chamber_radius=0.01, chamber_offset=0.0215,
                      length=0.03, chambers=3, youngs_modulus=0.5e6, poisson_ratio=0.45)

_CASES = [
    TrunkCase("rod4_planar_nh", "4 rods R 10 mm, L/R 2, ν 0.45, tip force along (1, 0, −1) (planar; a "
              "force normal to the trunk cannot turn the tip past 90°)", "neo_hookean",
              (_rod(0.01, 0.02, 0.45, 0.005, 4),), levels=(0.15, 0.32, 0.47, 0.72),
              forces={-1: (5.0, 0.0, -5.0)}, tags=("planar", "rod")),
    TrunkCase("rod4_planar_svk", "the same trunk in St Venant–Kirchhoff, to ~50°", "svk",
              (_rod(0.01, 0.02, 0.45, 0.005, 4),), levels=(0.25, 0.6, 1.0),
              forces={-1: (3.0, 0.0, 0.0)}, tags=("planar", "rod")),
    TrunkCase("tube2_slender_svk", "2 tubes R 10/6 mm, L/R 4, ν 0.3, tip force along x (planar)", "svk",
              (_tube(0.01, 0.006, 0.04, 0.3, 0.005, 2),), levels=(0.2, 0.5, 1.0),
              forces={-1: (2.2, 0.0, 0.0)}, tags=("planar", "tube")),
    TrunkCase("rod16_squat_nh", "16 rods R 10 mm, L/R 0.5, ν 0.3, tip force along x with gravity along −x "
              "(rods 1100 kg/m³, vertebrae 5 g)", "neo_hookean",
              (_rod(0.01, 0.005, 0.3, 0.006, 16, density=1100.0),), levels=(0.25, 0.6, 1.0, 1.7),
              forces={-1: (6.0, 0.0, 0.0)}, gravity=(-9.81, 0.0, 0.0), vertebra_mass=0.005,
              tags=("planar", "rod", "gravity")),
    TrunkCase("tube4_3d_nh", "4 tubes R 10/5 mm, L/R 1.5, ν 0.4: tip force in the diagonal plane x = y, "
              "axial compression and torsion (3-D)", "neo_hookean",
              (_tube(0.01, 0.005, 0.015, 0.4, 0.004, 4),), levels=(0.3, 0.65, 1.0),
              forces={-1: (3.5, 3.5, -1.5)}, moments={-1: (0.0, 0.0, 0.03)}, tags=("3d", "tube", "torsion")),
    TrunkCase("rod6_two_loads_svk", "6 rods R 10 mm, L/R 1, ν 0.35: force along x at vertebra 3 and along y "
              "at the tip (3-D)", "svk",
              (_rod(0.01, 0.01, 0.35, 0.005, 6),), levels=(0.4, 1.0),
              forces={3: (6.0, 0.0, 0.0), -1: (0.0, 3.0, 0.0)}, tags=("3d", "rod")),
    TrunkCase("cbha4_pneumatic_nh", "4 CBHA-like slices (R 40 mm, three chambers r 10 mm at 21.5 mm, L 30 mm, "
              "E 0.5 MPa, ν 0.45), chamber 0 pressurised in every slice; levels in bar", "neo_hookean",
              (CBHA,), levels=(0.25, 0.5, 1.0, 1.25, 1.4, 1.5, 1.55, 1.6, 1.65, 1.7),
              pressures={s: (BAR, 0.0, 0.0) for s in range(4)}, tags=("pneumatic",), level_unit="bar",
              symmetric_xz=True),
]
CASES = {c.name: c for c in _CASES}


@lru_cache(maxsize=None)
def _mesh(spec: SegmentSpec):
    from vertebra.designer import FAMILIES, canonical_parameters
    from vertebra.designer.geometry import mesh_segment
    family = FAMILIES[spec.family]
    return mesh_segment(family, canonical_parameters(family, spec.p), spec.mesh_size, spec.order)


def case_meshes(case: TrunkCase) -> list:
    """``designer.geometry.MeshData`` per segment, bottom to top (identical segments share one)."""
    return [_mesh(s) for s in case.specs()]


def n_cavities(spec: SegmentSpec) -> int:
    from vertebra.designer import FAMILIES, canonical_parameters
    family = FAMILIES[spec.family]
    return family.n_cavities(canonical_parameters(family, spec.p))


QUADRATURES = ("project", "calculix")


def _segment(spec: SegmentSpec, mesh, material_name: str, quadrature: str, **options):
    """``designer.nonlinear.NonlinearSegment`` of one spec. ``quadrature="calculix"`` integrates the
    volume terms with CalculiX's C3D10 rule (4 points per tetrahedron) instead of the project's
    (order 4, 11 points), which isolates the quadrature's share of a difference between the codes."""
    from vertebra.designer.nonlinear import NonlinearSegment
    from vertebra.designer.nonlinear.materials import get_material
    p = spec.p
    material = get_material(material_name, p["youngs_modulus"], p["poisson_ratio"])
    common = dict(density=p.get("density", 0.0), n_cavities=n_cavities(spec), length=p["length"])
    if quadrature == "project":
        return NonlinearSegment.build(mesh, material, **common, **options)
    if quadrature != "calculix":
        raise ValueError(f"quadrature {quadrature!r}: expected one of {QUADRATURES}")
    from skfem import Basis, ElementTetP2

    from vertebra.designer.fem import build_fe
    from vertebra.designer.nonlinear.fe_assembly import SolidModel
    from vertebra.designer.nonlinear.framed import FramedSolid
    fe = build_fe(mesh, material.youngs_modulus, material.poisson_ratio, common["density"], common["n_cavities"],
                  common["length"])
    fe.basis = Basis(fe.mesh, ElementTetP2(), intorder=2)
    segment = NonlinearSegment(FramedSolid(SolidModel(fe, material)), **options)
    segment.mesh_data = mesh
    return segment


def project_trunk(case: TrunkCase, quadrature: str = "project", **segment_options):
    """The project's full nonlinear FE trunk (``designer.nonlinear.NonlinearTrunk``) on the case's
    meshes; ``segment_options`` go to ``NonlinearSegment``."""
    from vertebra.designer.nonlinear import NonlinearTrunk, VertebraMass
    built = {}
    segments = []
    for spec, mesh in zip(case.specs(), case_meshes(case)):
        if spec not in built:
            built[spec] = _segment(spec, mesh, case.material, quadrature, **segment_options)
        segments.append(built[spec])
    masses = [VertebraMass()] + [VertebraMass(case.vertebra_mass) for _ in range(case.n_segments)]
    return NonlinearTrunk(segments, vertebrae=masses)


def scaled_loads(case: TrunkCase, level: float) -> dict:
    """Loads at ``level`` (SI, world axes): forces and moments by vertebra 1..m, pressures by
    segment, gravity (or None) and the vertebra masses' weights included in neither."""
    return {"forces": {case.vertebra(k): level * np.asarray(v, float) for k, v in case.forces.items()},
            "moments": {case.vertebra(k): level * np.asarray(v, float) for k, v in case.moments.items()},
            "pressures": {s: level * np.asarray(v, float) for s, v in case.pressures.items()},
            "gravity": None if case.gravity is None else level * np.asarray(case.gravity, float)}


def trunk_loads(case: TrunkCase, level: float):
    """``designer.nonlinear.TrunkLoads`` at ``level``."""
    from vertebra.designer.nonlinear import TrunkLoads
    loads = scaled_loads(case, level)
    return TrunkLoads(forces=loads["forces"], moments=loads["moments"], gravity=loads["gravity"],
                      pressures=loads["pressures"])
