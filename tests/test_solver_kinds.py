"""Link kinds (vertebra.solver.kinds): the registry picks the kind that makes each segment, every
energy class honours the interface the runtime relies on (w = ∂ψ/∂ξ, the material tangent
∂²ψ/∂ξ², the chamber forces −∂²ψ/∂ξ∂p, the volume growth −∂ψ/∂p), and a trunk whose links fall
into several energy batches solves and linearises like the same trunk in one batch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fitted_energies import with_energy
from test_solver_actuation import synthetic_entry
from vertebra import solver
from vertebra.solver import kinds
from vertebra.solver.kinds.quadratic import QuadraticEnergy, QuadraticKind
from vertebra.core.lie import qexp
from vertebra.store import SegmentEntry
from vertebra.core.errors import SceneError


def _mixed_scene(fitted=False):
    """Pneumatic slices with a tilted rest pose (``fitted``: straight slices with a fitted energy),
    then beams; two chambers, a cable, gravity."""
    slice_ = synthetic_entry()
    if fitted:
        first = with_energy(slice_, strength=0.3)
    else:
        first = SegmentEntry(key="k-tilt", name="tilt", family="synthetic", parameters={},
                             compliance=slice_.compliance, cavity_volumes=np.full(2, 1e-6), mass=0.01,
                             center_of_mass=[0.001, 0.0, 0.015], rest_translation=[0.002, 0.0, 0.03],
                             rest_quaternion=qexp(np.array([0.0, 0.1, 0.02])))
    data = {"catalogue": {"path": "never-opened.h5"},
            "segment": [{"type": "entry", "entry": first.name, "count": 3, "vertebra": {"mass": 0.01}},
                        {"type": "beam", "count": 2, "length": 0.03, "elements": 2, "youngs_modulus": 1e7,
                         "poisson_ratio": 0.4, "section": {"shape": "circle", "radius": 0.005}, "density": 1000.0}],
            "chamber": [{"name": "c0", "cavity": 0, "from": 1, "to": 3, "pressure": 2e4, "max_pressure": 1e5},
                        {"name": "c1", "cavity": 1, "from": 2, "to": 3, "pressure": 5e3, "max_pressure": 1e5}],
            "cable": [{"name": "t", "radius": 0.01, "angle_deg": 10.0, "from": 1, "to": 5, "tension": 0.2}],
            "gravity": {"vector": [0.0, -9.81, 0.0]},
            "effector": [{"name": "tip", "vertebra": -1}]}
    return solver.parse_scene(data), {first.name: first}


class SplitEnergy(QuadraticEnergy):
    """The same energy as a class of its own: its links form a batch of their own."""


class SplitKind(QuadraticKind):
    energy = SplitEnergy


def _split_kind():
    """Catalogue entries made by a kind of higher priority with an energy class of its own."""
    return SplitKind("split-entry", "entry", kinds.kinds()["linear-entry"].link, priority=1)


def test_the_highest_priority_kind_claiming_a_segment_makes_it(monkeypatch):
    scene, entries = _mixed_scene()
    assert kinds.kind_for(scene.segments[0], entries["tilt"]).name == "linear-entry"
    assert kinds.kind_for(scene.segments[1], None).name == "beam"
    monkeypatch.setitem(kinds.kinds(), "split-entry", _split_kind())
    assert kinds.kind_for(scene.segments[0], entries["tilt"]).name == "split-entry"
    with pytest.raises(SceneError, match="no link kind"):
        kinds.kind_for(dataclasses.replace(scene.segments[1], type="unknown"), None)


def test_several_energy_batches_give_the_single_batch_results(monkeypatch):
    scene, entries = _mixed_scene()
    one = solver.build_model(scene, entries)
    assert len(one.trunk.links.energies) == 1
    monkeypatch.setitem(kinds.kinds(), "split-entry", _split_kind())
    two = solver.build_model(scene, entries)
    energies = two.trunk.links.energies
    assert [type(e) for e in energies] == [SplitEnergy, QuadraticEnergy]
    assert [e.links.tolist() for e in energies] == [[0, 1, 2], [3, 4, 5, 6]]
    # the same arithmetic per link, gathered and scattered: equal to rounding (measured bitwise)
    a, b = one.solve(), two.solve()
    assert (a.iterations, a.converged) == (b.iterations, b.converged)
    assert np.abs(a.state.positions - b.state.positions).max() <= 1e-15 * one.length_scale
    actuation = one.default_actuation
    lin_a, lin_b = one.linearise(a.state, actuation), two.linearise(a.state, actuation)
    for name in ("residual", "actuator_forces", "actuator_jacobian", "actuator_displacements"):
        x, y = getattr(lin_a, name), getattr(lin_b, name)
        assert np.abs(x - y).max() <= 1e-14 * np.abs(x).max(), name
    ev_a, ev_b = one.evaluate(a.state), two.evaluate(a.state)
    assert ev_a.energy == pytest.approx(ev_b.energy, rel=1e-14)
    rhs = np.random.default_rng(3).normal(size=one.n_dof)
    assert np.abs(lin_a.solve(rhs) - lin_b.solve(rhs)).max() <= 1e-12 * np.abs(lin_a.solve(rhs)).max()


@pytest.mark.parametrize("name", ["beam", "linear-entry", "nonlinear-entry"])
def test_energy_interface_is_consistent_with_its_energy(name):
    # w, the material tangent, the chamber forces and the volume growth are the derivatives of
    # the energy the batch reports: central differences (h relative 1e-6 of the strain and 1e-3 of
    # the pressure) resolve them to ~1e-9 relative (the fitted quartic's truncation error at these
    # steps is below that: measured ≤ 2e-9); the quadratic energy is exact to rounding in its
    # second derivatives, so 1e-7 catches any inconsistency
    scene, entries = _mixed_scene(fitted=name == "nonlinear-entry")
    model = solver.build_model(scene, entries)
    kind_of_segment = np.array([kinds.kind_for(segment, entries.get(segment.entry)).name for segment in scene.segments])
    links = np.flatnonzero(kind_of_segment[_segment_of_links(scene)] == name)
    energy = next(e for e in model.trunk.links.energies if np.isin(links, e.links).all())
    chosen = np.flatnonzero(np.isin(energy.links, links))
    rng = np.random.default_rng(11)
    xi = energy.rest + 0.05 * rng.normal(size=energy.rest.shape)
    p = np.array([3e4, 1e4])
    energy_of = lambda xi_, p_: energy.response(xi_, energy.prepare(p_))[0]    # noqa: E731
    _, w, kept = energy.response(xi, energy.prepare(p))
    h = 1e-6
    for k in chosen[:2]:
        for i in range(6):
            d = np.zeros_like(xi)
            d[k, i] = h
            numeric = (energy_of(xi + d, p) - energy_of(xi - d, p)) / (2 * h)
            assert numeric == pytest.approx(w[k, i], rel=1e-6, abs=1e-7 * np.abs(w[k]).max())
            w_plus = energy.response(xi + d, energy.prepare(p))[1][k]
            w_minus = energy.response(xi - d, energy.prepare(p))[1][k]
            column = energy.material_tangent(xi, energy.prepare(p), kept)[k][:, i]
            assert np.abs((w_plus - w_minus) / (2 * h) - column).max() <= 1e-7 * np.abs(column).max()
    forces = energy.chamber_forces(xi, energy.prepare(p), kept)
    growth = energy.volume_growth(xi, energy.prepare(p), p)
    for j in range(2):
        dp = np.zeros(2)
        dp[j] = 1e-3 * p[j]
        numeric = -(energy_of(xi, p + dp) - energy_of(xi, p - dp)) / (2 * dp[j])
        assert numeric == pytest.approx(growth[j], rel=1e-7)
        dw = (energy.response(xi, energy.prepare(p + dp))[1] - energy.response(xi, energy.prepare(p - dp))[1]) / (2 * dp[j])
        assert np.abs(-dw - forces[:, j]).max() <= 1e-7 * np.abs(forces).max()


def _segment_of_links(scene):
    return np.concatenate([np.full(s.count * s.elements, i) for i, s in enumerate(scene.segments)])
