"""Exactness of condensation (DESIGN.md §7): a full FE model of a chain of three segments
joined by rigid vertebrae — ONE assembled FE system with shared interface frames — against
the chain of condensed entries, solved (a) by an independent assembly of the condensed
compliances and (b) by the runtime solver (``solver.build_model``).

Static condensation of a linear problem is exact, so (a) must agree to solver round-off;
(b) uses the runtime's own link formulation (constant strain, exponential map), linearised
at the rest pose, which is exact to first order — and its nonlinear Newton solve with a
load small enough that geometric nonlinearity stays below 1e-7 of the response.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vertebra import solver
from vertebra.designer import FAMILIES, canonical_parameters
from vertebra.designer.fem import build_fe, condense
from vertebra.designer.geometry import mesh_segment
from vertebra.store.entry import SegmentEntry

from reference.fe_chain import chain_condensed_solve, chain_fe_solve

pytestmark = pytest.mark.slow      # the module's three-segment chain is meshed and solved by the full FE

E = 1.0e6
SEGMENTS = [  # bottom to top: three different segments with cavities
    ("pneumatic", dict(outer_radius=0.012, chamber_radius=0.0025, chamber_offset=0.006, chambers=2,
                       chamber_angle_deg=math.degrees(0.5), length=0.02, youngs_modulus=2 * E, poisson_ratio=0.3), 0.005),
    ("pneumatic", dict(outer_radius=0.012, chamber_radius=0.003, chamber_offset=0.0065, length=0.015,
                       youngs_modulus=E, poisson_ratio=0.45), 0.004),
    ("tapered_pneumatic", dict(bottom_outer_radius=0.012, top_outer_radius=0.01, bottom_chamber_radius=0.003,
                               top_chamber_radius=0.0025, bottom_chamber_offset=0.0065, top_chamber_offset=0.0055,
                               length=0.015, youngs_modulus=E, poisson_ratio=0.45), 0.004),
]
TIP_WRENCH = np.array([0.02, -0.01, 0.05, 1e-4, 2e-4, -1e-4])       # N, N m at the tip frame
PRESSURES = [np.zeros(2), np.array([2.0e3, 0.0, 0.0]), np.array([0.0, 1.5e3, 0.0])]   # Pa per segment
# tolerance of the issue: relative tip-displacement difference ≤ 1e-6
TOLERANCE = 1e-6


@pytest.fixture(scope="module")
def chain():
    fes, entries = [], []
    for s, (family, parameters, h) in enumerate(SEGMENTS):
        fam = FAMILIES[family]
        p = canonical_parameters(fam, parameters)
        fe = build_fe(mesh_segment(fam, p, h, 2), p["youngs_modulus"], p["poisson_ratio"], p["density"],
                      fam.n_cavities(p), fam.length(p))
        compliance = condense(fe, ("top",), linear_solver="direct").compliance()
        entries.append(SegmentEntry(key=f"k{s}", name=f"segment{s}", family=family, parameters=p,
                                    compliance=compliance, cavity_volumes=fe.cavity_volumes, mass=0.0,
                                    center_of_mass=fe.center_of_mass,
                                    rest_translation=[0.0, 0.0, fam.length(p)]))
        fes.append(fe)
    full = chain_fe_solve(fes, TIP_WRENCH, PRESSURES)
    return fes, entries, full


def _relative(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b)


def test_condensed_chain_equals_full_fe_model(chain):
    fes, entries, full = chain
    condensed = chain_condensed_solve([e.compliance for e in entries], [e.rest_translation[2] for e in entries],
                                      TIP_WRENCH, PRESSURES)
    # every frame, translations and rotations, and every cavity's volume growth
    assert _relative(condensed["frames"][-1, :3], full["frames"][-1, :3]) < TOLERANCE
    assert _relative(condensed["frames"], full["frames"]) < TOLERANCE
    for s in (1, 2):
        assert _relative(condensed["volume_growth"][s], full["volume_growth"][s]) < TOLERANCE
    # it is in fact exact to round-off: direct solves of a linear problem
    assert _relative(condensed["frames"], full["frames"]) < 1e-9


def _scene(entries, force, moment, pressures):
    return {
        "solver": {"tolerance": 1e-13, "max_iterations": 50},
        "catalogue": {"path": "unused.h5"},                 # entries are passed in memory
        "segment": [{"type": "entry", "entry": e.name, "count": 1, "vertebra": {"mass": 0.0}} for e in entries],
        "chamber": [{"name": "c1", "cavity": 0, "from": 2, "to": 2, "pressure": float(pressures[1][0])},
                    {"name": "c2", "cavity": 1, "from": 3, "to": 3, "pressure": float(pressures[2][1])}],
        "load": [{"vertebra": -1, "force": list(map(float, force)), "moment": list(map(float, moment))}],
    }


def test_runtime_solver_linearised_equals_full_fe_model(chain):
    fes, entries, full = chain
    scene = solver.parse_scene(_scene(entries, TIP_WRENCH[:3], TIP_WRENCH[3:], PRESSURES))
    model = solver.build_model(scene, entries={e.name: e for e in entries})
    # tangent at the unstressed rest pose (zero actuation: a pressure would pre-stress the links
    # and add geometric stiffness, which the linear FE model does not have)
    pressures = model.default_actuation
    lin = model.linearise(model.rest_state, np.zeros_like(pressures))
    rhs = lin.residual + lin.actuator_forces @ pressures     # dead tip load + chamber pressures
    dq = lin.solve(rhs).reshape(-1, 6)                       # linear response at the rest pose
    frames = dq[model.vertebra_frames[1:] - 1]
    assert _relative(frames[-1, :3], full["frames"][-1, :3]) < TOLERANCE
    assert _relative(frames, full["frames"]) < TOLERANCE
    # chamber volume growth (linear in the pose and the pressures at rest)
    growth = model.actuator_displacements(model.rest_state, pressures) + lin.actuator_jacobian @ dq.reshape(-1)
    expected = [full["volume_growth"][1][0], full["volume_growth"][2][1]]
    assert _relative(growth, expected) < TOLERANCE


def test_runtime_solver_newton_with_small_load_equals_full_fe_model(chain):
    fes, entries, full = chain
    # scale the load so that rotations are ~1e-8 rad: geometric nonlinearity (relative ~ rotation)
    # is then far below the 1e-6 tolerance; the FE reference scales linearly
    scale = 1e-8 / np.abs(full["frames"][:, 3:]).max()
    pressures = [p * scale for p in PRESSURES]
    scene = solver.parse_scene(_scene(entries, scale * TIP_WRENCH[:3], scale * TIP_WRENCH[3:], pressures))
    model = solver.build_model(scene, entries={e.name: e for e in entries})
    result = model.solve()
    assert result.converged
    tip = model.vertebra_frames[-1]
    displacement = result.state.positions[tip] - model.rest_state.positions[tip]
    assert _relative(displacement, scale * full["frames"][-1, :3]) < TOLERANCE
