"""Cables, chambers (catalogue-style entries with cavities) and the linearisation used by
the inverse model: every Jacobian against finite differences, pressure physics against the
segment's own compliance (DESIGN §2)."""

import numpy as np
import pytest

from vertebra import solver
from vertebra.store import SegmentEntry
from vertebra.core.errors import SceneError

RNG = np.random.default_rng(7)


def synthetic_entry(n_cavities=2, length=0.03, name="slice"):
    """A plausible SPD (6+n)×(6+n) compliance: a soft rod-like C plus cavity coupling."""
    C = np.diag([2e-4, 2e-4, 2e-5, 0.3, 0.3, 0.5])
    C[0, 4] = C[4, 0] = 5e-3
    C[1, 3] = C[3, 1] = -5e-3
    angles = 2 * np.pi * np.arange(n_cavities) / n_cavities
    G = np.zeros((6, n_cavities))
    G[2] = 4e-9                                  # extension per Pa
    G[3] = -2e-7 * np.sin(angles)                # bending away from the inflated cavity
    G[4] = 2e-7 * np.cos(angles)
    V = 1e-13 * (np.eye(n_cavities) + 0.1)
    full = np.block([[C, G], [G.T, V + G.T @ np.linalg.solve(C, G)]])   # keeps the Schur complement SPD
    return SegmentEntry(key=f"k-{name}", name=name, family="synthetic", parameters={},
                        compliance=full, cavity_volumes=np.full(n_cavities, 1e-6), mass=0.01,
                        center_of_mass=[0.0, 0.0, length / 2], rest_translation=[0.0, 0.0, length])


def pneumatic_model(count=3, pressures=(0.0, 0.0), extra=None, entry=None):
    entry = entry or synthetic_entry()
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": entry.name, "count": count, "vertebra": {"mass": 0.0}}],
            "chamber": [{"name": f"c{k}", "cavity": k, "from": 1, "to": count, "pressure": p,
                         "max_pressure": 2e5} for k, p in enumerate(pressures)],
            "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.01, 0.0]}]}
    data.update(extra or {})
    return solver.build_model(solver.parse_scene(data), entries={entry.name: entry}), entry


def test_pressure_shifts_the_rest_pose_by_G_p():
    # one free segment: linear response to a small pressure is exactly G p, volume growth V p
    model, entry = pneumatic_model(count=1, pressures=(10.0, 0.0))
    result = model.solve()
    lin = model.linearise(model.rest_state, np.zeros(2))
    response = lin.solve(lin.actuator_forces @ np.array([10.0, 0.0]))
    assert np.allclose(response, entry.G[:, 0] * 10.0, rtol=1e-10, atol=1e-20)
    assert np.allclose(model.chamber_volume_growth(result.state, np.array([10.0, 0.0])), entry.V[:, 0] * 10.0,
                       rtol=1e-6)


def test_reciprocity_volume_growth_under_a_wrench_is_G_transpose():
    # ΔV = Gᵀ w + V p at the runtime level (DESIGN §2, Maxwell–Betti)
    entry = synthetic_entry()
    wrench = np.array([1e-3, -2e-3, 5e-3, 1e-5, 2e-5, -1e-5])
    model, _ = pneumatic_model(count=1, entry=entry, extra={
        "load": [{"vertebra": 1, "force": list(wrench[:3]), "moment": list(wrench[3:])}]})
    state = model.solve().state
    growth = model.chamber_volume_growth(state, np.zeros(2))
    assert np.allclose(growth, entry.G.T @ wrench, rtol=1e-4, atol=1e-6 * np.abs(entry.G.T @ wrench).max())


def test_chamber_spanning_segments_bends_the_section():
    model, _ = pneumatic_model(count=4, pressures=(5e4, 0.0))
    result = model.solve()
    tip = result.state.positions[-1]
    assert result.converged and tip[2] > 4 * 0.03      # extension
    assert abs(tip[0]) > 1e-4                          # bending away from cavity 0


def _perturbed_residual(model, state, actuation, direction, h):
    plus = model.linearise(model.step(state, h * direction), actuation).residual
    minus = model.linearise(model.step(state, -h * direction), actuation).residual
    return (plus - minus) / (2 * h)


