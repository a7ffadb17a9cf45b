"""Predicted marker positions of servo-driven samples, and their derivatives.

A calibration sees the robot through one narrow interface, :class:`Predictor`:
``predict(values, samples, wrt)`` solves every sample's static equilibrium under the element
values (:class:`~vertebra.solver.calibration.fit_parameters.Values`) and returns the markers in the
measurement frame and, for the elements ``wrt``, their derivatives.

:class:`RuntimePredictor` builds it on the runtime: the mapped cables are the scene's
stroke-driven tendons (tension ``k·max(0, L − L0 + stroke + P/k)``), the element values are
run-time parameters of the model (:meth:`~vertebra.solver.model.TrunkModel.set_parameters`:
stiffness scale per segment, hole angles and radii, spring rates, pretensions; no
recompilation).

**Derivatives** are the model's exact sensitivities (:mod:`~vertebra.solver.sensitivity`): at
each converged state one factor of the tangent ``K`` and ``dq/dθ = −K⁻¹ ∂g/∂θ`` for every model
element at once (the direct route: its ``dq`` also serves the next warm start), the marker's
``dp = dx_f + dφ_f × (R r)`` of its frame on top. The measurement frame and the marker offsets
act after the solve and are differentiated in closed form.

**Backlash.** With a play in the transmission (the ``backlash`` elements) the strokes that reach
the tendons are the commands passed through :func:`~vertebra.solver.calibration.data.play`, the
samples taken as one time-ordered sequence (in the calling process, before the samples are split
into blocks); a stroke's derivative with respect to its play is ±1 or carried, so the markers'
derivative is the model's sensitivity to that actuator times it. A **lag** (the ``lag``
elements: the stroke relaxes towards what the play passes on with a time constant, between the
samples' times, :func:`~vertebra.solver.calibration.data.lag`) acts the same way: the strokes
and their derivatives by the time constants and the plays come from
:func:`~vertebra.solver.calibration.data.transmission`.

**Warm starts.** Each sample's solve starts from its own equilibrium of the previous call, moved
to first order by the change of the model elements since (``q + dq/dθ Δθ`` where the derivatives
were taken there, which leaves Newton a second-order residual); a sample never solved starts from
its predecessor in the file (the data are a sequence of nearby poses).

**Processes.** With ``workers > 1`` the samples are split into that many contiguous blocks,
each solved by a worker process holding its own compiled model and its blocks' equilibria
(BLAS pinned to one thread, the workers die with the calling process); only the element values
go out and the markers and derivatives come back.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vertebra.core.errors import ConvergenceError, OptionError
from vertebra.core.lie import qmatrix, so3_exp
from vertebra.core.processes import exit_with_parent, pinned_environment
from vertebra.solver.calibration.data import play, transmission
from vertebra.solver.calibration.tension_play import march, stroke_derivatives
from vertebra.solver.calibration.fit_parameters import Values
from vertebra.solver.batch import predicted_strains
from vertebra.solver.model import build_model
from vertebra.solver.state import compose
from vertebra.solver.sensitivity import batch_sensitivities, parameters_of

__all__ = ["Prediction", "Predictor", "RuntimePredictor", "default_workers"]

#: the elements that act through the model, and the sensitivity parameter group of each
MODEL_KINDS = {"stiffness": "stiffness_scale", "angle": "hole_angle", "radius": "hole_radius",
               "cable_stiffness": "cable_stiffness", "pretension": "pretension", "backlash": "actuation",
               "lag": "actuation", "stroke": "actuation"}
#: the elements that act through the strokes (:func:`~vertebra.solver.calibration.data.transmission`)
STROKE_KINDS = ("backlash", "lag")
#: the elements of a play that depends on the tension (:mod:`~vertebra.solver.calibration.tension_play`)
TENSION_KINDS = ("backlash_rate", "entry_friction")
#: strokes through a tension-dependent play are consistent when the last Newton pass moves none
#: by more than this share of the trunk's length, or when the passes stop contracting below
#: PLAY_RESOLUTION of it (the equilibria's tensions resolve the strokes to about 1e-9 m on the v4
#: robot: far below what a marker measures); at most this many passes
PLAY_TOLERANCE = 1e-9
PLAY_RESOLUTION = 1e-6
PLAY_PASSES = 30
#: the fewest samples per worker process worth starting one for (a process costs ~1 s to start)
SAMPLES_PER_WORKER = 256


def default_workers(n_samples: int) -> int:
    """Worker processes for ``n_samples``: one per available core, at most one per
    :data:`SAMPLES_PER_WORKER` samples (1: solve in the calling process)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, n_samples // SAMPLES_PER_WORKER))


