"""The batched forward solve (vertebra.solver.batch, ``model.solve_batch``) and its factor.

Checked here: the batch's band factors against scipy's banded solver (and which matrices they
refuse against LAPACK's ``dpbtrf``), the batch's bands against the single solve's; every sample of a batch against the single
solve of the same actuation and start — the same convergence, iterations, factor kinds and
equilibrium to 1e-10 of the trunk's length — on beams with gravity and a dead force, cables
(some slack), stroke-driven tendons, linear entries with chambers, nonlinear (fitted) entries
with chambers, load stages, warm starts, chunks, and samples that fail (reported per sample
with the single solve's message).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solveh_banded
from scipy.linalg.lapack import dpbtrf

from fitted_energies import with_energy
from test_solver_actuation import synthetic_entry
from test_tendons import _with_tendons
from vertebra import solver
from vertebra.solver import potential
from vertebra.solver.banded import factor_cholesky_batch
from vertebra.solver.scene import load_scene


def _band_matrices(rng, B, n, kd, refuse=()):
    dense = np.zeros((B, n, n))
    for b in range(B):
        M = rng.standard_normal((n, n))
        M[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > kd] = 0.0
        A = 0.5 * (M + M.T)
        A += np.eye(n) * (-1.0 if b in refuse else np.abs(A).sum(1).max() + 1.0)
        dense[b] = A
    return dense


def _lapack_band(A, kd):
    n = A.shape[0]
    ab = np.zeros((kd + 1, n))
    for d in range(kd + 1):
        ab[d, :n - d] = np.diagonal(A, -d)
    return ab


@pytest.mark.parametrize("n, kd", [(6, 5), (42, 11), (54, 17), (30, 29)])
def test_batched_band_cholesky_solves_as_scipys_banded_solver_and_refuses_what_dpbtrf_refuses(n, kd):
    rng = np.random.default_rng(n + 10 * kd)
    dense = _band_matrices(rng, 6, n, kd, refuse=(2,))
    bands = np.stack([np.ascontiguousarray(_lapack_band(A, kd).T) for A in dense])
    factor = factor_cholesky_batch(bands.copy())
    refused = [dpbtrf(_lapack_band(A, kd), lower=1)[1] != 0 for A in dense]
    assert factor.ok.tolist() == [not r for r in refused]
    rhs = rng.standard_normal((6, n, 3))
    x, single = factor.solve(rhs), factor.solve(rhs[:, :, 0])
    for b in np.flatnonzero(factor.ok):
        reference = solveh_banded(_lapack_band(dense[b], kd), rhs[b], lower=True)
        assert np.abs(x[b] - reference).max() <= 1e-12 * np.abs(reference).max()
        assert np.abs(single[b] - reference[:, 0]).max() <= 1e-12 * np.abs(reference).max()


def test_the_batchs_symmetric_bands_are_the_single_solves_band():
    """The bands assembled from a batch's terms (links, cable pairs, weight) are the single
    solve's lower band of the same tangent (to rounding: the sums are taken in another order)."""
    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    trunk = model.trunk
    rng = np.random.default_rng(5)
    actuations = rng.uniform(0.0, 20.0, (3, model.n_cables))
    result = model.solve_batch(actuations)
    from vertebra.solver import batch as batch_module
    context = batch_module._Context(trunk)
    states, _ = batch_module.compose(trunk, result.strains)
    ev = batch_module.evaluate(context, states, batch_module.Loads.of(trunk, actuations, np.ones(3)))
    bands = batch_module.tangent(context, ev).bands
    for i in range(3):
        single = potential.tangent(trunk, model.evaluate(result.state(i), actuations[i])).symmetric_band()
        assert np.abs(bands[i].T - single).max() <= 1e-12 * np.abs(single).max()


def _compare(model, actuations, initial=None, **options):
    """Solve in a batch and one by one; every sample must agree."""
    batch = model.solve_batch(actuations, initial, **options)
    length = model.length_scale
    starts = [None] * len(actuations) if initial is None else list(initial)
    for i, actuation in enumerate(actuations):
        single = model.solve(actuation, starts[i], raise_on_failure=False,
                             **{k: v for k, v in options.items() if k != "chunk"})
        assert batch.converged[i] == single.converged, (i, single.message)
        assert batch.iterations[i] == single.iterations, i
        assert batch.load_steps[i] == single.load_steps, i
        assert batch.factorization[i] == single.factorization, i
        if single.converged:
            assert np.abs(batch.positions[i] - single.state.positions).max() <= 1e-10 * length, i
            assert np.abs(batch.quaternions[i] - single.state.quaternions).max() <= 1e-10, i
            # (a converged residual far below the tolerance is the rounding of the forces)
            floor = 1e-3 * options.get("tolerance", model.scene.solver.tolerance)
            assert abs(batch.residual[i] - single.residual) <= 1e-3 * single.residual + floor, i
            assert batch.result(i).out_of_range == single.out_of_range
            assert batch.bound_violations[i] == single.bound_violations
            assert np.allclose(model.effector_positions(batch.state(i)), model.effector_positions(single.state),
                               rtol=0, atol=1e-10 * length)
        else:
            assert batch.messages[i] == single.message
    return batch