@pytest.mark.parametrize("kind", ["cables", "chambers"])
def test_linearisation_jacobians_match_finite_differences(kind):
    # B = ∂r/∂λ, Ja = ∂(actuator displacement)/∂q, Je = ∂(effector)/∂q and K = −∂r/∂q at a
    # deformed, loaded state; central differences (h ~ 1e-6 of the scale) agree to ~1e-6
    if kind == "cables":
        data = {"segment": [{"type": "beam", "count": 4, "elements": 2, "length": 0.03, "youngs_modulus": 5e9,
                             "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 1e-3}}],
                "cable": [{"name": "a", "radius": 0.01, "angle_deg": 0.0, "from": 1, "to": 4, "tension": 3.0},
                          {"name": "b", "radius": 0.01, "angle_deg": 100.0, "from": 2, "to": 3, "tension": 1.0}],
                "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.005, 0.0]},
                             {"name": "axis", "vertebra": 2, "axis": [0.3, 0.0, 1.0]}],
                "gravity": {"vector": [0.0, 0.0, -9.81]}}
        model = solver.build_model(solver.parse_scene(data))
        actuation = np.array([3.0, 1.0])
    else:
        model, _ = pneumatic_model(count=3, pressures=(4e4, 1e4))
        actuation = np.array([4e4, 1e4])
    state = model.solve(actuation).state
    lin = model.linearise(state, actuation)
    # B by differences in λ
    for j in range(actuation.size):
        d = np.zeros_like(actuation)
        h = 1e-6 * max(1.0, abs(actuation[j]))
        d[j] = h
        numeric = (model.linearise(state, actuation + d).residual - model.linearise(state, actuation - d).residual) / (2 * h)
        assert np.abs(numeric - lin.actuator_forces[:, j]).max() <= 1e-6 * np.abs(lin.actuator_forces[:, j]).max()
    # Ja, Je and K along random directions
    for _ in range(3):
        direction = RNG.normal(size=model.n_dof)
        direction[3::6] *= 10      # rotations O(1), translations O(0.1) of the segment scale
        h = 1e-7
        a_plus = model.actuator_displacements(model.step(state, h * direction), actuation)
        a_minus = model.actuator_displacements(model.step(state, -h * direction), actuation)
        expected = lin.actuator_jacobian @ direction
        assert np.abs((a_plus - a_minus) / (2 * h) - expected).max() <= 1e-6 * np.abs(expected).max()
        e_plus = model.effector_positions(model.step(state, h * direction)).reshape(-1)
        e_minus = model.effector_positions(model.step(state, -h * direction)).reshape(-1)
        expected = lin.effector_jacobian @ direction
        assert np.abs((e_plus - e_minus) / (2 * h) - expected).max() <= 1e-6 * np.abs(expected).max()
        dr = _perturbed_residual(model, state, actuation, direction, h)
        recovered = lin.solve(-dr)
        assert np.abs(recovered - direction).max() <= 1e-5 * np.abs(direction).max()


def test_cable_pulls_are_symmetric_to_the_stroke_jacobian():
    # B = −Jaᵀ for cables (force −τ ∂L/∂q), B = Jaᵀ for chambers (reciprocity)
    model, _ = pneumatic_model(count=2, pressures=(1e4, 0.0), extra={
        "cable": [{"name": "t", "radius": 0.01, "angle_deg": 45.0, "from": 1, "to": 2, "tension": 0.5}]})
    lin = model.linearise(model.solve().state)
    assert np.allclose(lin.actuator_forces[:, 0], -lin.actuator_jacobian[0])
    assert np.allclose(lin.actuator_forces[:, 1:], lin.actuator_jacobian[1:].T)


def test_cables_spanning_several_links_widen_the_band():
    data = {"segment": [{"type": "beam", "count": 3, "elements": 4, "length": 0.03, "youngs_modulus": 5e9,
                         "poisson_ratio": 0.3, "section": {"shape": "circle", "radius": 1e-3}}],
            "cable": [{"name": "a", "radius": 0.01, "from": 1, "to": 3, "tension": 2.0}]}
    model = solver.build_model(solver.parse_scene(data))
    assert model.trunk.assembler.span == 4
    beam_only = solver.build_model(solver.parse_scene({"segment": data["segment"]}))
    assert beam_only.trunk.assembler.span == 1
    assert model.solve().converged


def test_chambers_next_to_entries_without_cavities():
    # a rod-like entry (no cavities) below pneumatic slices: chambers cover only the slices;
    # rest volumes add the covered cavities, and a chamber over the rod is an error naming it
    rod = SegmentEntry(key="k-rod", name="rod", family="synthetic", parameters={},
                       compliance=np.diag([2e-4, 2e-4, 2e-5, 0.3, 0.3, 0.5]), cavity_volumes=np.zeros(0),
                       mass=0.01, center_of_mass=[0, 0, 0.015], rest_translation=[0, 0, 0.03])
    slice_ = synthetic_entry()
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": "rod", "count": 2},
                        {"type": "entry", "entry": slice_.name, "count": 3}],
            "chamber": [{"name": "c0", "cavity": 0, "from": 3, "to": 5, "pressure": 2e4}]}
    model = solver.build_model(solver.parse_scene(data), entries={"rod": rod, slice_.name: slice_})
    assert np.isclose(model.chamber_rest_volumes[0], 3 * slice_.cavity_volumes[0])
    assert model.solve().converged
    data["chamber"][0]["from"] = 1
    with pytest.raises(SceneError, match="has 0 cavities"):
        solver.build_model(solver.parse_scene(data), entries={"rod": rod, slice_.name: slice_})
