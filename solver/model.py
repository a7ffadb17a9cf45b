"""The runtime object: a compiled trunk and what is done with it.

``build_model(scene)`` compiles a :class:`~vertebra.solver.scene.Scene` once
(:func:`~vertebra.solver.trunk.compile_trunk`) into a :class:`TrunkModel`; ``model.solve(actuation)``
then runs many times without re-parsing or re-allocating the structure. The model is a façade:

* :mod:`~vertebra.solver.trunk` — the compiled, read-only arrays (``model.trunk``);
* :mod:`~vertebra.solver.potential` — potential, gradient and tangent at a state;
* :mod:`~vertebra.solver.assembly` / :mod:`~vertebra.solver.banded` — band storage and factors;
* :mod:`~vertebra.solver.newton` — the forward solve;
* :mod:`~vertebra.solver.outputs` — effectors, actuator displacements, the linearisation;
* :class:`~vertebra.solver.potential.LoadCases` — the load cases of the last two actuations asked for.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

import numpy as np

from vertebra.solver import batch, bounds, compliance, contact_friction, friction, newton, outputs, sensitivity
from vertebra.solver.potential import Evaluation, LoadCases, Trial, cable_tensions, evaluate, out_of_range, potential
from vertebra.solver.newton import StaticResult
from vertebra.solver.outputs import Linearisation
from vertebra.solver.parameters import Parameters, parameters_of, reparameterise
from vertebra.solver.state import State, StrainRecord, kinematics, retract
from vertebra.solver.trunk import Trunk, compile_trunk
from vertebra.core.errors import CatalogueError, ConvergenceError, OptionError

__all__ = ["Linearisation", "State", "StaticResult", "StrainRecord", "TrunkModel", "build_model"]


def build_model(scene, entries: dict | None = None) -> "TrunkModel":
    """Compile a scene. ``entries`` maps entry names to ``SegmentEntry`` objects; when
    omitted, the entries the scene names (and only those) are read from its catalogue. A scene
    whose design segments are not resolved to entries yet is a SceneError (``vertebra prepare``)."""
    scene.check_resolved()
    needed = sorted({s.entry for s in scene.segments if s.type == "entry"})
    entries = dict(entries or {})
    missing = [name for name in needed if name not in entries]
    if missing:
        from vertebra.store import catalogue  # lazy: beam-only scenes never touch HDF5
        with catalogue.open_catalogue(scene.catalogue) as cat:
            for name in missing:
                try:
                    entries[name] = cat.load(name)
                except CatalogueError as error:
                    index = next(i for i, s in enumerate(scene.segments) if s.type == "entry" and s.entry == name)
                    raise CatalogueError(f"{scene.source}: segment[{index}].entry: {error}") from error
    return TrunkModel(scene, entries)


def _forward(part: str, name: str, doc: str) -> property:
    """A read-only attribute of the model that is a field of one part of the compiled trunk."""
    return property(lambda self: getattr(getattr(self.trunk, part), name), doc=doc)


class TrunkModel:
    """A compiled trunk. Build with :func:`build_model`."""

    def __init__(self, scene, entries: dict):
        self.compiled: Trunk = compile_trunk(scene, entries)
        self.trunk: Trunk = self.compiled       # the compiled trunk under the current parameters
        self.parameters: Parameters = Parameters.of_trunk(self.compiled)
        self.loads = LoadCases(self.trunk)      # the load cases of the last two actuations asked for
        self.entries: dict = dict(entries)      # the catalogue entries compiled, by name

    scene = property(lambda self: self.trunk.scene, doc="the scene the model was compiled from")
    rest_state = property(lambda self: self.trunk.rest_state, doc="the stress-free pose (carries its strains)")
    rest_cable_lengths = property(lambda self: self.trunk.rest_cable_lengths, doc="cable lengths at rest")
    n_dof = property(lambda self: self.trunk.n_dof, doc="6 · free frames")
    n_frames = _forward("frames", "count", "frames, the clamped base included")
    vertebra_frames = _forward("frames", "vertebra", "frame index of each vertebra")
    frame_mass = _forward("frames", "mass", "mass lumped on each frame")
    length_scale = _forward("frames", "length_scale", "trunk length Σ|d0| over the links")
    n_links = _forward("links", "count", "links (link k joins frames k and k + 1)")
    link_rest = _forward("links", "rest", "rest strains ξ₀ of the links (n_links, 6)")
    n_cables = _forward("actuators", "n_cables", "cables (the first actuators)")
    n_chambers = _forward("actuators", "n_chambers", "chambers (the actuators after the cables)")
    n_tendons = property(lambda self: self.trunk.actuators.tendons.size,
                         doc="stroke-driven cables (tendons whose value is a servo stroke)")
    actuator_names = property(lambda self: list(self.trunk.actuators.names), doc="cable then chamber names")
    default_actuation = _forward("actuators", "default", "the scene's tensions and pressures")
    actuator_bounds = _forward("actuators", "bounds", "(lower, upper) bounds on the actuation")
    displacement_bounds = _forward("actuators", "displacement_bounds", "(lower, upper) on strokes, volume growths")
    actuator_max_change = _forward("actuators", "max_change", "largest change of each actuator per control tick")
    chamber_rest_volumes = _forward("actuators", "chamber_rest_volumes", "rest volume of each chamber")
    effector_names = property(lambda self: list(self.trunk.effectors.names), doc="effector names")
    effector_frames = _forward("effectors", "frames", "frame of each effector")
    effector_is_axis = _forward("effectors", "is_axis", "True for axis (direction) effectors")
    effector_targets = _forward("effectors", "targets", "world targets (nan where none)")
    effector_weights = _forward("effectors", "weights", "effector weights")
    has_dead_moments = _forward("loads", "has_dead_moments", "dead moments act (the tangent is unsymmetric)")
    has_follower_loads = _forward("loads", "has_follower", "follower loads act (the tangent is unsymmetric)")

    def __repr__(self) -> str:
        kinds = Counter()
        for segment in self.scene.segments:
            kinds[segment.type] += segment.count * segment.elements
        by_kind = ", ".join(f"{kind} {count}" for kind, count in kinds.items())
        effectors = self.effector_names
        return (f"<TrunkModel {self.scene.name or self.scene.source!r}: {self.n_frames} frames "
                f"({len(self.vertebra_frames)} vertebrae), {self.n_links} links ({by_kind}), "
                f"{self.n_cables} cables, {self.n_chambers} chambers, {len(effectors)} effectors"
                + (f" ({', '.join(effectors)})" if effectors else "") + ">")

    def actuation(self, actuation=None) -> np.ndarray:
        """``actuation`` as a float array of one value per actuator: None gives the scene's
        values; a sequence gives every value (cables, then chambers); a mapping from actuator
        names to values changes those and keeps the scene's value for the others. Unknown names
        or a wrong count are an :class:`OptionError`."""
        default = self.trunk.actuators.default
        if type(actuation) is np.ndarray and actuation.dtype is default.dtype and actuation.shape == default.shape:
            return actuation            # (already one float per actuator)
        if actuation is None:
            return default.copy()
        if isinstance(actuation, Mapping):
            names = self.actuator_names
            unknown = [str(name) for name in actuation if name not in names]
            if unknown:
                raise OptionError(f"unknown actuator name(s) {', '.join(map(repr, unknown))}; the model has "
                                  f"{', '.join(names) or 'no actuators'}", field="actuation")
            values = default.copy()
            for name, value in actuation.items():
                values[names.index(name)] = float(value)
            return values
        actuation = np.asarray(actuation, dtype=float).reshape(-1)
        if actuation.shape != default.shape:
            raise OptionError(f"{actuation.size} values for {default.size} actuators "
                              f"({', '.join(self.actuator_names)})", field="actuation")
        return actuation

    # ------------------------------------------------------------------ parameters
    def with_parameters(self, parameters: Parameters | None = None, **changes) -> Parameters:
        """Parameters: ``parameters`` (default: the current ones) with ``changes`` by name (see
        :func:`~vertebra.solver.parameters.parameters_of`: ``gravity``, ``dead``, ``follower``,
        ``cable_stiffness``, ``pretension``, ``stiffness_scale``, ``hole_radius``, ``hole_angle``)."""
        return parameters_of(self.compiled, parameters or self.parameters, changes)

    def set_parameters(self, parameters: Parameters | None = None, **changes) -> Parameters:
        """Change loads and parameters between solves without compiling the scene again
        (:meth:`with_parameters`; :func:`~vertebra.solver.parameters.reparameterise`). Returns the
        parameters now in force. States solved before stay valid start states."""
        parameters = self.with_parameters(parameters, **changes)
        if parameters is not self.parameters:
            self.trunk = reparameterise(self.compiled, parameters)
            self.parameters = parameters
            self.loads = LoadCases(self.trunk)
        return parameters

    # ------------------------------------------------------------------ solve
    def solve(self, actuation=None, initial: State | None = None, *, tolerance=None,
              max_iterations=None, load_steps=None, raise_on_failure=True, history=None) -> StaticResult:
        """Quasi-static equilibrium (paper eq. 9) by Newton with line search and automatic load
        stepping (:mod:`~vertebra.solver.newton`). ``actuation``: see :meth:`actuation`
        (e.g. ``{"t1": 5.0}``). Raises :class:`ConvergenceError` (with the partial result) on
        failure. A negative tension on a cable is refused, other bounds are reported
        (``result.bound_violations``, :mod:`~vertebra.solver.bounds`).

        With cable friction (a ``friction`` in the scene, or a ``history``) the command is applied
        to ``history`` (a :class:`~vertebra.solver.friction.FrictionState`, e.g. an earlier
        result's ``friction``; None: the rest state — a single command is a monotone pull) and
        ``result.friction`` is the state after it (:mod:`~vertebra.solver.friction`,
        docs/friction.md); :meth:`solve_sequence` chains commands. With friction at obstacle
        contacts (an obstacle's ``friction``) the same holds with a
        :class:`~vertebra.solver.contact_friction.ContactFriction` history (docs/contact.md)."""
        settings = self.scene.solver
        values = self.actuation(actuation)
        bounds.check_pushing(self, values, from_scene=actuation is None)
        at_contacts = self._contact_friction(history)
        frictional = not at_contacts and (history is not None or self.trunk.actuators.frictional)
        options = dict(tolerance=settings.tolerance if tolerance is None else tolerance,
                       max_iterations=settings.max_iterations if max_iterations is None else max_iterations,
                       load_steps=settings.load_steps if load_steps is None else load_steps,
                       raise_on_failure=raise_on_failure)
        try:
            if at_contacts:
                result = contact_friction.solve(self.trunk, self.loads, values, initial, history, **options)
            else:
                result = (friction.solve if frictional else newton.solve)(
                    self.trunk, *((values, history) if frictional else (self.loads, values)), initial, **options)
        except ConvergenceError as error:
            if error.result is not None:
                error.result.bound_violations = bounds.bound_violations(self, error.result.state, values)
            raise
        result.bound_violations = bounds.bound_violations(self, result.state, values)
        return result

    def _contact_friction(self, history) -> bool:
        """Does a solve run friction at obstacle contacts (docs/contact.md)? Refused together with
        cable friction, which it is not combined with."""
        at_contacts = contact_friction.frictional(self.trunk) or isinstance(history, contact_friction.ContactFriction)
        if at_contacts and (self.trunk.actuators.frictional or isinstance(history, friction.FrictionState)):
            raise OptionError("friction at obstacle contacts and cable friction are not combined: give the "
                              "obstacles or the cables friction = 0", field="friction")
        return at_contacts

    def solve_batch(self, actuations, initial=None, *, tolerance=None, max_iterations=None, load_steps=None,
                    chunk=None, progress=None) -> "batch.BatchResult":
        """Equilibria of many actuations at once (:func:`vertebra.solver.batch.solve_batch`):
        ``actuations`` (B, n_actuators) in :attr:`actuator_names` order; ``initial`` None (from
        rest), start states (a sequence of :class:`State`, None entries from rest) or their link
        strains (B, n_links, 6). Each sample's result is the single :meth:`solve`'s (its checks,
        its failures, reported per sample: nothing is raised for a sample that fails). A negative
        tension on a cable is refused as by :meth:`solve`; bounds are reported per sample
        (``result.bound_violations``)."""
        settings = self.scene.solver
        values = np.asarray(actuations, dtype=float)
        if values.ndim != 2 or values.shape[1] != len(self.actuator_names):
            raise OptionError(f"actuations must be (samples, {len(self.actuator_names)}) for the actuators "
                              f"{', '.join(self.actuator_names)}; got shape {values.shape}", field="actuations")
        if self.n_cables:
            pushing = np.flatnonzero(np.any(values[:, :self.n_cables] < 0.0, 1))
            for i in pushing[:1].tolist():
                bounds.check_pushing(self, values[i])
        result = batch.solve_batch(
            self, values, initial,
            tolerance=settings.tolerance if tolerance is None else tolerance,
            max_iterations=settings.max_iterations if max_iterations is None else max_iterations,
            load_steps=settings.load_steps if load_steps is None else load_steps, chunk=chunk, progress=progress)
        result.bound_violations = batch.bound_violations(self, result)
        return result

    def solve_sequence(self, actuations, history=None, initial: State | None = None, **options) -> list:
        """Solve the commands ``actuations`` (each as for :meth:`solve`) in order, each applied to
        the friction state the one before left (``history``: where the sequence starts; None: at
        rest): a pull then a release traces the hysteresis loop. Returns the results."""
        if self._contact_friction(history):
            results = []
            for actuation in actuations:
                results.append(self.solve(actuation, initial, history=history, **options))
                history, initial = results[-1].friction, None
            return results
        return friction.solve_sequence(self, [self.actuation(a) for a in actuations], history, initial, **options)

    def evaluate(self, state: State, actuation=None, *, scale: float = 1.0, previous=None) -> Evaluation:
        """Total potential and gradient at ``state`` under ``scale`` × the actuation and loads
        (:func:`vertebra.solver.potential.evaluate`; ``previous``: an evaluation or :meth:`trial`
        of the same state to reuse)."""
        actuation = self.actuation(actuation)
        return evaluate(self.trunk, state, self.loads(actuation, scale), previous)

    def potential(self, state: State, actuation=None) -> float:
        """Total potential at ``state`` under the actuation and loads, without its gradient
        (:func:`vertebra.solver.potential.potential`)."""
        return self.trial(state, actuation).energy

    def trial(self, state: State, actuation=None) -> "Trial | Evaluation":
        """The potential at ``state`` (``.energy``) with what it computed on the way: hand it as
        ``previous`` to :meth:`linearise` or :meth:`evaluate` of the same state and actuation."""
        return potential(self.trunk, state, self.loads(self.actuation(actuation), 1.0))

    def residual_norm(self, residual: np.ndarray, actuation=None) -> float:
        """The solver's convergence measure of an out-of-balance force ``residual`` (n_dof,):
        max(|force|, |moment| / length) over the frames relative to the rest pose's
        out-of-balance load under ``actuation``."""
        actuation = self.actuation(actuation)
        reference = newton.reference_force(self.trunk, self.loads(actuation, 1.0))
        return newton.residual_norm(residual, reference, newton.residual_weights(self.trunk))

    def step(self, state: State, dq: np.ndarray) -> State:
        """The state moved by ``dq`` (``[dx; dφ]`` per free frame, world axes; n_dof values) with
        the strain-space retraction (:func:`vertebra.solver.state.retract`)."""
        return retract(state, dq, kinematics(state))

    # ------------------------------------------------------------------ outputs
    def linearise(self, state: State, actuation=None, *, previous=None, history=None, factor=None) -> Linearisation:
        """Tangent stiffness factor, actuator and effector Jacobians at ``state`` (``previous``:
        an evaluation or :meth:`trial` of the same state and actuation to reuse; ``factor``: an
        earlier linearisation's factor to use instead of this state's tangent, a chord step). With
        cable friction, the frictional transmission (:func:`~vertebra.solver.friction.linearise`)
        of the command applied to ``history`` (a :class:`~vertebra.solver.friction.FrictionState`;
        None: a pull from rest), holes at incipient slip sliding on in their last direction (its
        own tangent: ``factor`` is not taken)."""
        if self.trunk.actuators.frictional or history is not None:
            return friction.linearise(self.trunk, state, self.actuation(actuation), history,
                                      None if history is None else history.incipient(self.trunk))[0]
        return outputs.linearise(self.trunk, state, self.actuation(actuation), self.loads, previous, factor)

    def cable_tensions(self, state: State, actuation=None) -> np.ndarray:
        """The tension of every cable at ``state`` under ``actuation``: a tension-driven cable's
        value, a stroke-driven tendon's ``k·max(0, e)`` from its elongation there."""
        actuation = self.actuation(actuation)
        if not self.n_tendons:
            return actuation[:self.n_cables].copy()
        return cable_tensions(self.trunk, self.evaluate(state, actuation))

    def cable_lengths(self, state: State, pieces=None) -> np.ndarray:
        return outputs.cable_lengths(self.trunk, state, pieces)

    def chamber_volume_growth(self, state: State, pressures: np.ndarray, links=None) -> np.ndarray:
        """ΔV_j of every chamber under ``pressures`` (reciprocity gives the Gᵀ row)."""
        return outputs.chamber_volume_growth(self.trunk, state, pressures, self.loads, links)

    def actuator_displacements(self, state: State, actuation=None, *, links=None, pieces=None) -> np.ndarray:
        """Cable strokes ``L − L0``, then chamber volume growths."""
        return outputs.actuator_displacements(self.trunk, state, self.actuation(actuation), self.loads,
                                              links=links, pieces=pieces)

    def out_of_range(self, state: State, actuation=None) -> tuple:
        """Where the links' states at ``state`` under ``actuation`` leave the range their energies
        were fitted on (:class:`~vertebra.solver.kinds.RangeExcess`, in link order; empty when
        inside, or when no link energy is a fit): what a solve reports in ``out_of_range``."""
        if not self.trunk.links.fitted:
            return ()
        return out_of_range(self.trunk, kinematics(state).xi, self.loads(self.actuation(actuation), 1.0))

    def effector_positions(self, state: State) -> np.ndarray:
        """World position of each point effector; world unit direction of each axis effector."""
        return outputs.effector_points(self.trunk, state)[1].copy()

    def sensitivities(self, state, actuation=None, *, wrt=sensitivity.PARAMETER_GROUPS,
                      outputs=sensitivity.OUTPUTS, method: str = "auto") -> "sensitivity.Sensitivities":
        """Derivatives of the outputs at the equilibrium ``state`` (or a solve's result) with respect
        to the actuation, loads and parameters, from the converged tangent
        (:func:`vertebra.solver.sensitivity.sensitivities`; docs/sensitivities.md)."""
        return sensitivity.sensitivities(self, state, actuation, wrt=wrt, outputs=outputs, method=method)

    def effector_compliance(self, state: State, actuation=None):
        """Cartesian compliance of every effector at the equilibrium ``state`` under ``actuation``
        (``Je K⁻¹ Jeᵀ`` from the banded factor; :func:`vertebra.solver.compliance.effector_compliance`)."""
        return compliance.effector_compliance(self, state, actuation)