def test_the_16_tendon_robot_in_a_batch_is_the_single_solve_sample_by_sample():
    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    rng = np.random.default_rng(3)
    actuations = rng.uniform(0.0, 20.0, (24, model.n_cables))
    actuations[0] = 0.0                           # every cable slack: gravity only
    actuations[1, ::2] = 0.0                      # half of them slack
    batch = _compare(model, actuations)
    assert batch.converged.all() and not batch.single.any()
    assert "shifted" in "".join(batch.factorization)        # the shifted path is exercised too


def test_chunks_warm_starts_and_load_stages_give_the_single_solves_results():
    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    rng = np.random.default_rng(4)
    actuations = rng.uniform(0.0, 20.0, (9, model.n_cables))
    first = model.solve_batch(actuations, chunk=4)
    assert first.converged.all()
    # warm starts from a neighbouring sample's equilibrium (one missing: from rest)
    starts = [first.state(i - 1) if i else None for i in range(len(actuations))]
    moved = actuations + rng.uniform(-1.0, 1.0, actuations.shape).clip(-actuations, None)
    _compare(model, moved, starts, chunk=4)
    warm = model.solve_batch(moved, first.strains[np.r_[0, np.arange(len(moved) - 1)]])
    assert np.array_equal(warm.converged, np.ones(len(moved), bool))
    _compare(model, actuations[:5], load_steps=3)


def test_beams_with_gravity_and_a_dead_force():
    model = solver.build_model(load_scene("gallery:cantilever"))
    _compare(model, np.zeros((1, 0))) if not model.actuator_names else None
    scene = load_scene("gallery:tendon_two_section")
    model = solver.build_model(scene)
    rng = np.random.default_rng(5)
    lower, upper = (np.nan_to_num(b, posinf=5.0) for b in model.actuator_bounds)
    _compare(model, rng.uniform(lower, np.minimum(upper, 5.0), (6, len(model.actuator_names))))


CHAMBERS = ({"name": "c0", "cavity": 0, "from": 1, "to": 4, "pressure": 4e4, "max_pressure": 1.4e5},
            {"name": "c1", "cavity": 1, "from": 2, "to": 3, "pressure": 1.5e4, "max_pressure": 1.4e5})


def _entry_model(entry):
    data = {"catalogue": {"path": "never-opened.h5"}, "gravity": {"vector": [0.0, -9.81, 0.0]},
            "segment": [{"type": "entry", "entry": entry.name, "count": 4, "vertebra": {"mass": 0.005}}],
            "chamber": [dict(c) for c in CHAMBERS],
            "cable": [{"name": "t", "radius": 0.008, "angle_deg": 30.0, "to": 4, "tension": 0.0, "max_tension": 3.0}],
            "effector": [{"name": "tip", "vertebra": -1, "offset": [0.0, 0.004, 0.0]}]}
    return solver.build_model(solver.parse_scene(data), {entry.name: entry})


@pytest.mark.parametrize("fitted", [False, True])
def test_linear_and_fitted_entries_with_chambers_and_a_cable(fitted):
    entry = synthetic_entry()
    model = _entry_model(with_energy(entry, strength=0.3) if fitted else entry)
    assert [e.fitted for e in model.trunk.links.energies] == [fitted]
    rng = np.random.default_rng(6)
    actuations = np.column_stack([rng.uniform(0.0, 3.0, 8), rng.uniform(0.0, 1.2e5, (8, 2))])
    actuations[0] = 0.0
    actuations[1, 1:] = 0.0
    batch = _compare(model, actuations)
    assert batch.converged.all() and not batch.single.any()


def test_stroke_driven_tendons_slack_and_taut():
    model = solver.build_model(_with_tendons(load_scene("gallery:paper_5v_16t")))
    rng = np.random.default_rng(8)
    strokes = rng.uniform(-0.0005, 0.0005, (8, model.n_cables))
    strokes[0] = -0.002                           # every tendon slack
    batch = _compare(model, strokes)
    assert batch.converged.all() and not batch.single.any()
    tensions = [model.cable_tensions(batch.state(i), strokes[i]) for i in range(len(strokes))]
    assert not np.any(tensions[0]) and all(np.any(t == 0.0) and np.any(t > 0.0) for t in tensions[1:])


