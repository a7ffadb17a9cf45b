"""Predictions of time-ordered samples with tendon friction (docs/friction.md).

With friction the pose under a command depends on the commands before it: the samples of a data
file are then one sequence in file order (each row a command applied to the state the row
before left, the first from rest), solved with the friction state carried from row to row
(:meth:`~vertebra.solver.model.TrunkModel.solve` with ``history``). Without friction (every
``friction`` element 0) :class:`SequencePredictor` is the :class:`RuntimePredictor` itself.

Derivatives with friction: by μ exact, in forward mode along the sequence (each equilibrium's
implicit-function derivative with those of the friction state the sample before left, the
holes' statuses held: :func:`~vertebra.solver.friction.sequence_sensitivities`; at μ = 0, the
bound, differences); by the other model parameters forward differences of the whole sequence (a
parameter changes the path, not only the equilibrium at one command): one sequence per model
parameter (stiffness, hole geometry, tendon spring rate and pretension); the measurement frame
and the marker offsets act after the solve and are differenced on the solved states.
"""

from __future__ import annotations

import time

import numpy as np

from vertebra.core.errors import ConvergenceError, OptionError
from vertebra.core.lie import so3_exp
from vertebra.solver.calibration.backend import Prediction, RuntimePredictor
from vertebra.solver import friction
from vertebra.solver.calibration.fit_parameters import Values

__all__ = ["SequencePredictor"]

# forward-difference steps, times the element's typical size (backend's, and 1 for μ): above the
# equilibria's tolerance-limited noise carried along a sequence
SEQUENCE_STEP = 1e-4
OUTPUT_STEP = 1e-7
SOLVED_KINDS = ("stiffness", "angle", "radius", "cable_stiffness", "pretension", "friction")


class SequencePredictor(RuntimePredictor):
    """The samples as one time-ordered sequence of commands (module docstring)."""

    def __init__(self, scene, mapping, model=None, workers: int = 1):
        super().__init__(scene, mapping, model, workers)
        self._kept = None        # (key, markers, states) of the last sequence solved
        self._results = None     # … and its solves (their friction states)

    def _set(self, values: Values) -> None:
        super()._set(values)
        if not np.array_equal(self.model.parameters.friction, values.friction):
            self.model.set_parameters(friction=values.friction)

    def predict(self, values: Values, samples, wrt=()) -> Prediction:
        if not np.any(values.friction) and not any(kind == "friction" for kind, _ in wrt):
            return super().predict(values, samples, wrt)
        if (np.any(values.backlash) or np.any(values.lag) or np.any(values.backlash_rate)
                or np.any(values.entry_friction)
                or any(kind in ("backlash", "lag", "backlash_rate", "entry_friction") for kind, _ in wrt)):
            raise OptionError("backlash or lag and friction together are not supported: fit one of them (the "
                              "frictional sequence does not pass the commands through the play and the lag)",
                              field="--fit")
        t0 = time.perf_counter()
        markers, states = self._sequence(values, samples)
        solve_s = time.perf_counter() - t0
        derivatives = None
        if wrt:
            exact = self._friction_derivatives(values, wrt, markers, states)
            derivatives = np.stack([exact[element] if element in exact else
                                    self._difference(values, samples, element, markers, states)
                                    for element in wrt], -1)
            self._set(values)
        return Prediction(markers.copy(), derivatives, solve_s, time.perf_counter() - t0 - solve_s)

    def _sequence(self, values: Values, samples, keep: bool = True):
        """Markers (n, n_markers, 3) and states of the samples solved in order under ``values``
        (``keep``: remember them for a call with the same values and samples)."""
        key = (samples.source, len(samples), samples.commands.tobytes(),
               tuple(getattr(values, f).tobytes() for f in ("stiffness", "angle", "radius", "cable_stiffness",
                                                            "pretension", "frame", "marker", "friction")))
        if self._kept is not None and self._kept[0] == key:
            return self._kept[1], self._kept[2]
        self._set(values)
        model = self.model
        history = state = None
        states, results = [], []
        for i, command in enumerate(samples.commands):
            result = model.solve(self._actuation(command), state, history=history, raise_on_failure=False)
            if not result.converged:
                raise ConvergenceError(f"{samples.source}: sample {i}: the frictional equilibrium did not converge "
                                       f"({result.message})", result)
            history, state = result.friction, result.state
            states.append(state)
            results.append(result)
        markers = self._observe(values, states)
        if keep:
            self._kept, self._results = (key, markers, states), results
        return markers, states

    def _friction_derivatives(self, values: Values, wrt, markers, states) -> dict:
        """``{element: (n, n_markers, 3)}``: the markers' exact derivatives by the friction
        elements of ``wrt`` whose μ is > 0, in forward mode along the sequence
        (:func:`~vertebra.solver.friction.sequence_sensitivities`: each equilibrium with the
        derivatives of the friction state the sample before left, the holes' statuses held); the
        sequence last solved at ``values`` (its results kept). At μ = 0 (the bound; without any
        friction the solves carry no friction state) they are left to the differences."""
        elements = [(kind, index) for kind, index in wrt if kind == "friction" and values.friction[index] > 0.0]
        results = self._results
        if not elements or not results or len(results) != len(states) or any(
                r.friction is None or r.state is not s for r, s in zip(results, states)):
            return {}
        self._set(values)
        model = self.model
        names = [model.actuator_names[index] for _, index in elements]
        exact = friction.sequence_sensitivities(model, results, None, names)
        Rf = so3_exp(values.frame[3:])
        out = np.empty((len(states),) + markers.shape[1:] + (len(elements),))
        for i, (state, dq) in enumerate(zip(states, exact["state"])):
            _, arm, _ = self._markers(state, values.marker)
            out[i] = np.einsum("ij,mjp->mip", Rf, self.engine._marker_moves(dq[None], arm[None])[0])
        return {element: out[..., k] for k, element in enumerate(elements)}

    def _observe(self, values: Values, states) -> np.ndarray:
        Rf = so3_exp(values.frame[3:])
        return np.stack([self._markers(state, values.marker)[0] @ Rf.T + values.frame[:3] for state in states])

    def _difference(self, values: Values, samples, element, markers, states) -> np.ndarray:
        """(n, n_markers, 3): the markers' forward difference in one element."""
        kind, index = element
        if kind in SOLVED_KINDS:
            typical = {"radius": self.rest_radius[index] if kind == "radius" else 1.0,
                       "cable_stiffness": values.cable_stiffness[index] if kind == "cable_stiffness" else 1.0,
                       "pretension": values.cable_stiffness[index] * float(self.model.length_scale)
                       if kind == "pretension" else 1.0}.get(kind, 1.0)
            h = SEQUENCE_STEP * typical
        else:
            h = OUTPUT_STEP * (1.0 if kind == "frame" and index >= 3 else float(self.model.length_scale))
        changed = values.with_elements([((kind, index), values.get(kind, index) + h)])
        if kind in SOLVED_KINDS:
            moved = self._sequence(changed, samples, keep=False)[0]
        else:
            moved = self._observe(changed, states)
        return (moved - markers) / h
