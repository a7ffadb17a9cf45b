"""Geometrically nonlinear FE of segments and trunks (total Lagrangian, scikit-fem bases).

Public API::

    from vertebra.designer.nonlinear import (MATERIALS, get_material, NonlinearSegment,
                                              SegmentResponse, SegmentSettings)

    material = get_material("neo_hookean", youngs_modulus, poisson_ratio)   # "linear" | "svk" | "neo_hookean"
    seg = NonlinearSegment.build(mesh_data, material, density=..., n_cavities=..., length=...)
    seg = NonlinearSegment.from_family("pneumatic", parameters, "neo_hookean", mesh_size=..., order=2)
    resp = seg.solve(R, t, pressures=None, initial=None, gravity=None)     # frame b at (R, t) in a
    resp.wrench, resp.tangent, resp.volumes, resp.dvolume_dpose, resp.dvolume_dpressure, resp.energy
    resp2 = seg.solve(R2, t2, initial=resp.state)                          # continuation

    trunk = NonlinearTrunk([seg, seg, seg], vertebrae=[VertebraMass(...), ...])   # full-trunk reference
    out = trunk.solve(TrunkLoads(forces={-1: F}, moments={-1: M}, gravity=g, pressures={s: p}))
    out.positions, out.quaternions, out.volumes, out.diagnostics

Conventions are documented in :mod:`.segment` and ``docs/nonlinear-fe.md``. Heavy
imports (scikit-fem, gmsh, pyamg) happen inside functions.
"""

from vertebra.designer.nonlinear.materials import MATERIALS, get_material
from vertebra.designer.nonlinear.fe_newton import NewtonSettings
from vertebra.designer.nonlinear.fe_segment import NonlinearSegment, SegmentResponse, SegmentSettings, SegmentState
from vertebra.designer.nonlinear.fe_trunk import (NonlinearTrunk, TrunkLoads, TrunkResponse, TrunkSettings, TrunkState,
                                               VertebraMass)

__all__ = ["MATERIALS", "get_material", "NewtonSettings", "NonlinearSegment", "SegmentResponse",
           "SegmentSettings", "SegmentState", "NonlinearTrunk", "TrunkLoads", "TrunkResponse", "TrunkSettings",
           "TrunkState", "VertebraMass"]
