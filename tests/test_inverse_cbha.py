"""Pressure inverse on the designer's CBHA-like trunk (catalogue entries from FE).

Builds the coarse CBHA catalogue once (16 tapered pneumatic slices, gmsh + scikit-fem,
~8 s on this machine) and inverts forward solutions of the two-section, six-chamber trunk.
"""

from __future__ import annotations

import numpy as np
import pytest

from vertebra import solver
from vertebra.designer.gallery import cbha_catalogue
from vertebra.solver.inverse import invert

pytestmark = pytest.mark.slow      # the module designs the 16 CBHA slices (gmsh + scikit-fem)


@pytest.fixture(scope="module")
def cbha_model(tmp_path_factory):
    path = tmp_path_factory.mktemp("cbha") / "cbha.h5"
    built = cbha_catalogue(path, coarse=True, estimate_accuracy=False)
    return solver.build_model(solver.parse_scene(built["scene"], base_dir=str(path.parent)))


def test_cbha_inverse_of_a_forward_solution_reaches_the_target(cbha_model):
    # 6 chambers for a 3-D tip target: redundant, so the pressures found differ from the
    # ones that made the target (the energy regulariser picks the cheapest), but the tip
    # must reach it to the 1e-6 m requirement, pressures within [0, 1.5 bar].
    model = cbha_model
    known = np.zeros(len(model.actuator_names))
    known[0], known[4] = 0.8e5, 0.4e5
    target = model.effector_positions(model.solve(known).state)
    step = invert(model, target)
    assert step.reached and np.all(step.errors <= 1e-6)
    lo, hi = model.actuator_bounds
    assert np.all(step.actuation >= lo) and np.all(step.actuation <= hi)
    # energy: the regularised answer needs no more actuation energy than the known one
    # (Σ |W_aa,ii| pᵢ², evaluated with the same linearisation at the target state)
    lin = model.linearise(step.state, step.actuation)
    d = np.abs(np.diag(lin.actuator_jacobian @ lin.solve(lin.actuator_forces)))
    assert d @ step.actuation**2 <= d @ known**2


def test_cbha_unreachable_target_saturates_within_bounds(cbha_model):
    # 5 cm beside a reachable tip position: closest reach, some chamber at a bound.
    model = cbha_model
    known = np.zeros(len(model.actuator_names))
    known[0] = 1.0e5
    target = model.effector_positions(model.solve(known).state) + np.array([0.0, 0.05, 0.0])
    step = invert(model, target)
    assert not step.reached and step.status == "closest_reach"
    lo, hi = model.actuator_bounds
    assert np.all(step.actuation >= lo) and np.all(step.actuation <= hi)
    active = step.qp.diagnostics()
    assert active.active_lower.any() or active.active_upper.any()