@dataclass
class Prediction:
    markers: np.ndarray             # (n, n_markers, 3) m, measurement frame
    derivatives: np.ndarray | None  # (n, n_markers, 3, len(wrt))
    solve_s: float = 0.0
    derivative_s: float = 0.0
    iterations: int = 0             # Newton iterations of the solves
    tensions: np.ndarray | None = None             # (n, n_actuators) the driven tendons' tensions (when asked)
    tension_derivatives: np.ndarray | None = None  # (n, n_actuators, len(wrt))


class Predictor(Protocol):
    model: object

    def predict(self, values: Values, samples, wrt=()) -> Prediction: ...


class RuntimePredictor:
    """Servo-driven samples on the runtime's stroke-driven tendons (module docstring), in this
    process or in ``workers`` processes. Use as a context manager (or call :meth:`close`) to end
    the worker processes."""

    def __init__(self, scene, mapping, model=None, workers: int = 1):
        self.engine = _Engine(scene, mapping, model)
        self.model = self.engine.model
        if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
            raise OptionError(f"expected a positive integer, got {workers!r}", field="workers")
        self.workers = workers
        self._pool = None
        self._scene, self._mapping = scene, mapping
        self._tension_state: dict = {}   # the last strokes through a tension-dependent play, tensions, ∂T/∂s
        self.play_passes = 0             # Newton passes of the tension-dependent play (solves of every sample)

    # the engine's pieces, for predictors built on this one (calibration.sequence)
    rest_radius = property(lambda self: self.engine.rest_radius)

    def _set(self, values: Values) -> None:
        self.engine._set(values)

    def _actuation(self, command) -> np.ndarray:
        return self.engine._actuation(command)

    def _markers(self, state, offsets):
        return self.engine._markers(state, offsets)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def predict(self, values: Values, samples, wrt=()) -> Prediction:
        """Markers of every sample under ``values`` and, for the elements ``wrt``, their
        derivatives. A call with the values and samples of the previous call reuses its
        equilibria (a least-squares step asks for the residuals, then the Jacobian, at one point)."""
        wrt = tuple(wrt)
        if (values.backlash_rate.any() or values.entry_friction.any()
                or any(kind in TENSION_KINDS for kind, _ in wrt)):
            return self._predict_tension_play(values, samples, wrt)
        commands, slopes = samples.commands, None
        if values.backlash.any() or values.lag.any() or any(kind in STROKE_KINDS for kind, _ in wrt):
            driven = self.engine.driven
            if (values.lag.any() or any(kind == "lag" for kind, _ in wrt)) and samples.times is None:
                raise OptionError(f"{samples.source}: a lag needs each sample's time: name the time column in the "
                                  f"mapping's [data] table (time = \"COLUMN\", time_unit = \"s\")", field="--fit")
            commands, slopes = transmission(commands, samples.times, values.backlash[driven], values.lag[driven])
        return self._blocks(values, commands, samples, wrt, slopes)

    def _blocks(self, values, commands, samples, wrt, slopes=None, tensions=False) -> Prediction:
        """The engine's predictions of ``samples`` under the strokes ``commands``, in this process
        or split into contiguous blocks among the worker processes."""
        blocks = min(self.workers, len(samples))
        if blocks <= 1:
            return self.engine.predict(values, commands, samples.source, samples.rows, wrt, slopes, tensions)
        if self._pool is None:
            self._pool = _Pool(self.workers, self._scene, self._mapping)
        edges = np.linspace(0, len(samples), blocks + 1).round().astype(int)
        parts = self._pool.map("predict", [(values, commands[a:b], samples.source, samples.rows[a:b], wrt,
                                            None if slopes is None else {kind: d[a:b] for kind, d in slopes.items()},
                                            tensions)
                                           for a, b in zip(edges[:-1], edges[1:])])

        def joined(name):
            return None if getattr(parts[0], name) is None else np.concatenate([getattr(p, name) for p in parts])

        return Prediction(joined("markers"), joined("derivatives"), max(p.solve_s for p in parts),
                          max(p.derivative_s for p in parts), sum(p.iterations for p in parts), joined("tensions"),
                          joined("tension_derivatives"))

    def _predict_tension_play(self, values: Values, samples, wrt: tuple) -> Prediction:
        """Markers and derivatives through a play that grows with the tendon's tension
        (:mod:`~vertebra.solver.calibration.tension_play`): Newton over the sequence — every
        sample's equilibrium with its tensions' derivatives by the strokes, the rows marched with
        the tensions linearised — until no stroke moves by more than :data:`PLAY_TOLERANCE` of the
        trunk's length (or the passes stall below :data:`PLAY_RESOLUTION` of it); the derivatives
        by the strokes' recursion."""
        if values.lag.any() or any(kind == "lag" for kind, _ in wrt):
            raise OptionError("a play that depends on the tension (backlash_rate, entry_friction) and a lag "
                              "together are not supported: fit one of them", field="--fit")
        driven = self.engine.driven
        a = len(driven)
        b0, b1, hold = values.backlash[driven], values.backlash_rate[driven], values.entry_friction[driven]
        strokes_wrt = tuple(("stroke", int(c)) for c in driven)
        inner = tuple(e for e in wrt if e[0] not in ("backlash",) + TENSION_KINDS)
        tolerance = PLAY_TOLERANCE * float(self.model.length_scale)
        resolution = PLAY_RESOLUTION * float(self.model.length_scale)
        key = (samples.source, samples.rows.tobytes(), samples.commands.tobytes())
        at = tuple(getattr(values, f).tobytes() for f in ("stiffness", "angle", "radius", "cable_stiffness",
                                                          "pretension", "backlash", "backlash_rate",
                                                          "entry_friction"))
        known = self._tension_state.get(key)
        tension = gradient = None
        if known is None:           # (the plain play's strokes to start from)
            strokes = play(samples.commands, b0)[0]
        elif known[0] == at:        # (the same values: the strokes, tensions and ∂T/∂s of the last call)
            strokes, tension, gradient = known[1:4]
        else:                       # (other values: the last call's strokes moved to first order by their change)
            strokes = known[1]
            if known[4] is not None:
                elements, was, d_strokes = known[4]
                change = np.array([values.get(kind, index) for kind, index in elements]) - was
                strokes = strokes + d_strokes @ change
        solve_s = derivative_s = 0.0
        iterations = 0
        changes = []
        for _ in range(PLAY_PASSES):
            if gradient is not None:
                moved, status = march(samples.commands, b0, b1, tension, gradient, strokes, hold)
                changes.append(float(np.abs(moved - strokes).max()))
                stalled = len(changes) > 1 and changes[-1] > 0.5 * changes[-2]
                if changes[-1] <= tolerance or (stalled and changes[-1] <= resolution):
                    break           # (consistent, or at the resolution of the equilibria's tensions)
                if stalled:
                    # (not contracting: a tendon's tension has a kink where it goes slack, and Newton
                    # from the slack side sees no slope — half a step, then the slope of the taut side)
                    moved = strokes + 0.5 * (moved - strokes)
                strokes = moved
            found = self._blocks(values, strokes, samples, strokes_wrt, tensions=True)
            self.play_passes += 1
            solve_s, derivative_s = solve_s + found.solve_s, derivative_s + found.derivative_s
            iterations += found.iterations
            tension, gradient = found.tensions, found.tension_derivatives
        else:
            raise ConvergenceError(f"{samples.source}: the strokes through the tension-dependent play did not "
                                   f"converge in {PLAY_PASSES} passes (largest change of a stroke in each: "
                                   f"{', '.join(f'{c:.3g}' for c in changes)} m)", None)
        first_order = None if known is None else known[4]
        self._tension_state[key] = (at, strokes, tension, gradient, first_order)
        found = self._blocks(values, strokes, samples, inner + strokes_wrt if wrt else (), tensions=bool(wrt))
        derivatives = None
        if wrt:
            P = len(wrt)
            column = {e: j for j, e in enumerate(wrt)}
            d_b0, d_b1, d_hold = np.zeros((a, P)), np.zeros((a, P)), np.zeros((a, P))
            for i, c in enumerate(driven.tolist()):
                for kind, d in (("backlash", d_b0), ("backlash_rate", d_b1), ("entry_friction", d_hold)):
                    if (kind, c) in column:
                        d[i, column[(kind, c)]] = 1.0
            where = [column[e] for e in inner]
            m = len(inner)
            d_tension = np.zeros((len(samples), a, P))
            d_tension[..., where] = found.tension_derivatives[..., :m]
            d_strokes = stroke_derivatives(status, b1, found.tensions, found.tension_derivatives[..., m:],
                                           d_tension, d_b0, d_b1, d_hold)
            derivatives = np.zeros(found.markers.shape + (P,))
            derivatives[..., where] = found.derivatives[..., :m]
            derivatives += np.einsum("bmxa,bap->bmxp", found.derivatives[..., m:], d_strokes)
            moved_by = [j for j, (kind, _) in enumerate(wrt) if kind not in ("frame", "marker")]   # (the strokes')
            self._tension_state[key] = (at, strokes, tension, gradient,
                                        (tuple(wrt[j] for j in moved_by),
                                         np.array([values.get(*wrt[j]) for j in moved_by]), d_strokes[..., moved_by]))
            solve_s, derivative_s = solve_s + found.solve_s, derivative_s + found.derivative_s
        return Prediction(found.markers, derivatives, solve_s, derivative_s, iterations + found.iterations)


