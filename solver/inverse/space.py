"""Constraint space of the inverse model (paper §IV, eqs. 10–12): where every QP is posed.

A :class:`ConstraintSpace` holds what stays fixed for one robot — the actuator box, the
actuator-displacement limits, the effector weights and the regulariser — validated once in
its constructor. Each linearisation of the model at a state ``q`` with actuation ``λ0``
(out-of-balance force ``r``, banded factor of ``K``, actuator forces ``B``, Jacobians
``Ja``, ``Je``; docs/solver-api.md) is projected into it by one banded solve with
``1 + n_act`` right-hand sides, ``X = K⁻¹[r, B]``::

    dq(λ)  = K⁻¹r + K⁻¹B (λ − λ0)                                    (paper eq. 10)
    δe(λ)  = e − target + Je K⁻¹r − W_ea λ0 + W_ea λ,  W_ea = Je K⁻¹B  (paper eq. 11)
    δa(λ)  = a + Ja K⁻¹r − W_aa λ0 + W_aa λ,           W_aa = Ja K⁻¹B  (paper eq. 12)

giving a :class:`ConstraintProblem` (the space plus ``W_ea``, ``δe_free``, ``W_aa``,
``δa_free`` and ``λ0``), whose constructor checks shapes and that the values are finite.
A non-finite linearisation is a numerical failure (:class:`ConvergenceError`); bad
arguments are :class:`OptionError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vertebra.core.errors import ConvergenceError, OptionError

__all__ = ["ConstraintSpace", "ConstraintProblem", "Projection", "DEFAULT_REGULARISATION"]

DEFAULT_REGULARISATION = 1e-8


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _bound(name: str, value, n: int) -> np.ndarray:
    """A read-only float vector of ``n`` bounds from a scalar or a sequence (±inf allowed)."""
    a = np.array(np.broadcast_to(value, (n,)) if np.ndim(value) == 0 else value, dtype=float).reshape(-1)
    if a.shape != (n,):
        raise OptionError(f"len({name}) = {a.size}, but it must be {n}", field=name)
    if np.isnan(a).any():
        raise OptionError(f"{name} contains NaN", field=name)
    return _read_only(a)


def _ordered(lower_name, lower, upper_name, upper):
    if (lower > upper).any():
        i = int(np.flatnonzero(lower > upper)[0])
        raise OptionError(f"{lower_name}[{i}] = {lower[i]} > {upper_name}[{i}] = {upper[i]}", field=lower_name)


@dataclass(frozen=True)
class ConstraintSpace:
    """Bounds, effector weights and regulariser of the inverse QPs of one robot.

    ``n_actuators`` efforts ``λ`` (cables then chambers) in ``[lambda_lower, lambda_upper]``;
    ``n_rows`` effector rows (three per effector) weighted by ``effector_weights`` (> 0);
    actuator displacements in ``[displacement_lower, displacement_upper]`` (±inf: none);
    ``regularisation`` the dimensionless actuation-energy weight ``ε`` (``solver.inverse.qp``);
    ``max_change`` the largest change of each effort in one control tick (≥ 0, inf: none).
    Scalars apply to every entry. Arrays are stored as read-only copies.
    """

    n_actuators: int
    n_rows: int
    lambda_lower: np.ndarray | float = -np.inf
    lambda_upper: np.ndarray | float = np.inf
    effector_weights: np.ndarray | float = 1.0
    displacement_lower: np.ndarray | float = -np.inf
    displacement_upper: np.ndarray | float = np.inf
    regularisation: float = DEFAULT_REGULARISATION
    max_change: np.ndarray | float = np.inf
    rows: np.ndarray = field(init=False, repr=False, compare=False)  # actuators with a finite displacement bound
    unit_weights: bool = field(init=False, repr=False, compare=False)  # every effector weight is 1

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        n, m = self.n_actuators, self.n_rows
        if not (isinstance(n, (int, np.integer)) and n >= 1):
            raise OptionError(f"must be an integer ≥ 1, got {n!r}", field="n_actuators")
        if not (isinstance(m, (int, np.integer)) and m >= 1):
            raise OptionError(f"must be an integer ≥ 1, got {m!r}", field="n_rows")
        lo, hi = _bound("lambda_lower", self.lambda_lower, n), _bound("lambda_upper", self.lambda_upper, n)
        _ordered("lambda_lower", lo, "lambda_upper", hi)
        dlo = _bound("displacement_lower", self.displacement_lower, n)
        dhi = _bound("displacement_upper", self.displacement_upper, n)
        _ordered("displacement_lower", dlo, "displacement_upper", dhi)
        w = _bound("effector_weights", self.effector_weights, m)
        if not (np.isfinite(w).all() and (w > 0).all()):
            raise OptionError(f"must be finite and > 0, got min {w.min()}", field="effector_weights")
        change = _bound("max_change", self.max_change, n)
        if (change < 0).any():
            raise OptionError(f"must be ≥ 0, got min {change.min()}", field="max_change")
        eps = float(self.regularisation)
        if not (math.isfinite(eps) and eps >= 0):
            raise OptionError(f"must be finite and ≥ 0, got {eps}", field="regularisation")
        for key, value in (("n_actuators", int(n)), ("n_rows", int(m)), ("lambda_lower", lo), ("lambda_upper", hi),
                           ("displacement_lower", dlo), ("displacement_upper", dhi), ("effector_weights", w),
                           ("regularisation", eps), ("max_change", change)):
            set_(key, value)
        set_("rows", _read_only(np.flatnonzero(np.isfinite(dlo) | np.isfinite(dhi))))
        set_("unit_weights", bool((w == 1.0).all()))

    @classmethod
    def of_model(cls, model, regularisation: float = DEFAULT_REGULARISATION) -> "ConstraintSpace":
        """The space of a compiled ``solver.TrunkModel``: its actuator and displacement bounds, its
        actuators' per-tick changes and its effector weights (one per effector, applied to its
        three rows)."""
        lo, hi = model.actuator_bounds
        dlo, dhi = model.displacement_bounds
        return cls(len(model.actuator_names), 3 * len(model.effector_names), lambda_lower=lo, lambda_upper=hi,
                   effector_weights=np.repeat(model.effector_weights, 3), displacement_lower=dlo,
                   displacement_upper=dhi, regularisation=regularisation, max_change=model.actuator_max_change)

    def tick_box(self, actuation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The λ box of one control tick from ``actuation``: the actuator limits intersected with
        ``actuation ± max_change``."""
        return (np.maximum(self.lambda_lower, actuation - self.max_change),
                np.minimum(self.lambda_upper, actuation + self.max_change))

    def project(self, lin, targets: np.ndarray, actuation: np.ndarray, box: tuple | None = None,
                damping: float = 0.0) -> "Projection":
        """Project a ``solver.Linearisation`` at ``actuation`` (``λ0``) with effector ``targets``
        (n_effectors, 3) into this space (module docstring). ``box`` (lower, upper) narrows the λ
        box of this one problem (a tick's, :meth:`tick_box`); ``damping`` weighs the change from
        ``actuation`` (:class:`ConstraintProblem`).

        With a Cholesky factor ``K = L Lᵀ`` (``lin.cholesky``) and ``B = Jaᵀ diag(c)``
        (``lin.force_scale``) every product is one of halves: one triangular sweep
        ``Z = L⁻¹[Jaᵀ, Jeᵀ, r]`` and ``[Ja; Je] K⁻¹ [B, r] = Z_aeᵀ Z diag(c, 1)`` — ``W_aa`` and
        ``W_ea`` without the second sweep, and ``W_aa diag(c)⁻¹`` symmetric by construction. Else
        one banded solve ``X = K⁻¹[r, B]`` and ``[Je; Ja] X``."""
        factor, scale = lin.cholesky, lin.force_scale
        if factor is not None and scale is not None:
            projection = self._project_halves(lin, factor, scale, targets, actuation, box, damping)
            if projection is not None:
                return projection
        # (also where the halves are not finite: here each array comes from one part of the
        # linearisation, so the constructor's message names the array a broken part feeds)
        Je, Ja, B = lin.effector_jacobian, lin.actuator_jacobian, lin.actuator_forces
        rhs = np.empty((B.shape[0], 1 + B.shape[1]), order="F")  # LAPACK's layout, solved in place
        rhs[:, 0] = lin.residual
        rhs[:, 1:] = B
        X = lin.solve(rhs, overwrite=True)
        JeX = Je.dot(X)
        JaX = Ja.dot(X)
        problem = self._problem(lin, JeX[:, 1:], JeX[:, 0], JaX[:, 1:], JaX[:, 0], JeX, JaX, targets, actuation, box,
                                damping)
        return Projection(problem, JeX[:, 0].copy(), X[:, 0], X[:, 1:], lin)

    def _project_halves(self, lin, factor, scale, targets, actuation, box, damping) -> "Projection | None":
        """:meth:`project` with the halves of a Cholesky factor; None when not finite."""
        Je, Ja = lin.effector_jacobian, lin.actuator_jacobian
        n_act = Ja.shape[0]
        rhs = np.empty((Ja.shape[1], n_act + Je.shape[0] + 1), order="F")   # LAPACK's layout, solved in place
        rhs[:, :n_act] = Ja.T
        rhs[:, n_act:-1] = Je.T
        rhs[:, -1] = lin.residual
        Z = factor.forward(rhs, overwrite=True)
        products = Z[:, :-1].T.dot(Z)                    # [Ja; Je] K⁻¹ [Jaᵀ, Jeᵀ, r]
        products[:, :n_act] *= scale                     # [Ja; Je] K⁻¹ [B, r] = [W_aa, Ja K⁻¹r; W_ea, Je K⁻¹r]
        # the free gaps, actuators' rows then effectors': [a; e − target] + [Ja; Je] K⁻¹r − [W_aa; W_ea] λ0
        free = np.concatenate((lin.actuator_displacements, (lin.effector_positions - targets).reshape(-1)))
        free += products[:, -1]
        W = products[:, :n_act]
        free -= W.dot(actuation)
        # finite unless a value is not (or the sum overflows): one sum over everything projected
        if not math.isfinite(float(np.add.reduce(products, None)) + float(free.dot(free))):
            return None
        problem = ConstraintProblem.projected(self, W[n_act:], free[n_act:], W[:n_act], free[:n_act], actuation, box,
                                              damping, stacked=(W, free, n_act))
        return Projection(problem, products[n_act:, -1], Z[:, -1], Z[:, :n_act] * scale, lin, (factor, Z[:, n_act:-1]))

    def _problem(self, lin, W_ea, JeKr, W_aa, JaKr, JeX, JaX, targets, actuation, box, damping) -> "ConstraintProblem":
        """The :class:`ConstraintProblem` of a projection by ``K⁻¹[r, B]``, checked finite by one sum
        over everything projected (when that is not finite, or overflows, the constructor's own
        check looks at each array and names the one that is not)."""
        # e − target + Je K⁻¹r − W_ea λ0 and a + Ja K⁻¹r − W_aa λ0
        delta_e_free = (lin.effector_positions - targets).reshape(-1)
        delta_e_free += JeKr
        delta_e_free -= W_ea.dot(actuation)
        delta_a_free = lin.actuator_displacements + JaKr
        delta_a_free -= W_aa.dot(actuation)
        if math.isfinite(float(JeX.sum()) + float(JaX.sum()) + float(delta_e_free.dot(delta_e_free)) +
                         float(delta_a_free.dot(delta_a_free))):
            return ConstraintProblem.projected(self, W_ea, delta_e_free, W_aa, delta_a_free, actuation, box, damping)
        return ConstraintProblem(self, W_ea, delta_e_free, W_aa, delta_a_free, actuation, box, damping)