def test_a_sample_that_fails_fails_alone_with_the_single_solves_message():
    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    actuations = np.full((3, model.n_cables), 2.0)
    actuations[1, :4] = 5e4                       # far beyond what the links can represent
    batch = _compare(model, actuations)
    assert batch.converged.tolist() == [True, False, True]
    assert batch.single.tolist() == [False, True, False]
    assert "turns" in batch.messages[1] or "cable" in batch.messages[1]


def test_cable_friction_is_solved_by_the_single_solve_sample_by_sample():
    model = solver.build_model(load_scene("gallery:paper_3v_4t"))
    model.set_parameters(friction={name: 0.2 for name in model.actuator_names})
    rng = np.random.default_rng(9)
    batch = _compare(model, rng.uniform(0.0, 3.0, (3, model.n_cables)))
    assert batch.single.all() and batch.converged.all() and "friction" in batch.why[0]
    assert batch.result(0).friction is not None


def test_contacts_are_solved_by_the_single_solve_sample_by_sample():
    from test_contact import disc_trunk

    model = disc_trunk(2.0)
    assert model.trunk.contact is not None
    actuations = np.array([model.actuation() * f for f in (0.5, 1.0)])
    batch = _compare(model, actuations)
    assert batch.single.all() and "contacts" in batch.why[0]


def test_actuation_sensitivities_of_a_batch_are_the_single_sensitivities():
    from vertebra.solver.batch import actuation_sensitivities

    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    rng = np.random.default_rng(12)
    actuations = rng.uniform(0.0, 20.0, (4, model.n_cables))
    batch = model.solve_batch(actuations)
    found = actuation_sensitivities(model, batch)
    assert found["has"].all()
    for i in range(len(actuations)):
        single = model.sensitivities(batch.result(i), actuations[i], wrt=("actuation",),
                                     outputs=("effector_positions",), method="direct")
        scale = np.abs(single.dq).max()
        assert np.abs(found["dq"][i] - single.dq).max() <= 1e-8 * scale
        reference = single["effector_positions"]
        assert np.abs(found["effector_positions"][i] - reference).max() <= 1e-8 * np.abs(reference).max()


def test_a_capped_step_limit_skips_only_the_cable_pieces_that_cannot_halve_within_the_cap():
    # the cable pieces' half-length limit is left out only where it cannot be below the cap: the
    # capped limits agree with the full ones wherever either is below the cap, for steps from tiny
    # to ones that fold pieces
    from vertebra.solver import batch

    model = solver.build_model(load_scene("gallery:paper_5v_16t"))
    trunk = model.trunk
    rng = np.random.default_rng(3)
    B = 60
    actuations = rng.uniform(0.0, 20.0, (B, model.n_cables))
    states, _ = batch.compose(trunk, np.broadcast_to(trunk.rest_state.strains.xi, (B, trunk.links.count, 6)).copy())
    context = batch._Context(trunk)
    ev = batch.evaluate(context, states, batch.Loads.of(trunk, actuations, np.ones(B)))
    run = batch._Run(context, actuations)
    rows = np.arange(B)
    size = 10.0 ** rng.uniform(-9.0, -1.0, B)             # frame increments from 1 nm to 10 cm (rad)
    dq = rng.normal(size=(B, trunk.n_dof)) * size[:, None]
    change = np.zeros((B, trunk.links.count, 6))          # (no strain caps: the pieces' limit alone)
    full = run.step_limit(rows, dq, change, ev.pieces)
    capped = run.step_limit(rows, dq, change, ev.pieces, cap=1.0)
    assert np.array_equal(np.minimum(1.0, full), np.minimum(1.0, capped))
    assert np.any(full < 1.0) and np.any(full >= 1.0)     # both kinds of steps were tried


def test_kept_heap_pads_the_c_heap_while_the_outermost_batch_runs(monkeypatch):
    # glibc keeps MEMORY_BUDGET of freed heap at its top from the outermost batch's start to its
    # end (nested batches and an error inside leave it as it is, then restore the default once)
    from vertebra.solver import batch as batch_module

    calls = []
    monkeypatch.setattr(batch_module, "_MALLOPT", lambda parameter, value: calls.append((parameter, value)) or 1)
    with batch_module.kept_heap():
        with batch_module.kept_heap():
            assert calls == [(-2, batch_module.MEMORY_BUDGET)]
        assert calls == [(-2, batch_module.MEMORY_BUDGET)]
    assert calls == [(-2, batch_module.MEMORY_BUDGET), (-2, 128 * 1024)]
    calls.clear()
    with pytest.raises(RuntimeError):
        with batch_module.kept_heap():
            raise RuntimeError("inside")
    assert calls == [(-2, batch_module.MEMORY_BUDGET), (-2, 128 * 1024)] and batch_module._heap_users == 0
    monkeypatch.setattr(batch_module, "_MALLOPT", None)         # no mallopt (not glibc): nothing to do
    with batch_module.kept_heap():
        pass
    assert batch_module._heap_users == 0