class _Engine:
    """The predictions of one process: a compiled model and the equilibria of its samples."""

    def __init__(self, scene, mapping, model=None):
        self.scene, self.mapping = scene, mapping
        self.model = model if model is not None else build_model(scene)
        cables = {c.name: i for i, c in enumerate(scene.cables)}
        missing = [a.cable for a in mapping.actuators if a.cable not in cables]
        if missing:
            raise OptionError(f"the mapping drives cable(s) {', '.join(missing)} that the scene {scene.source} "
                              f"does not have (it has {', '.join(cables) or 'none'})", field=mapping.source)
        self.driven = np.array([cables[a.cable] for a in mapping.actuators], dtype=int)
        stroke_driven = np.asarray(self.model.compiled.actuators.stroke_driven)
        tension = [a.cable for a, i in zip(mapping.actuators, self.driven) if not stroke_driven[i]]
        if tension:
            raise OptionError(f"cable(s) {', '.join(tension)} of the scene {scene.source} are driven by a tension; "
                              f"a mapped actuator column is a servo stroke (give the cable `stroke`, `stiffness` "
                              f"and `pretension`, docs/scenes.md)", field=mapping.source)
        self.rest_angle = np.array([c.angle for c in scene.cables], float)
        self.rest_radius = np.array([c.radius for c in scene.cables], float)
        n_vertebrae = len(self.model.vertebra_frames)
        frames = []
        for m in mapping.markers:
            v = m.vertebra + n_vertebrae if m.vertebra < 0 else m.vertebra
            if not 0 <= v < n_vertebrae:
                raise OptionError(f"marker {m.name}: vertebra {m.vertebra} out of range (the scene has "
                                  f"vertebrae 0..{n_vertebrae - 1})", field=mapping.source)
            frames.append(int(self.model.vertebra_frames[v]))
        self.marker_frames = np.array(frames, dtype=int)
        self._warm: dict = {}            # (samples source, index) -> _Warm
        self._last = None                # (key, markers, actuations, Solved) of the previous call
        self._derived = None             # (key, wrt, tensions, derivatives, tension derivatives) last taken
        self._columns: dict = {}         # model elements -> the sensitivities' parameter columns

    # ------------------------------------------------------------------ parameters
    def _set(self, values: Values) -> None:
        """Apply ``values`` to the model (a negative pretension is a slack of ``−P/k`` at zero stroke)."""
        self.model.set_parameters(stiffness_scale=values.stiffness, hole_angle=self.rest_angle + values.angle,
                                  hole_radius=self.rest_radius + values.radius,
                                  cable_stiffness=values.cable_stiffness,
                                  pretension=values.pretension, friction=values.friction)

    def _actuation(self, command) -> np.ndarray:
        """The model's actuation for one sample's commands (the strokes of the driven cables)."""
        actuation = self.model.actuation().copy()
        actuation[self.driven] = command
        return actuation

    def _model_columns(self, elements: tuple):
        """The sensitivity columns of the model ``elements`` ((kind, index) pairs), made once, and
        each element's column among them (a tendon's play and lag share its actuator's)."""
        if elements not in self._columns:
            names = [f"{MODEL_KINDS[kind]}:{index if kind == 'stiffness' else self.scene.cables[index].name}"
                     for kind, index in elements]
            unique = list(dict.fromkeys(names))
            self._columns[elements] = (parameters_of(self.model, unique), [unique.index(n) for n in names])
        return self._columns[elements]

    # ------------------------------------------------------------------ markers
    def _markers(self, state, offsets):
        """Robot-frame marker points (n_markers, 3), their lever arms ``R r`` and rotations."""
        R = qmatrix(state.quaternions[self.marker_frames])
        arm = np.einsum("mij,mj->mi", R, offsets)
        return state.positions[self.marker_frames] + arm, arm, R

    def _marker_moves(self, dq, arm):
        """(n, n_markers, 3, P): ``dp = dx_f + dφ_f × (R r)`` of each marker's frame, for the
        frames' moves ``dq`` (n, n_dof, P) and the markers' lever arms ``arm`` (n, n_markers, 3)."""
        moved = np.zeros(arm.shape + dq.shape[-1:])
        for m, f in enumerate(self.marker_frames.tolist()):
            if f == 0:
                continue
            moves = dq[:, 6 * (f - 1):6 * f]                                       # (n, 6, P)
            moved[:, m] = moves[:, :3] + np.cross(moves[:, 3:], arm[:, m, :, None], axis=1)
        return moved

    # ------------------------------------------------------------------ predict
    def predict(self, values: Values, commands, source, rows, wrt: tuple, slopes=None,
                tensions: bool = False) -> Prediction:
        """Markers of the samples ``commands`` (rows ``rows`` of ``source``; the strokes that reach
        the tendons) under ``values`` and, for the elements ``wrt``, their derivatives
        (``slopes``: the strokes' derivatives by the play and the lag of their actuator column,
        :func:`~vertebra.solver.calibration.data.transmission`, needed for ``backlash`` and ``lag``
        elements; ``("stroke", cable)`` elements: by a driven tendon's stroke itself).
        ``tensions``: the driven tendons' tensions too, and with ``wrt`` their derivatives."""
        self._set(values)
        Rf = so3_exp(values.frame[3:])
        key = (source, rows.tobytes(), commands.tobytes(),
               tuple(getattr(values, f).tobytes() for f in ("stiffness", "angle", "radius", "cable_stiffness",
                                                            "pretension", "frame", "marker", "friction",
                                                            "backlash", "lag", "backlash_rate", "entry_friction")))
        t0 = time.perf_counter()
        iterations = 0
        if self._last is not None and self._last[0] == key:
            markers, actuations, states = self._last[1:]
        else:
            markers, actuations, states, iterations = self._solve(values, commands, source, rows, Rf)
            self._last = (key, markers, actuations, states)
        solve_s = time.perf_counter() - t0
        derivatives = d_tension = None
        if wrt:
            if self._derived is not None and self._derived[:3] == (key, wrt, tensions):
                derivatives, d_tension = self._derived[3:]       # (the optimiser's last Jacobian, asked for again)
            else:
                derivatives, d_tension = self._derivatives(values, wrt, states, actuations, source, rows, Rf, slopes,
                                                           tensions)
                self._derived = (key, wrt, tensions, derivatives, d_tension)
        tension = None
        if tensions:
            rest = self.model.trunk.rest_state
            tension = np.array([self.model.cable_tensions(states.state(i, rest), actuations[i])[self.driven]
                                for i in range(len(actuations))]).reshape(len(actuations), len(self.driven))
        return Prediction(markers.copy(), None if derivatives is None else derivatives.copy(), solve_s,
                          time.perf_counter() - t0 - solve_s, iterations, tension,
                          None if d_tension is None else d_tension.copy())

    def _solve(self, values, commands, source, rows, Rf):
        """Every sample's equilibrium. The samples solved before, in one batch
        (:meth:`~vertebra.solver.model.TrunkModel.solve_batch`, each sample the single solve's
        result from its start), each from its own equilibrium of the previous call moved to first
        order to ``values``; one that fails tries its unmoved equilibrium, then rest, by the single
        solve. A sample never solved, by the single solve from its predecessor's equilibrium (the
        data are a sequence of nearby poses; the batch from rest costs more here: load stages, and
        samples whose rest pose no load moves leave the batch's path), then from rest."""
        model = self.model
        n = len(commands)
        actuations = np.repeat(model.actuation()[None], n, 0)
        actuations[:, self.driven] = commands
        warm = [self._warm.get((source, int(row))) for row in rows]
        known = np.array([w is not None for w in warm], bool)
        trunk = model.trunk
        rest = trunk.rest_state
        solved = Solved(np.full((n, trunk.frames.count, 3), np.nan), np.full((n, trunk.frames.count, 4), np.nan),
                        np.full((n, trunk.links.count, 6), np.nan), {})
        iterations = 0
        if known.any():
            at = np.flatnonzero(known)
            found = model.solve_batch(actuations[at], self._starts(values, [warm[i] for i in at]))
            iterations += int(found.iterations.sum())
            solved.positions[at], solved.quaternions[at], solved.strains[at] = (found.positions, found.quaternions,
                                                                                found.strains)
            for j, result in found.results.items():
                solved.put(int(at[j]), result.state)
            for j in np.flatnonzero(~found.converged).tolist():
                i = int(at[j])           # the single solve from the unmoved equilibrium, then from rest
                starts = (compose(rest.quaternions[0], rest.positions[0], warm[i].xi.copy()), None)
                result, spent = _first_converged(model, actuations[i], starts, f"{source}: sample {int(rows[i])}")
                iterations += spent
                solved.put(i, result.state)
        for i in np.flatnonzero(~known).tolist():
            previous = solved.state(i - 1, rest) if i > 0 and np.isfinite(solved.positions[i - 1, 0, 0]) else None
            starts = ([previous] if previous is not None else []) + [None]
            result, spent = _first_converged(model, actuations[i], starts, f"{source}: sample {int(rows[i])}")
            iterations += spent
            solved.put(i, result.state)
        for i, row in enumerate(rows.tolist()):
            if np.all(np.isfinite(solved.strains[i])):
                self._warm[(source, row)] = _Warm(solved.strains[i])
            else:                        # (a state that does not carry its strains: the next starts from rest)
                self._warm.pop((source, row), None)
        markers = self._batch_markers(solved.positions, solved.quaternions, values.marker) @ Rf.T + values.frame[:3]
        return markers, actuations, solved, iterations

    def _starts(self, values: Values, warm: list) -> np.ndarray:
        """Start strains (n, n_links, 6) of the samples whose last equilibria are ``warm`` (None:
        never solved, a row of nan: from rest): each moved to first order to ``values`` where its
        derivatives were taken (``q ⊕ dq/dθ Δθ``, the strain-space retraction of ``model.step``)."""
        trunk = self.model.trunk
        start = np.full((len(warm), trunk.links.count, 6), np.nan)
        moved = {}
        for i, w in enumerate(warm):
            if w is None:
                continue
            start[i] = w.xi
            if w.dq is not None:
                moved.setdefault((w.elements, w.at.tobytes()), []).append(i)
        for (elements, _), members in moved.items():
            at = warm[members[0]].at
            change = np.array([values.get(kind, index) for kind, index in elements]) - at
            if not change.any():
                continue
            dq = np.stack([warm[i].dq for i in members])
            start[members] = predicted_strains(self.model, start[members], dq,
                                               np.broadcast_to(change, (len(members), change.size)))
        return start

    def _batch_markers(self, positions, quaternions, offsets):
        """Robot-frame marker points (n, n_markers, 3) of a batch of poses."""
        R = qmatrix(quaternions[:, self.marker_frames])
        return positions[:, self.marker_frames] + np.einsum("bmij,mj->bmi", R, offsets)

    def _derivatives(self, values, wrt, solved, actuations, source, rows, Rf, slopes=None, tensions=False):
        """The markers' derivatives (n, n_markers, 3, len(wrt)): the model elements' from every
        sample's ``dq/dθ`` at once (:func:`~vertebra.solver.sensitivity.batch_sensitivities`, the
        batched factors), the measurement frame's and the marker offsets' in closed form; and with
        ``tensions`` the driven tendons' tensions' (n, n_actuators, len(wrt)), else None."""
        model, n = self.model, len(actuations)
        nm, npar = len(self.marker_frames), len(wrt)
        out = np.zeros((n, nm, 3, npar))
        d_tension = np.zeros((n, len(self.driven), npar)) if tensions else None
        inner = tuple((kind, index) for kind, index in wrt if kind in MODEL_KINDS)
        where = [col for col, (kind, _) in enumerate(wrt) if kind in MODEL_KINDS]
        R = qmatrix(solved.quaternions[:, self.marker_frames])                     # (n, nm, 3, 3)
        arm = np.einsum("bmij,mj->bmi", R, values.marker)                          # R r
        if inner:
            rest = model.trunk.rest_state
            columns, which = self._model_columns(inner)
            sens = batch_sensitivities(model, solved.strains, actuations, wrt=columns,
                                       outputs=("cable_tensions",) if tensions else (), method="direct",
                                       states=_States(solved, rest))
            dq = sens.dq if which == list(range(len(columns))) else sens.dq[:, :, which]
            if tensions:
                d_tension[..., where] = sens["cable_tensions"][:, self.driven][:, :, which]
            # a play's or a lag's column: the actuator's sensitivity times its stroke's derivative (per sample)
            column_of = {int(c): a for a, c in enumerate(self.driven)}
            for k, (kind, index) in enumerate(inner):
                if kind in STROKE_KINDS:
                    dq[:, :, k] *= slopes[kind][:, column_of[index]][:, None]
            # (a warm start moves by the elements' change, not by the strokes': those come with the commands)
            kept = [k for k, (kind, _) in enumerate(inner) if kind != "stroke"]
            elements = tuple(inner[k] for k in kept)
            at = np.array([values.get(kind, index) for kind, index in elements])
            moves = dq if len(kept) == len(inner) else dq[:, :, kept]
            for i, row in enumerate(rows.tolist()):
                if np.all(np.isfinite(solved.strains[i])):
                    self._warm[(source, int(row))] = _Warm(solved.strains[i], elements, at, moves[i])
            out[..., where] = np.einsum("ij,bmjp->bmip", Rf, self._marker_moves(dq, arm))
        points = self._batch_markers(solved.positions, solved.quaternions, values.marker)
        for col, (kind, index) in enumerate(wrt):
            if kind == "frame":
                if index < 3:
                    out[:, :, index, col] += 1.0
                else:
                    out[:, :, :, col] += points @ _rotation_derivative(values.frame[3:], index - 3).T
            elif kind == "marker":
                mi, c = index
                out[:, mi, :, col] += R[:, mi, :, c] @ Rf.T
        return out, d_tension