_ONES: dict = {}  # n -> read-only ones(n), for row sums


def _ones(n: int) -> np.ndarray:
    a = _ONES.get(n)
    if a is None:
        a = _ONES[n] = _read_only(np.ones(n))
    return a


def _box(box, n: int) -> tuple:
    """``box`` as two ordered float arrays (lower ≤ upper) of ``n`` values without NaN
    (:class:`OptionError` otherwise)."""
    lower, upper = box
    if not (isinstance(lower, np.ndarray) and isinstance(upper, np.ndarray)):
        lower, upper = (_array(f"box[{k}]", b, (n,)) for k, b in enumerate(box))
    # (the smallest gap is NaN, never ≥ 0, when a bound is NaN)
    if lower.shape != (n,) or upper.shape != (n,) or not float(np.minimum.reduce(upper - lower)) >= 0.0:
        raise OptionError(f"must be two ordered arrays (lower ≤ upper) of {n} values without NaN", field="box")
    return lower, upper


def _array(name: str, value, shape: tuple) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != shape:
        raise OptionError(f"{name}.shape = {a.shape}, but it must be {shape}", field=name)
    return a


@dataclass(frozen=True)
class ConstraintProblem:
    """One linearised inverse step in a :class:`ConstraintSpace` (paper eqs. 11–12)::

        δe(λ) = δe_free + W_ea λ        δa(λ) = δa_free + W_aa λ

    ``W_ea`` (m×n) and ``delta_e_free`` (m) are required; ``W_aa`` (n×n) and ``delta_a_free``
    (n) come together and are needed when the space has displacement limits. ``lambda0`` (n)
    is the current actuation (the QP's warm start). ``box`` (lower, upper), when given, is this
    problem's λ box in place of the space's (a control tick's, :meth:`ConstraintSpace.tick_box`,
    inside the actuator limits); ``damping`` (≥ 0, needs ``lambda0``)
    the dimensionless weight of the change from ``lambda0`` (``solver.inverse.qp``). The arrays
    are used as given (not copied).
    """

    space: ConstraintSpace
    W_ea: np.ndarray
    delta_e_free: np.ndarray
    W_aa: np.ndarray | None = None
    delta_a_free: np.ndarray | None = None
    lambda0: np.ndarray | None = None
    box: tuple | None = None
    damping: float = 0.0

    def __post_init__(self):
        space = self.space
        n, m = space.n_actuators, space.n_rows
        W_ea = _array("W_ea", self.W_ea, (m, n))
        delta_e_free = _array("delta_e_free", self.delta_e_free, (m,))
        # Finite values: one sum of squares of the row sums and vectors, NaN or inf when any value
        # is (a finite value whose square overflows only sends the arrays to the element-wise check).
        rows = W_ea.dot(_ones(n))
        total = rows.dot(rows) + delta_e_free.dot(delta_e_free)
        W_aa = delta_a_free = lambda0 = None
        if (self.W_aa is None) != (self.delta_a_free is None):
            raise OptionError("W_aa and delta_a_free must be given together", field="W_aa")
        if self.W_aa is not None:
            W_aa = _array("W_aa", self.W_aa, (n, n))
            delta_a_free = _array("delta_a_free", self.delta_a_free, (n,))
            rows = W_aa.dot(_ones(n))
            total += rows.dot(rows) + delta_a_free.dot(delta_a_free)
        elif space.rows.size:
            raise OptionError("displacement limits need W_aa and delta_a_free", field="W_aa")
        if self.lambda0 is not None:
            lambda0 = _array("lambda0", self.lambda0, (n,))
            total += lambda0.dot(lambda0)
        arrays = (("W_ea", W_ea), ("delta_e_free", delta_e_free), ("W_aa", W_aa), ("delta_a_free", delta_a_free),
                  ("lambda0", lambda0))
        if not math.isfinite(total):
            for name, a in arrays:
                if a is not None and not np.isfinite(a).all():
                    if name == "lambda0":
                        raise OptionError("contains NaN or ±inf", field=name)
                    raise ConvergenceError(f"constraint projection: {name} contains NaN or ±inf "
                                           "(the linearisation is not finite)")
        for name, a in arrays:
            if a is not getattr(self, name):  # converted from another type
                object.__setattr__(self, name, a)
        if self.damping:
            if not (math.isfinite(self.damping) and self.damping > 0) or lambda0 is None:
                raise OptionError(f"must be finite and ≥ 0, with lambda0, got {self.damping}", field="damping")
        if self.box is not None:
            object.__setattr__(self, "box", _box(self.box, n))

    @classmethod
    def projected(cls, space: ConstraintSpace, W_ea, delta_e_free, W_aa, delta_a_free, lambda0, box=None,
                  damping: float = 0.0, stacked: tuple | None = None) -> "ConstraintProblem":
        """The problem of :meth:`ConstraintSpace.project`, whose arrays have the space's shapes by
        construction and have been checked finite there: stored as they are, without the
        constructor's conversions (``box`` is checked as there). ``stacked``: ``([W_aa; W_ea],
        [δa_free; δe_free], n_actuators)`` when the arrays are those rows of two stacked ones, so
        that :meth:`predict` takes one product."""
        problem = object.__new__(cls)
        problem.__dict__.update(space=space, W_ea=W_ea, delta_e_free=delta_e_free, W_aa=W_aa, delta_a_free=delta_a_free,
                                lambda0=lambda0, box=None if box is None else _box(box, space.n_actuators),
                                damping=damping, _stacked=stacked)
        return problem

    @property
    def n_actuators(self) -> int:
        return self.space.n_actuators

    @property
    def n_rows(self) -> int:
        return self.space.n_rows

    @property
    def lambda_lower(self) -> np.ndarray:
        """Lower bounds of the efforts in this step."""
        return self.space.lambda_lower if self.box is None else self.box[0]

    @property
    def lambda_upper(self) -> np.ndarray:
        """Upper bounds of the efforts in this step."""
        return self.space.lambda_upper if self.box is None else self.box[1]

    def start(self) -> np.ndarray:
        """The warm start ``λ0`` (zeros when none) inside the λ box."""
        l0 = np.zeros(self.n_actuators) if self.lambda0 is None else self.lambda0
        return np.minimum(np.maximum(l0, self.lambda_lower), self.lambda_upper)

    def predict(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Linearised effector gaps ``δe(λ)`` and actuator displacements ``δa(λ)`` (None without ``W_aa``)."""
        stacked = self.__dict__.get("_stacked")        # (a projection's: its rows of two stacked arrays)
        if stacked is not None:
            W, free, n = stacked
            both = free + W.dot(lam)
            return both[n:], both[:n]
        de = self.delta_e_free + self.W_ea.dot(lam)
        da = None if self.W_aa is None else self.delta_a_free + self.W_aa.dot(lam)
        return de, da


@dataclass
class Projection:
    """A linearisation projected into constraint space: the problem, the effectors' motion
    ``Je K⁻¹r`` towards the equilibrium under ``λ0``, and what a state change needs — ``K⁻¹r`` and
    ``K⁻¹B`` (``free``, ``per_actuator``), or with a Cholesky factor their halves ``L⁻¹r``,
    ``L⁻¹B`` and the factor whose ``L⁻ᵀ`` completes them (``halves``: the factor and
    ``L⁻¹Jeᵀ``)."""

    problem: ConstraintProblem
    Je_K_inv_r: np.ndarray     # (n_rows,)
    free: np.ndarray           # (n_dof,) K⁻¹r, or L⁻¹r
    per_actuator: np.ndarray   # (n_dof, n_actuators) K⁻¹B, or L⁻¹B
    lin: object = field(repr=False, default=None)     # the linearisation projected
    halves: tuple | None = field(repr=False, default=None)

    def state_change(self, actuation: np.ndarray, change: np.ndarray | None = None) -> np.ndarray:
        """``dq(λ) = K⁻¹r + K⁻¹B (λ − λ0)`` (paper eq. 10): the linearised motion to the
        equilibrium under ``actuation`` (``change``: ``λ − λ0`` when the caller has it)."""
        dq = self.free + self.per_actuator.dot(actuation - self.problem.lambda0 if change is None else change)
        return dq if self.halves is None else self.halves[0].backward(dq, overwrite=True)

    def effector_motion(self, force: np.ndarray) -> np.ndarray:
        """``Je K⁻¹ force`` (n_rows,): how far the effectors move under an out-of-balance
        ``force`` (n_dof,) by the linearisation's tangent."""
        if self.halves is None:
            return self.lin.effector_jacobian.dot(self.lin.solve(force))
        factor, Ze = self.halves
        return Ze.T.dot(factor.forward(force))
