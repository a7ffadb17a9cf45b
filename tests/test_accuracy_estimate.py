"""The accuracy estimate stored with a designed entry: Richardson extrapolation from a coarser mesh
(second order), the second-order compliance on the same mesh (first order).

The full validation (every family, orders 1 and 2, ν up to 0.49, against references three times
finer) is benchmarks/bench_accuracy.py; here the mechanism on coarse cases.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vertebra.designer.accuracy import estimated_error, relative_error, richardson
from vertebra.designer.linear import LockingWarning, solve_segment
from vertebra.designer.segment import design_segment

ROD = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
PNEUMATIC = {"outer_radius": 0.02, "chamber_radius": 0.005, "chamber_offset": 0.011, "length": 0.02,
             "youngs_modulus": 1e6, "poisson_ratio": 0.49}


def test_richardson_recovers_a_power_law_exactly():
    """C(h) = C∞ + A h^p: one coarser value and p give C∞ to round-off."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(7, 7))
    C_inf, A = a @ a.T + 7 * np.eye(7), np.diag(rng.random(7))
    h, r, p = 0.01, 1.4, 2.0
    C_h, C_rh = C_inf - A * h ** p, C_inf - A * (r * h) ** p
    np.testing.assert_allclose(richardson(C_h, C_rh, r, p), C_inf, rtol=0, atol=1e-12)


def test_relative_error_is_unit_free():
    """Rescaling the loads (D C D, any positive diagonal D: other units) leaves it unchanged."""
    rng = np.random.default_rng(4)
    a = rng.normal(size=(6, 6))
    C = a @ a.T + 6 * np.eye(6)
    other = C + 0.01 * np.diag(rng.random(6))
    D = np.diag(10.0 ** rng.uniform(-6, 6, size=6))
    assert relative_error(D @ C @ D, D @ other @ D) == pytest.approx(relative_error(C, other), rel=1e-9)


@pytest.mark.slow
def test_estimate_on_a_coarse_rod_against_a_finer_mesh():
    """Second-order rod at its default mesh (3.7k DoFs): the estimate costs a coarser solve
    (fewer DoFs than the design), the extrapolated compliance is closer to a 2× finer mesh than
    the stored one, and the estimate is within a factor 2 of the error measured against that
    finer mesh (whose own error, ~1/4 of the design's for p = 2, makes the measured error at most
    ~25 % low; benchmarks/bench_accuracy.py measured 1.3 against h/3 for this case)."""
    entry = design_segment("rod", ROD, order=2)
    acc = entry.accuracy
    assert acc["method"] == "richardson" and acc["convergence_order"] == 2.0
    assert acc["coarse_dofs"] < entry.mesh["dofs"] and acc["size_ratio"] > 1.08
    assert acc["basis"].startswith("Richardson")
    assert entry.timings["accuracy_s"] > 0 and estimated_error(acc) == acc["relative_error"]
    fine, *_ = solve_segment("rod", ROD, mesh_size=entry.mesh["mesh_size"] / 2, order=2)
    measured = relative_error(entry.compliance, fine)
    extrapolated = np.array(acc["extrapolated_compliance"])
    assert relative_error(fine, extrapolated) < relative_error(fine, entry.compliance)
    assert 0.5 < acc["relative_error"] / measured < 2.0, (acc["relative_error"], measured)


@pytest.mark.slow
def test_first_order_estimate_sees_locking():
    """First-order chambered segment at ν = 0.49 on a coarse mesh (10 mm, 672 DoFs): linear
    tetrahedra lock, the compliance is more than ten times too small (true error ~12). The estimate
    is the second-order compliance on the same mesh; it is within a factor 2 of the error against a
    second-order mesh twice finer (whose own error, ~0.1, is under 1 % of the one measured). A
    coarser first-order mesh, as locked as the design's, saw a quarter of the error
    (benchmarks/bench_accuracy.py)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LockingWarning)
        entry = design_segment("pneumatic", PNEUMATIC, mesh_size=0.01, order=1)
    acc = entry.accuracy
    assert acc["method"] == "order-raising" and acc["raised_order"] == 2 and acc["same_mesh"]
    assert acc["raised_dofs"] > entry.mesh["dofs"] and any("lock" in w for w in acc["warnings"])
    reference, *_ = solve_segment("pneumatic", PNEUMATIC, mesh_size=0.005, order=2)
    measured = relative_error(entry.compliance, reference)
    assert measured > 3.0, measured                       # the case is deep in locking
    assert 0.5 < acc["relative_error"] / measured < 2.0, (acc["relative_error"], measured)
    # relative to the reference the first-order compliance is 0.92 off (it is 13× too stiff), the
    # second-order one on the same mesh 0.12
    better = np.array(acc["extrapolated_compliance"])
    assert relative_error(reference, better) < 0.25 * relative_error(reference, entry.compliance)


def test_older_entries_keep_their_refined_mesh_estimate():
    older = {"method": "refined mesh h/1.5", "relative_change": 0.012, "warnings": []}
    assert estimated_error(older) == 0.012 and estimated_error({"method": "none"}) is None


@pytest.mark.slow
@pytest.mark.parametrize("order", [1, 2])
def test_an_estimate_started_alongside_the_design_is_the_same_estimate(order):
    # ``estimate_alongside`` only moves the estimate's first solve to a worker process that runs
    # while the design solves its own mesh: the same meshes, the same solves, the same numbers
    serial = design_segment("rod", ROD, order=order).accuracy
    alongside = design_segment("rod", ROD, order=order, estimate_alongside=True).accuracy
    assert alongside["method"] == serial["method"] == ("order-raising" if order == 1 else "richardson")
    assert alongside["basis"] == serial["basis"]
    assert np.array_equal(alongside["extrapolated_compliance"], serial["extrapolated_compliance"])
    assert alongside["relative_error"] == serial["relative_error"]