class _States:
    """Sample ``i``'s state of a :class:`Solved` on demand (the samples that leave the batch)."""

    def __init__(self, solved, rest):
        self.solved, self.rest = solved, rest

    def __getitem__(self, i: int):
        return self.solved.state(i, self.rest)


class _Warm:
    """A sample's last equilibrium (its link strains ``xi``) and, when its derivatives were taken
    there, the model elements (``elements`` at values ``at``) and ``dq/dθ`` that move it to first
    order (:meth:`_Engine._starts`)."""

    __slots__ = ("xi", "elements", "at", "dq")

    def __init__(self, xi, elements=(), at=None, dq=None):
        self.xi, self.elements, self.at, self.dq = xi, elements, at, dq


class Solved:
    """The equilibria of a batch of samples: every frame's poses, the link strains (nan where a
    state does not carry them) and the single solves' states by sample."""

    def __init__(self, positions, quaternions, strains, states: dict):
        self.positions, self.quaternions, self.strains, self.states = positions, quaternions, strains, states

    def put(self, i: int, state) -> None:
        self.positions[i], self.quaternions[i] = state.positions, state.quaternions
        record = state.carried_strains()
        self.strains[i] = record.xi if record is not None else np.nan
        self.states[i] = state

    def state(self, i: int, rest):
        """Sample ``i``'s state (composed from its strains unless a single solve gave it)."""
        if i in self.states:
            return self.states[i]
        return compose(rest.quaternions[0], rest.positions[0], self.strains[i].copy())


