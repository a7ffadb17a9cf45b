"""Sensitivities of an equilibrium: derivatives of its outputs with respect to the actuation, the
loads and the run-time parameters, from the converged tangent (implicit function theorem).

At an equilibrium the gradient of the potential along the solver's chart vanishes on the free
frames, ``g(q, p) = 0`` (``q``: the free frames' ``[dx; dφ]``, world axes; ``p``: a parameter).
With the tangent ``K = ∂g/∂q``, a change of ``p`` moves the equilibrium by
``dq/dp = −K⁻¹ ∂g/∂p``, and an output ``y(q, p)`` changes by ``dy/dp = ∂y/∂q dq/dp + ∂y/∂p``.
One factor of ``K`` serves every parameter: the *direct* route solves ``K dq = −∂g/∂p`` (one
back-substitution per parameter), the *adjoint* route solves ``Kᵀ Λ = (∂y/∂q)ᵀ`` (one per output
row) and gives ``dy/dp = −Λᵀ ∂g/∂p + ∂y/∂p`` without ``dq``. ``K`` is the factor the linearisation
makes (the tendons' dense rank-one terms beside the band included); it is unsymmetric when dead
moments or follower loads act, and the adjoint then solves with its transpose.

The explicit derivatives ``∂g/∂p`` and ``∂y/∂p`` at the fixed state are analytic: the actuation
(the actuator forces), gravity (masses and lever arms), dead loads (a unit wrench at a frame), follower loads (the
unit wrench turned into world axes by the frame's rotation, ``R e``),
the tendons' spring rates and pretensions (taut tendons: ``∂τ/∂k = e − T₀/k``, ``∂τ/∂T₀ = 1``,
times ``∂L/∂q``), the stiffness scales (a segment's links' gradient divided by its scale) and the
hole radii and angles (the pieces' length gradients moved with their holes, and the tendons'
elongations through ``L`` and ``L0``). One term is a central difference at the fixed state: a
chamber's own pressure term of its volume growth, ``−∂²ψ/∂p²`` (exact to rounding for linear
entries, where the growth is linear in the pressure; ``O(h²)`` with ``h = PRESSURE_STEP`` × the
pressure scale, about 1e-10 relative, for fitted entries). No parameter needs a new solve.

:func:`batch_sensitivities` gives those of many equilibria at once: the batch's factors
(:mod:`vertebra.solver.batch`) and the same explicit terms, which take a leading sample axis (the
single route passes one sample). See docs/sensitivities.md.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lu_solve
from scipy.linalg.lapack import dgbtrs

from vertebra.core.errors import ConvergenceError, OptionError
from vertebra.core.lie import hat, qmatrix
from vertebra.solver import batch as batch_module
from vertebra.solver import outputs as outputs_module
from vertebra.solver.banded import BandedFactor, LowRankFactor
from vertebra.solver.cables import CablePieces, scatter_rows
from vertebra.solver.potential import Evaluation, evaluate, volume_growth
from vertebra.solver.parameters import reparameterise
from vertebra.solver.state import compose as compose_state

PARAMETER_GROUPS = ("actuation", "gravity", "dead", "follower", "cable_stiffness", "pretension", "stiffness_scale",
                    "hole_radius", "hole_angle")
OUTPUTS = ("frame_positions", "frame_rotations", "effector_positions", "cable_tensions", "cable_strokes",
           "chamber_volumes")
AXES = ("x", "y", "z")
WRENCH = ("fx", "fy", "fz", "mx", "my", "mz")
PRESSURE_STEP = 6e-6         # ≈ ε^(1/3): the central difference's truncation and rounding balance
PRESSURE_FLOOR = 1e3         # Pa: the smallest pressure scale of a chamber's difference step


@dataclass(frozen=True)
class Parameter:
    """One column of the sensitivities: ``group`` (one of :data:`PARAMETER_GROUPS`), ``index``
    (actuator, cable, segment or frame) and ``component`` (gravity's axis, a dead or follower wrench's
    component; 0 otherwise)."""

    name: str
    group: str
    index: int = 0
    component: int = 0


@dataclass
class Sensitivities:
    """Derivatives of an equilibrium's outputs with respect to ``parameters`` (one column each).

    ``dq`` (n_dof, P): the free frames' ``[dx; dφ]`` (world axes) per unit parameter (None on the
    adjoint route); ``outputs``: output name → (n_out, P) — ``frame_positions`` and
    ``frame_rotations`` (3 rows per frame, the base included; a rotation's rows are the world
    rotation increment ``dφ``), ``effector_positions`` (3 rows per effector), ``cable_tensions``,
    ``cable_strokes`` (``L − L0``) and ``chamber_volumes`` (volume growths), one row each.
    ``differenced``: the parameters with an explicit term that is a central difference at the
    fixed state (a fitted chamber's own pressure term of its volume growth; module docstring).
    ``effector_jacobian`` of many states (:class:`BatchSensitivities`) keeps their sample axis."""

    parameters: tuple
    outputs: dict
    dq: np.ndarray | None
    method: str                      # "direct" or "adjoint"
    effector_names: tuple = ()
    differenced: tuple = ()
    timings: dict = field(default_factory=dict)

    def __getitem__(self, output: str) -> np.ndarray:
        try:
            return self.outputs[output]
        except KeyError:
            raise OptionError(f"no output {output!r} (computed: {', '.join(self.outputs)})", field="outputs") from None

    def column(self, parameter: str) -> int:
        """The column of the parameter named ``parameter`` (e.g. ``"actuation:t1"``)."""
        try:
            return self.parameters.index(parameter)
        except ValueError:
            raise OptionError(f"no parameter {parameter!r} among the sensitivities", field="wrt") from None

    def effector_jacobian(self, effectors: Sequence[str] | None = None) -> np.ndarray:
        """``d(effector positions)/dp`` (3·k, P) of the effectors named (default: all, in the
        model's order), rows ``x, y, z`` per effector: the Jacobian of a least-squares fit of
        measured points."""
        jacobian = self["effector_positions"]
        if effectors is None:
            return jacobian
        unknown = [name for name in effectors if name not in self.effector_names]
        if unknown:
            raise OptionError(f"unknown effector(s) {', '.join(map(repr, unknown))}", field="effectors")
        rows = np.array([3 * self.effector_names.index(name) + k for name in effectors for k in range(3)], int)
        return jacobian[..., rows, :]


# ------------------------------------------------------------------ the parameters asked for
def parameters_of(model, wrt: Iterable[str]) -> list[Parameter]:
    """The columns named by ``wrt``: group names (every parameter of the group: every actuator,
    gravity's three axes, six components at every free vertebra, the tendons' spring rates and
    pretensions, the scale of every segment without cavities, every cable's hole radius and
    angle) or single parameters (``"actuation:t1"``, ``"gravity:z"``, ``"dead:5:fx"`` or
    ``"dead:-1"`` (all six), ``"follower:-1:mz"`` (in the vertebra's axes), ``"cable_stiffness:t2"``,
    ``"pretension:t2"``, ``"stiffness_scale:0"``, ``"hole_radius:t3"``, ``"hole_angle:t3"``), or :class:`Parameter`
    columns this function gave before for the same model (taken as they are: a caller asking at
    many states names its columns once)."""
    if isinstance(wrt, str):
        wrt = (wrt,)
    columns: list[Parameter] = []
    for item in wrt:
        if isinstance(item, Parameter):
            columns.append(item)
            continue
        group, _, rest = str(item).partition(":")
        if group not in PARAMETER_GROUPS:
            raise OptionError(f"unknown parameter {item!r} (groups: {', '.join(PARAMETER_GROUPS)})", field="wrt")
        columns.extend(_group(model, group, rest.split(":") if rest else None))
    names = [c.name for c in columns]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise OptionError(f"parameter(s) asked for twice: {', '.join(repeated)}", field="wrt")
    return columns


def _group(model, group: str, keys: list | None) -> list[Parameter]:
    trunk = model.trunk
    actuators = trunk.actuators
    cables = list(actuators.names[:actuators.n_cables])
    tendons = actuators.stroke_driven

    def cable(key: str, tendon_only: bool) -> int:
        if key not in cables:
            raise OptionError(f"unknown cable {key!r} (cables: {', '.join(cables) or 'none'})", field="wrt")
        index = cables.index(key)
        if tendon_only and not tendons[index]:
            raise OptionError(f"{group} applies to stroke-driven tendons; {key!r} is tension-driven", field="wrt")
        return index

    if group == "actuation":
        names = list(actuators.names)
        if keys is None:
            return [Parameter(f"actuation:{n}", group, i) for i, n in enumerate(names)]
        if len(keys) != 1 or keys[0] not in names:
            raise OptionError(f"unknown actuator {':'.join(keys)!r} (actuators: {', '.join(names) or 'none'})",
                              field="wrt")
        return [Parameter(f"actuation:{keys[0]}", group, names.index(keys[0]))]
    if group == "gravity":
        axes = AXES if keys is None else keys
        if any(a not in AXES for a in axes) or (keys is not None and len(keys) != 1):
            raise OptionError(f"gravity's axes are x, y, z (got {':'.join(keys)!r})", field="wrt")
        return [Parameter(f"gravity:{a}", group, 0, AXES.index(a)) for a in axes]
    if group in ("dead", "follower"):
        n_vertebrae = trunk.frames.vertebra.size
        if keys is None:
            vertebrae, components = range(1, n_vertebrae), WRENCH
        else:
            try:
                vertebra = int(keys[0])
            except ValueError:
                raise OptionError(f"{group} loads are named {group}:<vertebra>[:<component>], got {keys!r}",
                                  field="wrt") from None
            if not -n_vertebrae <= vertebra < n_vertebrae or len(keys) > 2:
                raise OptionError(f"vertebra {keys[0]} out of range (0..{n_vertebrae - 1}, or negative from the end)",
                                  field="wrt")
            vertebrae = [vertebra % n_vertebrae]
            components = WRENCH if len(keys) == 1 else keys[1:]
            if any(c not in WRENCH for c in components):
                raise OptionError(f"a {group} load's components are {', '.join(WRENCH)}", field="wrt")
        return [Parameter(f"{group}:{v}:{c}", group, int(trunk.frames.vertebra[v]), WRENCH.index(c))
                for v in vertebrae for c in components]
    if group in ("cable_stiffness", "pretension", "hole_radius", "hole_angle"):
        tendon_only = group in ("cable_stiffness", "pretension")
        if keys is None:
            return [Parameter(f"{group}:{n}", group, i) for i, n in enumerate(cables)
                    if tendons[i] or not tendon_only]
        return [Parameter(f"{group}:{keys[0]}", group, cable(":".join(keys), tendon_only))]
    # stiffness_scale
    n_segments = len(trunk.scene.segments)
    scalable = _scalable_segments(model)
    if keys is None:
        return [Parameter(f"stiffness_scale:{s}", group, s) for s in range(n_segments) if scalable[s]]
    try:
        segment = int(keys[0])
    except ValueError:
        raise OptionError(f"stiffness scales are named stiffness_scale:<segment>, got {keys!r}", field="wrt") from None
    if not -n_segments <= segment < n_segments or len(keys) != 1:
        raise OptionError(f"segment {keys[0]} out of range (0..{n_segments - 1})", field="wrt")
    segment %= n_segments
    if not scalable[segment]:
        raise OptionError(f"segment {segment} has cavities: a stiffness scale applies to segments without cavities "
                          "only", field="wrt")
    return [Parameter(f"stiffness_scale:{segment}", group, segment)]


def _scalable_segments(model) -> np.ndarray:
    """Which segments take a stiffness scale (those whose links serve no chamber's cavity)."""
    trunk = model.compiled
    current = model.parameters.stiffness_scale
    scalable = np.zeros(current.size, bool)
    for s in range(current.size):
        if not np.any(trunk.links.segment == s):
            continue
        scale = current.copy()
        scale[s] *= 2.0
        try:
            reparameterise(trunk, model.parameters.replace(stiffness_scale=scale))
        except OptionError:
            continue
        scalable[s] = True
    return scalable


# ------------------------------------------------------------------ the sensitivities
def sensitivities(model, state, actuation=None, *, wrt: Iterable[str] = PARAMETER_GROUPS,
                  outputs: Iterable[str] = OUTPUTS, method: str = "auto") -> Sensitivities:
    """Sensitivities at the equilibrium ``state`` (a :class:`~vertebra.solver.state.State` or a
    solve's result, whose actuation is then the default) of ``model`` under its current
    parameters (module docstring). ``wrt``: parameter groups or names (:func:`parameters_of`);
    ``outputs``: names among :data:`OUTPUTS`; ``method``: "direct" (gives ``dq``), "adjoint"
    (no ``dq``) or "auto" (adjoint when there are fewer output rows than parameters). The state
    must be an equilibrium (its residual is not checked: a state off equilibrium gives the
    derivatives of nothing in particular); a singular tangent (a limit point) is an error."""
    start = time.perf_counter()
    if hasattr(state, "state") and hasattr(state, "actuation"):        # a StaticResult
        if actuation is None:
            actuation = state.actuation
        state = state.state
    values = model.actuation(actuation)
    outputs = _outputs(outputs)
    _check_method(method)
    columns = parameters_of(model, wrt)
    trunk = model.trunk
    ev = evaluate(trunk, state, model.loads(values, 1.0))
    lin = outputs_module.linearise(trunk, state, values, model.loads, previous=ev)
    _check_factor(lin)
    local = _Local(model, Fixed.of_state(trunk, state, ev, lin), values[trunk.actuators.n_cables:], ev.links)
    forces, explicit, differenced = local.explicit(columns, outputs)          # −∂g/∂p, ∂y/∂p
    forces, explicit = forces[0], {name: value[0] for name, value in explicit.items()}
    jacobians = {name: local.output_jacobian(name)[0] for name in outputs}   # ∂y/∂q
    rows = sum(j.shape[0] for j in jacobians.values())
    if method == "auto":
        method = "adjoint" if rows < len(columns) else "direct"
    timings = {"explicit_s": time.perf_counter() - start}
    dq = None
    if method == "direct":
        dq = lin.solve(np.asfortranarray(forces)) if columns else np.zeros((trunk.n_dof, 0))
        result = {name: jacobians[name] @ dq + explicit[name] for name in outputs}
    else:
        stacked = np.vstack([jacobians[name] for name in outputs]) if outputs else np.zeros((0, trunk.n_dof))
        adjoint = transpose_solve(lin.factor, np.asfortranarray(stacked.T)) if rows else stacked.T
        result = _split(adjoint.T @ forces, explicit, outputs)
    timings["total_s"] = time.perf_counter() - start
    return Sensitivities(tuple(c.name for c in columns), result, dq, method, tuple(trunk.effectors.names),
                         tuple(differenced), timings)


@dataclass
class BatchSensitivities(Sensitivities):
    """:class:`Sensitivities` of B equilibria (:func:`batch_sensitivities`), every array with a
    leading sample axis: ``dq`` (B, n_dof, P) (None on the adjoint route), ``outputs``: name →
    (B, n_out, P); ``single`` (B,) marks the samples whose sensitivities the single
    :func:`sensitivities` gave (``why``: sample → the reason), the others come from the batched
    factors."""

    single: np.ndarray | None = None
    why: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return 0 if self.single is None else self.single.size


def batch_sensitivities(model, strains, actuation, *, wrt: Iterable[str] = PARAMETER_GROUPS,
                        outputs: Iterable[str] = OUTPUTS, method: str = "auto", states=None,
                        chunk: int | None = None) -> BatchSensitivities:
    """The :func:`sensitivities` of B equilibria at once: link strains ``strains`` (B, n_links, 6)
    under ``actuation`` (B, n_actuators), from the batched evaluation, tangent and factor of
    :mod:`vertebra.solver.batch` (each sample's band Cholesky, the tendons' Woodbury term) and the same
    explicit terms, evaluated for all samples together. The results are the single route's to
    rounding (the sums are taken in another order).

    A sample leaves the batch for the single :func:`sensitivities` (``single``, ``why``) where the
    batch does not follow it: a band that is not positive definite (the single route's LU or
    low-rank inertia test), strains that are not finite or not carried by the state (``states[i]``
    then gives its state), dead moments or follower loads (unsymmetric tangents), cable friction,
    contacts, and chamber volumes asked with respect to a chamber's pressure (a central difference
    per sample). Errors of those samples (a singular tangent) are raised as by the single route.
    ``chunk``: samples per batch (default: a working memory of about
    :data:`~vertebra.solver.batch.MEMORY_BUDGET`)."""
    start = time.perf_counter()
    trunk = model.trunk
    strains = np.asarray(strains, float)
    actuation = np.asarray(actuation, float)
    B = strains.shape[0]
    if strains.shape != (B, trunk.links.count, 6) or actuation.shape != (B, len(trunk.actuators.names)):
        raise OptionError(f"strains must be (samples, {trunk.links.count}, 6) and the actuation (samples, "
                          f"{len(trunk.actuators.names)}); got {strains.shape} and {actuation.shape}", field="strains")
    outputs = _outputs(outputs)
    _check_method(method)
    columns = parameters_of(model, wrt)
    P = len(columns)
    n_cables = trunk.actuators.n_cables
    sizes = _output_sizes(trunk)
    rows = sum(sizes[name] for name in outputs)
    if method == "auto":
        method = "adjoint" if rows < P else "direct"
    result = {name: np.zeros((B, sizes[name], P)) for name in outputs}
    dq = np.zeros((B, trunk.n_dof, P)) if method == "direct" else None
    why: dict = {}
    everywhere = None
    if trunk.loads.unsymmetric:
        everywhere = "dead moments or follower loads (an unsymmetric tangent: LU factors)"
    elif np.any(trunk.actuators.friction):
        everywhere = "cable friction"
    elif trunk.contact is not None:
        everywhere = "contacts"
    elif "chamber_volumes" in outputs and any(c.group == "actuation" and c.index >= n_cables for c in columns):
        everywhere = "chamber volumes by a pressure (a central difference per sample)"
    finite = np.all(np.isfinite(strains.reshape(B, -1)), 1)
    if everywhere is not None:
        why.update({i: everywhere for i in range(B)})
    else:
        why.update({i: "strains not finite" for i in np.flatnonzero(~finite).tolist()})
    differenced = []
    batched = np.flatnonzero(finite) if everywhere is None else np.zeros(0, int)
    if batched.size and P:
        extra = (3 * P + rows + (3 * P if method == "direct" else 2 * rows)) * trunk.n_dof
        size = chunk if chunk is not None else batch_module.chunk_size(trunk, extra=extra)
        context = batch_module._Context(trunk)
        for k in range(0, batched.size, size):
            at = batched[k:k + size]
            ok, found, terms, differenced = _batch_chunk(model, context, strains[at], actuation[at], columns,
                                                         outputs, method)
            for i in at[~ok].tolist():
                why[i] = "the band is not positive definite (or not carried)"
            good = at[ok]
            if dq is not None:
                dq[good] = terms[ok]
            for name in outputs:
                result[name][good] = found[name][ok]
    single = np.zeros(B, bool)
    single[list(why)] = True
    for i in sorted(why):
        state = states[i] if states is not None else None
        if state is None:
            if not finite[i]:
                raise OptionError(f"sample {i}: its strains are not finite and no state was given", field="states")
            state = compose_state(trunk.rest_state.quaternions[0], trunk.rest_state.positions[0], strains[i].copy())
        one = sensitivities(model, state, actuation[i], wrt=columns, outputs=outputs, method=method)
        if dq is not None:
            dq[i] = one.dq
        for name in outputs:
            result[name][i] = one.outputs[name]
        differenced = list(one.differenced) or differenced
    return BatchSensitivities(tuple(c.name for c in columns), result, dq, method, tuple(trunk.effectors.names),
                              tuple(differenced), {"total_s": time.perf_counter() - start}, single, why)


def _batch_chunk(model, context, strains, actuation, columns, outputs, method):
    """One chunk of :func:`batch_sensitivities`: which samples the batch serves, their outputs'
    derivatives, ``dq`` (direct route) and the differenced parameters."""
    trunk = model.trunk
    B = strains.shape[0]
    with np.errstate(all="ignore"):
        states, carried = batch_module.compose(trunk, strains)
        ev = batch_module.evaluate(context, states, batch_module.Loads.of(trunk, actuation, np.ones(B)))
        factor = batch_module.tangent(context, ev).factor()
    ok = factor.ok & carried & np.isfinite(ev.energy)
    local = _Local(model, Fixed.of_batch(context, states, ev))
    forces, explicit, differenced = local.explicit(columns, outputs)        # (B, n_dof, P), (B, n_out, P)
    jacobians = {name: local.output_jacobian(name) for name in outputs}
    with np.errstate(all="ignore"):
        if method == "direct":
            dq = factor.solve(forces)
            found = {name: jacobians[name] @ dq + explicit[name] for name in outputs}
        else:                                           # (a symmetric tangent: Kᵀ = K)
            stacked = np.concatenate([np.broadcast_to(jacobians[name], (B,) + jacobians[name].shape[-2:])
                                      for name in outputs], 1)
            dq = None
            found = _split(factor.solve(stacked.mT).mT @ forces, explicit, outputs)
    if dq is not None:
        ok &= np.all(np.isfinite(dq.reshape(B, -1)), 1)
    return ok, found, dq, differenced


def _outputs(outputs) -> tuple:
    outputs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
    unknown = [name for name in outputs if name not in OUTPUTS]
    if unknown:
        raise OptionError(f"unknown output(s) {', '.join(map(repr, unknown))} (outputs: {', '.join(OUTPUTS)})",
                          field="outputs")
    return outputs


def _check_method(method: str) -> None:
    if method not in ("auto", "direct", "adjoint"):
        raise OptionError(f"method must be 'auto', 'direct' or 'adjoint', not {method!r}", field="method")


def _output_sizes(trunk) -> dict:
    n_frames, actuators = trunk.frames.count, trunk.actuators
    return {"frame_positions": 3 * n_frames, "frame_rotations": 3 * n_frames,
            "effector_positions": 3 * len(trunk.effectors.names), "cable_tensions": actuators.n_cables,
            "cable_strokes": actuators.n_cables, "chamber_volumes": actuators.n_chambers}


def _split(total: np.ndarray, explicit: dict, outputs: tuple) -> dict:
    """The adjoint route's stacked ``Λᵀ ∂g/∂p`` (…, rows, P) split by output, plus ``∂y/∂p``."""
    result, at = {}, 0
    for name in outputs:
        n = explicit[name].shape[-2]
        result[name] = total[..., at:at + n, :] + explicit[name]
        at += n
    return result


def _check_factor(lin) -> None:
    """Refuse a state whose tangent is singular: the linearisation then factors a shifted tangent,
    and the equilibrium has no derivative there (a limit point, or a trunk held by nothing)."""
    if lin.shift != 0.0:
        raise ConvergenceError("the tangent stiffness is singular at this state: the equilibrium has no "
                               "sensitivities there (a limit point)")


def transpose_solve(factor, rhs: np.ndarray) -> np.ndarray:
    """``K⁻ᵀ rhs`` with the factor of ``K`` (a banded Cholesky or LU, possibly with the tendons'
    symmetric low-rank term beside the band: ``(A + U D Uᵀ)ᵀ = Aᵀ + U D Uᵀ``, Woodbury with
    ``Aᵀ``)."""
    if isinstance(factor, LowRankFactor):
        y = transpose_solve(factor.band, rhs)
        Zt = factor.Z if factor.band.pivots is None else transpose_solve(factor.band, factor.U)
        return y - Zt @ lu_solve(factor.capacitance, factor.U.T @ y, trans=1, check_finite=False)
    if not isinstance(factor, BandedFactor):
        raise TypeError(f"cannot solve with the transpose of a {type(factor).__name__}")
    if factor.pivots is None:                                   # Cholesky: symmetric
        return factor.solve(rhs)
    x, info = dgbtrs(factor.data, factor.kd, factor.kd, rhs, factor.pivots, trans=1)
    if info:
        raise np.linalg.LinAlgError(f"banded transposed solve failed (LAPACK info {info})")
    return x


@dataclass
class Fixed:
    """What the explicit terms and the outputs' Jacobians read at B fixed equilibria (leading
    sample axis B): from one state's evaluation and linearisation (:meth:`of_state`) or from a
    batch's evaluation (:meth:`of_batch`)."""

    actuator_forces: np.ndarray          # (B, n_act, n_dof) ∂r/∂λ: −∂L/∂q, −k ∂L/∂q (taut), chambers' Jaᵀ
    actuator_jacobian: np.ndarray        # (B, n_act, n_dof) ∂L/∂q of the cables, ∂ΔV/∂q of the chambers
    effector_jacobian: np.ndarray        # (B, 3·n_effectors, n_dof)
    link_gradient: np.ndarray            # (B, n_links, 12) the links' energy gradient on their two frames
    positions: np.ndarray                # (B, N, 3)
    rotations: np.ndarray                # (B, N, 3, 3)
    pieces: CablePieces | None           # the B·m cable pieces (None: not evaluated, every cable slack)
    piece_tension: np.ndarray | None     # (B, m) every piece's tension (None: all slack)
    elongation: np.ndarray               # (B, n_cables) the stroke-driven tendons' elongation (else 0)
    lever: np.ndarray | None             # (B, N, 3) R s (None: computed when asked)

    @classmethod
    def of_state(cls, trunk, state, ev: Evaluation, lin) -> "Fixed":
        record = state.carried_strains()
        rotations = record.chain.rotations if record is not None else qmatrix(state.quaternions)
        elongation = np.zeros(trunk.actuators.n_cables)
        tendons = ev.load.tendons
        if tendons is not None:
            elongation[tendons.cables] = ev.parts.elongation
        piece_tension = ev.parts.piece_tension if ev.parts is not None else None
        return cls(lin.actuator_forces.T[None], lin.actuator_jacobian[None], lin.effector_jacobian[None],
                   ev.link_gradient[None], state.positions[None], rotations[None], ev.pieces,
                   None if piece_tension is None else piece_tension[None], elongation[None],
                   None if ev.lever is None else ev.lever[None])

    @classmethod
    def of_batch(cls, context, states, ev) -> "Fixed":
        trunk = context.trunk
        B = len(states)
        jacobian, forces = batch_module.actuator_jacobians(context, states, ev)
        elongation = np.zeros((B, trunk.actuators.n_cables))
        if ev.load.tendons is not None:
            elongation[:, ev.load.tendons[0]] = ev.elongation
        return cls(forces, jacobian, batch_module.effector_jacobian(trunk, states.rotations),
                   ev.link_gradient.reshape(B, trunk.links.count, 12), states.positions, states.rotations, ev.pieces,
                   ev.piece_tension, elongation, ev.lever)

    @property
    def count(self) -> int:
        return self.positions.shape[0]


class _Local:
    """The explicit derivatives at B fixed equilibria (:class:`Fixed`), every array with a leading
    sample axis. ``pressures`` and ``links``: the chambers' pressures and the link kinematics of a
    single state (its own pressure term of the volume growth, :meth:`_pressure_term`; None for a
    batch)."""

    def __init__(self, model, fixed: Fixed, pressures: np.ndarray | None = None, links=None):
        self.model, self.trunk, self.fixed, self.pressures, self.links = model, model.trunk, fixed, pressures, links
        actuators = self.trunk.actuators
        self.n_cables, self.n_chambers = actuators.n_cables, actuators.n_chambers
        self.elongation = fixed.elongation                       # (B, n_cables)
        self.taut = (fixed.elongation > 0.0) & actuators.stroke_driven[:self.n_cables]
        self.stiffness = actuators.cable_stiffness

    # -------------------------------------------------------------- ∂y/∂q
    def output_jacobian(self, name: str) -> np.ndarray:
        """``∂y/∂q`` (B or 1, n_out, n_dof)."""
        trunk, fixed = self.trunk, self.fixed
        n_frames, n_dof = trunk.frames.count, trunk.n_dof
        if name in ("frame_positions", "frame_rotations"):
            jacobian = np.zeros((n_frames, 3, n_frames - 1, 6))
            shift = 0 if name == "frame_positions" else 3
            free = np.arange(1, n_frames)
            jacobian[free, :, free - 1, shift:shift + 3] = np.eye(3)
            return jacobian.reshape(1, 3 * n_frames, n_dof)
        if name == "effector_positions":
            return fixed.effector_jacobian
        strokes = fixed.actuator_jacobian[:, :self.n_cables]
        if name == "cable_strokes":
            return strokes
        if name == "cable_tensions":                      # taut tendons: τ = k (L − L0 + s) + T0
            return (self.stiffness * self.taut)[:, :, None] * strokes
        return fixed.actuator_jacobian[:, self.n_cables:]   # chamber_volumes: ∂ΔV/∂q

    # -------------------------------------------------------------- ∂g/∂p and ∂y/∂p
    def explicit(self, columns: list[Parameter], names: tuple) -> tuple[np.ndarray, dict, list]:
        """``−∂g/∂p`` on the free frames (B, n_dof, P), ``∂y/∂p`` per output (B, n_out, P) and
        the parameters whose terms are differences."""
        trunk, fixed = self.trunk, self.fixed
        B, n_frames, n_dof, P = fixed.count, trunk.frames.count, trunk.n_dof, len(columns)
        sizes = _output_sizes(trunk)
        explicit = {name: np.zeros((B, sizes[name], P)) for name in names}
        tensions = explicit.get("cable_tensions")
        forces = np.zeros((B, n_frames, 6, P))                       # −∂g/∂p on every frame
        free = forces[:, 1:].reshape(B, n_dof, P)
        strokes = fixed.actuator_jacobian[:, :self.n_cables]         # ∂L/∂q (B, n_cables, n_dof)
        stroke_driven = trunk.actuators.stroke_driven
        differenced = []
        lever = None
        for j, column in enumerate(columns):
            group, i = column.group, column.index
            if group == "actuation":
                free[:, :, j] = fixed.actuator_forces[:, i]
                if tensions is not None and i < self.n_cables:
                    tensions[:, i, j] = self.stiffness[i] * self.taut[:, i] if stroke_driven[i] else 1.0
                if i >= self.n_cables and "chamber_volumes" in explicit:
                    explicit["chamber_volumes"][:, :, j] = self._pressure_term(i - self.n_cables)
            elif group == "gravity":
                if lever is None:
                    lever = self._lever()
                unit = np.eye(3)[column.component]
                forces[:, :, :3, j] = trunk.frames.mass[:, None] * unit        # −∂(−m g)/∂g
                forces[:, :, 3:, j] = lever @ hat(unit)                        # −∂(−(R s) × g)/∂g
            elif group == "dead":
                forces[:, i, column.component, j] = 1.0
            elif group == "follower":                        # −∂(−R e)/∂p = R e, in the frame's axes
                c = column.component
                forces[:, i, 3 * (c // 3):3 * (c // 3) + 3, j] = fixed.rotations[:, i, :, c % 3]
            elif group == "cable_stiffness":                 # ∂τ/∂k = e − T0/k while taut
                rate = (self.elongation[:, i] - trunk.actuators.pretension[i] / self.stiffness[i]) * self.taut[:, i]
                free[:, :, j] = -rate[:, None] * strokes[:, i]
                if tensions is not None:
                    tensions[:, i, j] = rate
            elif group == "pretension":                      # ∂τ/∂T0 = 1 while taut
                taut = self.taut[:, i].astype(float)
                free[:, :, j] = -taut[:, None] * strokes[:, i]
                if tensions is not None:
                    tensions[:, i, j] = taut
            elif group == "stiffness_scale":
                forces[:, :, :, j] = -self._link_forces(i) / self.model.parameters.stiffness_scale[i]
        for group in ("hole_radius", "hole_angle"):         # each group's columns at once
            mine = [j for j, column in enumerate(columns) if column.group == group]
            if not mine:
                continue
            gradient, terms = self._hole_derivatives(group, np.array([columns[j].index for j in mine]))
            free[:, :, mine] = -gradient
            for name in ("cable_tensions", "cable_strokes"):
                if name in explicit:
                    explicit[name][:, :, mine] = terms[name]
        if "chamber_volumes" in explicit and trunk.links.fitted:     # (linear entries: exact)
            differenced.extend(c.name for c in columns if c.group == "actuation" and c.index >= self.n_cables)
        return np.ascontiguousarray(free), explicit, differenced

    def _lever(self) -> np.ndarray:
        """``R s`` (B, N, 3): every frame's first mass moment in world axes."""
        fixed = self.fixed
        if fixed.lever is not None:
            return fixed.lever
        return (fixed.rotations @ self.trunk.frames.moment[:, :, None])[..., 0]

    def _link_forces(self, segment: int) -> np.ndarray:
        """The gradient (B, N, 6) of the links' energies of ``segment``."""
        trunk, g = self.trunk, self.fixed.link_gradient
        mine = (trunk.links.segment == segment)[:, None]
        out = np.zeros((g.shape[0], trunk.frames.count, 6))
        out[:, :-1] += np.where(mine, g[:, :, :6], 0.0)
        out[:, 1:] += np.where(mine, g[:, :, 6:], 0.0)
        return out

    def _pressure_term(self, chamber: int) -> np.ndarray:
        """``∂ΔV/∂p`` (1, n_chambers) of every chamber per unit pressure of ``chamber`` at the
        fixed strains of a single state: a central difference (exact for linear entries, whose
        growth is linear in the pressure)."""
        trunk, pressures = self.trunk, self.pressures
        if pressures is None or self.fixed.count != 1:
            raise ValueError("a chamber's pressure term is taken at a single state")
        upper = trunk.actuators.bounds[1][self.n_cables + chamber]
        scale = max(abs(pressures[chamber]), abs(upper) if np.isfinite(upper) else 0.0, PRESSURE_FLOOR)
        h = PRESSURE_STEP * scale
        links = self.links
        growth = []
        for sign in (1.0, -1.0):
            p = pressures.copy()
            p[chamber] += sign * h
            growth.append(volume_growth(trunk, links, p, tuple(e.prepare(p) for e in trunk.links.energies)))
        return ((growth[0] - growth[1]) / (2.0 * h))[None]

    def _hole_derivatives(self, group: str, cables_of: np.ndarray) -> tuple[np.ndarray, dict]:
        """``−∂g/∂p`` on the free frames (B, n_dof, J) and the cable tensions' and strokes'
        explicit terms (B, n_cables, J) for the hole parameters of ``group`` (``hole_radius`` or
        ``hole_angle``) of the cables ``cables_of`` (J distinct cables), all at once: a piece
        belongs to one cable, hence to one column. A change ``δh`` of a cable's hole offset (its
        vertebrae's axes) moves each of its pieces' ends by ``δs = R δh``; with ``d = P_b − P_a``,
        ``u = d/|d|`` and ``δu = (I − u uᵀ) δd / |d|`` the piece's length gradient
        ``[−u; −s_a × u; u; s_b × u]`` changes by
        ``[−δu; −δs_a × u − s_a × δu; δu; δs_b × u + s_b × δu]``, its length by ``u · δd`` (at the
        rest state likewise, for ``L0``), and a taut tendon's tension by ``k (δL − δL0)``."""
        trunk, fixed = self.trunk, self.fixed
        cables = trunk.cables
        B, N, J, m = fixed.count, trunk.frames.count, cables_of.size, cables.piece_a.size
        radius, angle = self.model.parameters.hole_radius[cables_of], self.model.parameters.hole_angle[cables_of]
        zero = np.zeros(J)
        if group == "hole_radius":
            dh = np.stack([np.cos(angle), np.sin(angle), zero], 1)
        else:
            dh = radius[:, None] * np.stack([-np.sin(angle), np.cos(angle), zero], 1)
        column_of = np.full(cables.n_cables, -1)
        column_of[cables_of] = np.arange(J)
        column = column_of[cables.owner]                          # (m,) the column of each piece, −1: none
        moved = np.flatnonzero(column >= 0)
        piece_dh = np.zeros((m, 3))
        piece_dh[moved] = dh[column[moved]]
        end_dh = np.repeat(piece_dh, 2, axis=0)[:, :, None]       # (2m, 3, 1): a and b ends alike
        pieces = fixed.pieces
        if pieces is None:                   # (every cable slack: the pieces were not evaluated)
            pieces = CablePieces.of_spans(*cables.spans(fixed.positions, fixed.rotations))
        ds = (fixed.rotations.take(cables.ends, axis=1) @ end_dh).reshape(B, m, 2, 3)
        ds_a, ds_b = ds[:, :, 0], ds[:, :, 1]
        dd = ds_b - ds_a
        rest_pieces, rest_ends = trunk.rest_routing
        rest_ds = (rest_ends @ end_dh).reshape(m, 2, 3)
        rest_dd = rest_ds[:, 1] - rest_ds[:, 0]
        u = pieces.u.reshape(B, m, 3)
        along = np.add.reduce(u * dd, -1)                         # (B, m) u · δd
        du = (dd - u * along[..., None]) / pieces.length.reshape(B, m, 1)
        offsets = pieces.offsets.reshape(B, m, 6)
        s_a, s_b = offsets[..., :3], offsets[..., 3:]
        d_length = np.zeros((B, cables.n_cables))
        for c in cables_of.tolist():
            d_length[:, c] = np.add.reduce(along[:, cables.owner == c], 1)
        d_rest = np.bincount(cables.owner, np.einsum("ij,ij->i", rest_pieces.u, rest_dd), minlength=cables.n_cables)
        d_stroke = np.zeros((B, cables.n_cables, J))
        d_stroke[:, cables_of, np.arange(J)] = (d_length - d_rest)[:, cables_of]
        d_tension = (self.stiffness * self.taut)[:, :, None] * d_stroke
        gradient = np.zeros((B, N, 6, J))
        if fixed.piece_tension is not None and moved.size:
            tension = fixed.piece_tension[:, moved, None]
            d_unit = np.concatenate([-du[:, moved], -_cross(ds_a[:, moved], u[:, moved]) - _cross(s_a[:, moved],
                                                                                                 du[:, moved]),
                                     du[:, moved], _cross(ds_b[:, moved], u[:, moved]) + _cross(s_b[:, moved],
                                                                                              du[:, moved])], -1)
            ends = np.stack([2 * moved, 2 * moved + 1], 1).reshape(-1)         # the moved pieces' ends, a then b
            per_end = (tension * d_unit).reshape(B, 2 * moved.size, 6)
            targets = cables.ends[ends] * J + np.repeat(column[moved], 2)      # (frame, column) of each end
            spread = scatter_rows(targets, per_end.transpose(1, 0, 2).reshape(2 * moved.size, 6 * B), N * J)
            gradient += spread.reshape(N, J, B, 6).transpose(2, 0, 3, 1)
        if self.taut.any():
            gradient[:, 1:] += (fixed.actuator_jacobian[:, :self.n_cables].mT @ d_tension).reshape(B, N - 1, 6, J)
        return gradient[:, 1:].reshape(B, -1, J), {"cable_tensions": d_tension, "cable_strokes": d_stroke}


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` over the last axis (numpy's ``cross`` costs more in set-up than in work on small
    arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)
