"""Predicted marker positions of servo-driven samples, and their derivatives.

A calibration sees the robot through one narrow interface, :class:`Predictor`:
``predict(values, samples, wrt)`` solves every sample's static equilibrium under the element
values (:class:`~vertebra.solver.calibration.fit_parameters.Values`) and returns the markers in the
measurement frame and, for the elements ``wrt``, their derivatives.

:class:`RuntimePredictor` builds it on the runtime: the mapped cables are the scene's
stroke-driven tendons (tension ``k·max(0, L − L0 + stroke + P/k)``), the element values are
run-time parameters of the model (:meth:`~vertebra.solver.model.TrunkModel.set_parameters`:
stiffness scale per segment, hole angles and radii, spring rates, pretensions; no
recompilation), and each sample's solve starts from the state it had at the previous call (else
from its predecessor in the file: the data are a sequence of nearby poses).

Derivatives come from the implicit function theorem at each converged state: with ``g(q, θ)``
the out-of-balance force (tendon springs included) and ``K`` its tangent,
``dq/dθ = −K⁻¹ ∂g/∂θ``, one back-substitution per parameter with the converged tangent's
factor. A tendon's force is ``τ ∂L/∂q`` with ``τ = k·max(0, e)`` and ``e ∋ P/k``, so for its
pretension and spring rate ``∂g/∂θ = (∂τ/∂θ) ∂L/∂q`` in closed form; for a stiffness scale and
the hole geometry ``∂g/∂θ`` is a forward difference of ``g`` at the fixed converged state under
the perturbed parameter (no re-solve: ``g`` is linear in a stiffness scale and smooth in the
hole geometry). The measurement frame and the marker offsets act after the solve and
are differentiated in closed form.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vertebra.core.errors import ConvergenceError, OptionError
from vertebra.core.lie import qmatrix, so3_exp
from vertebra.solver.calibration.fit_parameters import Values
from vertebra.solver.model import build_model

__all__ = ["Prediction", "Predictor", "RuntimePredictor"]

# relative forward-difference steps of the elements differentiated through the model
# (times the typical size of the element: 1, a radian, the hole radius, the spring rate, k·length)
FD_STEP = 1e-6
MODEL_KINDS = ("stiffness", "angle", "radius", "cable_stiffness", "pretension")
FD_KINDS = ("stiffness", "angle", "radius")      # the others in closed form


@dataclass
class Prediction:
    markers: np.ndarray             # (n, n_markers, 3) m, measurement frame
    derivatives: np.ndarray | None  # (n, n_markers, 3, len(wrt))
    solve_s: float = 0.0
    derivative_s: float = 0.0


class Predictor(Protocol):
    model: object

    def predict(self, values: Values, samples, wrt=()) -> Prediction: ...


class RuntimePredictor:
    """Servo-driven samples on the runtime's stroke-driven tendons (module docstring)."""

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
        self._warm: dict = {}            # (samples source, index) -> state
        self._last = None                # (key, markers, actuations, states) of the previous call

    # ------------------------------------------------------------------ parameters
    def _set(self, values: Values) -> None:
        """Apply ``values`` to the model (a negative pretension is a slack of ``−P/k`` at zero stroke)."""
        self.model.set_parameters(stiffness_scale=values.stiffness, hole_angle=self.rest_angle + values.angle,
                                  hole_radius=self.rest_radius + values.radius,
                                  cable_stiffness=values.cable_stiffness,
                                  pretension=values.pretension)

    def _actuation(self, values: Values, command) -> np.ndarray:
        """The model's actuation for one sample's commands (the strokes of the driven cables)."""
        actuation = self.model.actuation().copy()
        actuation[self.driven] = command
        return actuation

    def _step(self, kind: str, index, values: Values) -> float:
        typical = {"stiffness": 1.0, "angle": 1.0, "radius": self.rest_radius[index] if kind == "radius" else 1.0,
                   "cable_stiffness": values.cable_stiffness[index] if kind == "cable_stiffness" else 1.0,
                   "pretension": values.cable_stiffness[index] * float(self.model.length_scale)
                   if kind == "pretension" else 1.0}[kind]
        return FD_STEP * typical

    # ------------------------------------------------------------------ markers
    def _markers(self, state, offsets):
        """Robot-frame marker points (n_markers, 3), their lever arms ``R r`` and rotations."""
        R = qmatrix(state.quaternions[self.marker_frames])
        arm = np.einsum("mij,mj->mi", R, offsets)
        return state.positions[self.marker_frames] + arm, arm, R

    def _marker_jacobian(self, arm):
        """(n_markers, 3, n_dof): ``dp = dx_f + dφ_f × (R r)`` of each marker's frame."""
        J = np.zeros((len(arm), 3, self.model.n_dof))
        for i, (f, a) in enumerate(zip(self.marker_frames, arm)):
            if f == 0:
                continue
            c = 6 * (f - 1)
            J[i, :, c:c + 3] = np.eye(3)
            J[i, :, c + 3:c + 6] = -np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        return J

    # ------------------------------------------------------------------ predict
    def predict(self, values: Values, samples, wrt=()) -> Prediction:
        """Markers of every sample under ``values`` and, for the elements ``wrt``, their
        derivatives. A call with the values and samples of the previous call reuses its
        equilibria (a least-squares step asks for the residuals, then the Jacobian, at one point)."""
        model = self.model
        self._set(values)
        Rf = so3_exp(values.frame[3:])
        key = (samples.source, len(samples), samples.commands.tobytes(),
               tuple(getattr(values, f).tobytes() for f in ("stiffness", "angle", "radius", "cable_stiffness",
                                                            "pretension", "frame", "marker")))
        t0 = time.perf_counter()
        if self._last is not None and self._last[0] == key:
            markers, actuations, states = self._last[1:]
        else:
            markers, actuations, states = self._solve(values, samples, Rf)
            self._last = (key, markers, actuations, states)
        solve_s = time.perf_counter() - t0
        derivatives = None
        if wrt:
            derivatives = self._derivatives(values, list(wrt), states, actuations, samples.commands, Rf)
        return Prediction(markers.copy(), derivatives, solve_s, time.perf_counter() - t0 - solve_s)

    def _solve(self, values, samples, Rf):
        model = self.model
        n, nm = len(samples), len(self.marker_frames)
        markers = np.empty((n, nm, 3))
        actuations, states = [], []
        previous = None
        for i in range(n):
            actuation = self._actuation(values, samples.commands[i])
            key = (samples.source, i)
            start = self._warm.get(key, previous)
            result = model.solve(actuation, initial=start, raise_on_failure=False)
            if not result.converged and start is not None:      # a far warm start: from the rest pose
                result = model.solve(actuation, raise_on_failure=False)
            if not result.converged:
                raise ConvergenceError(f"{samples.source}: sample {i}: the equilibrium did not converge "
                                       f"({result.message})", result)
            self._warm[key] = previous = result.state
            points, _, _ = self._markers(result.state, values.marker)
            markers[i] = points @ Rf.T + values.frame[:3]
            actuations.append(actuation)
            states.append(result.state)
        return markers, actuations, states

    def _derivatives(self, values, wrt, states, actuations, commands, Rf):
        model, n = self.model, len(states)
        nm, npar = len(self.marker_frames), len(wrt)
        out = np.zeros((n, nm, 3, npar))
        inner = [(col, kind, index) for col, (kind, index) in enumerate(wrt) if kind in MODEL_KINDS]
        G = np.zeros((n, model.n_dof, len(inner)))
        differenced = [(j, kind, index) for j, (_, kind, index) in enumerate(inner) if kind in FD_KINDS]
        if differenced:
            g0 = np.stack([model.evaluate(s, a).gradient[1:].reshape(-1) for s, a in zip(states, actuations)])
            for j, kind, index in differenced:
                h = self._step(kind, index, values)
                changed = values.with_elements([((kind, index), values.get(kind, index) + h)])
                self._set(changed)
                for i, s in enumerate(states):
                    a = self._actuation(changed, commands[i])
                    G[i, :, j] = (model.evaluate(s, a).gradient[1:].reshape(-1) - g0[i]) / h
            self._set(values)
        tendon = [(j, kind, index) for j, (_, kind, index) in enumerate(inner) if kind not in FD_KINDS]
        k, P = values.cable_stiffness, values.pretension
        for i, (state, actuation) in enumerate(zip(states, actuations)):
            points, arm, R = self._markers(state, values.marker)
            if inner:
                lin = model.linearise(state, actuation)
                if tendon:      # τ = k·max(0, e), e ∋ P/k: the force τ ∂L/∂q changes along ∂L/∂q
                    tension = model.cable_tensions(state, actuation)
                    for j, kind, index in tendon:
                        taut = float(tension[index] > 0.0)
                        rate = taut if kind == "pretension" else tension[index] / k[index] - taut * P[index] / k[index]
                        G[i, :, j] = rate * lin.actuator_jacobian[index]
                dq = -lin.solve(np.asfortranarray(G[i]))                      # (n_dof, n_inner)
                dm = self._marker_jacobian(arm) @ dq                           # (nm, 3, n_inner)
                out[i][..., [c for c, _, _ in inner]] = np.einsum("ij,mjp->mip", Rf, dm)
            for col, (kind, index) in enumerate(wrt):
                if kind == "frame":
                    if index < 3:
                        out[i, :, index, col] += 1.0
                    else:
                        out[i, :, :, col] += _rotation_derivative(values.frame[3:], index - 3, points)
                elif kind == "marker":
                    mi, c = index
                    out[i, mi, :, col] += Rf @ R[mi][:, c]
        return out


def _rotation_derivative(rotvec, axis, points, h=1e-7):
    """∂(R(ω) p)/∂ω_axis by a central difference of the rotation alone (no solve)."""
    e = np.zeros(3)
    e[axis] = h
    plus, minus = so3_exp(rotvec + e), so3_exp(rotvec - e)
    return points @ ((plus - minus) / (2 * h)).T