def _first_converged(model, actuation, starts, where: str):
    """``(result, iterations)``: the first converged solve of ``actuation`` from ``starts`` in turn (None:
    from rest) and the Newton iterations of every attempt; ConvergenceError if none converges."""
    spent = 0
    for start in starts:
        result = model.solve(actuation, initial=start, raise_on_failure=False)
        spent += result.iterations
        if result.converged:
            break
    if not result.converged:
        raise ConvergenceError(f"{where}: the equilibrium did not converge ({result.message})", result)
    return result, spent


def _rotation_derivative(rotvec, axis, h=1e-7):
    """∂R(ω)/∂ω_axis by a central difference of the rotation alone (no solve)."""
    e = np.zeros(3)
    e[axis] = h
    return (so3_exp(rotvec + e) - so3_exp(rotvec - e)) / (2 * h)


# ------------------------------------------------------------------ worker processes
class _Pool:
    """``workers`` processes, each an :class:`_Engine` of the scene, called block by block."""

    def __init__(self, workers: int, scene, mapping):
        context = multiprocessing.get_context("spawn")
        self.connections, self.processes = [], []
        with pinned_environment(1):
            for _ in range(workers):
                mine, theirs = context.Pipe()
                process = context.Process(target=_serve, args=(theirs, os.getpid(), scene, mapping), daemon=True,
                                          name="vertebra-calibration-worker")
                process.start()
                theirs.close()
                self.connections.append(mine)
                self.processes.append(process)

    def map(self, method: str, calls: list) -> list:
        """``method(*args)`` of the engines, the k-th call on the k-th worker, all at once."""
        for connection, args in zip(self.connections, calls):
            connection.send((method, args))
        results, error = [], None
        for connection, process in zip(self.connections[:len(calls)], self.processes):
            try:
                ok, value = connection.recv()
            except EOFError:
                ok, value = False, RuntimeError(f"a calibration worker process ended (exit code "
                                                f"{process.exitcode}): out of memory or killed")
            if not ok and error is None:
                error = value
            results.append(value)
        if error is not None:
            raise error
        return results

    def close(self) -> None:
        for connection in self.connections:
            try:
                connection.send(None)
                connection.close()
            except OSError:
                pass
        for process in self.processes:
            process.join(timeout=5)
            if process.is_alive():
                process.terminate()


def _serve(connection, owner: int, scene, mapping) -> None:
    """A worker process: an engine of ``scene`` answering calls until told to stop."""
    exit_with_parent(owner)
    try:
        engine = _Engine(scene, mapping)
    except Exception as error:  # noqa: BLE001 - reported to the caller, which raises it
        engine, failure = None, error
    while True:
        try:
            message = connection.recv()
        except EOFError:
            return
        if message is None:
            return
        if engine is None:
            connection.send((False, failure))
            continue
        method, args = message
        try:
            connection.send((True, getattr(engine, method)(*args)))
        except Exception as error:  # noqa: BLE001 - the caller raises it
            try:
                connection.send((False, error))
            except Exception:  # noqa: BLE001 - an error that does not pickle: its message
                connection.send((False, RuntimeError(f"{type(error).__name__}: {error}")))
