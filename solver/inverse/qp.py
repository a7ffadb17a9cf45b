"""Constraint-space QP of the inverse model (paper §IV, eqs. 11–13).

After linearisation and projection into constraint space (paper eqs. 11–12) the
inverse step is a small dense problem in the actuator efforts ``λ`` (n actuators,
m = 3·effectors rows)::

    δe(λ) = δe_free + W_ea λ            predicted effector gaps      (paper eq. 11)
    δa(λ) = δa_free + W_aa λ            predicted actuator displacement (paper eq. 12)

    minimise   ½ ‖Wₑ^{1/2} δe(λ)‖²  +  ½ ρ Σᵢ dᵢ λᵢ²                 (paper eq. 13 + regulariser)
    subject to λ_lower ≤ λ ≤ λ_upper,   δa_lower ≤ δa(λ) ≤ δa_upper

The regulariser makes the answer unique when ``W_eaᵀ W_ea`` is only semi-definite
(16 tendons, one 3-D target). It is the **actuation energy** each actuator spends
on its own displacement, ``dᵢ λᵢ² = |W_aa,ii| λᵢ²`` (joules whatever the actuator:
N·m for a cable, Pa·m³ for a chamber), so it is invariant to the units of each
actuator and homogeneous across mixed cable/chamber actuation. ``ρ = ε·s`` with a
dimensionless ``ε`` (default 1e-8) and ``s = meanᵢ(Hᵢᵢ/dᵢ)`` (m²/J; ``H`` the
weighted Hessian of the effector term): every ratio ``Hᵢᵢ/dᵢ`` has the same units
for every actuator, and a mean (not a sum) does not grow with the number of
actuators. When ``W_aa`` is not given, ``dᵢ = Hᵢᵢ`` (Marquardt scaling), again
per-actuator unit invariant. ``ε`` is small enough that the fixed point of the
converged inverse is biased by ≈ ε × (effector motion) ≪ 1e-6 m (measured in
``benchmarks/bench_qp.py``), and large enough that the active-set solver sees a
Hessian with condition ≲ 1/ε.

Backends implement :class:`QPBackend` and register in ``BACKENDS``; adding one
touches one function here. The default ``"daqp"`` (exact dual active-set solver,
called directly for speed; chosen by ``benchmarks/bench_qp.py``), the paper's
projected ``"gauss-seidel"`` (pure numpy), and ``"qpsolvers:<name>"`` for any
solver ``qpsolvers`` knows (clarabel, osqp, proxqp, daqp, …).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

try:  # the clip ufunc itself (what np.clip calls, same results): its Python wrapper costs ~1 µs
    from numpy._core.umath import clip as _clip  # a call on the tiny vectors of the inverse step
except ImportError:  # pragma: no cover
    _clip = np.clip

__all__ = [
    "ConstraintProblem",
    "QuadraticForm",
    "ConstraintSolution",
    "QPBackend",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "DEFAULT_REGULARISATION",
    "register_backend",
    "get_backend",
    "available_backends",
    "quadratic_form",
    "solve_constraint_problem",
]

DEFAULT_REGULARISATION = 1e-8
DEFAULT_BACKEND = "daqp"


def _vector(name: str, value, n: int) -> np.ndarray:
    if np.ndim(value) == 0:
        v = float(value)
        if v != v:
            raise ValueError(f"{name} is NaN")
        return np.full(n, v)
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"len({name}) = {arr.size}, but it must be {n}")
    if np.isnan(arr).any():
        raise ValueError(f"{name} contains NaN")
    return arr


_ONES: dict = {}  # n -> read-only ones(n)
_vdot = np.vdot  # of a contiguous array: its flat view with itself


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class ConstraintProblem:
    """One linearised inverse step in constraint space (paper eqs. 11–13).

    ``W_ea`` (m×n) and ``delta_e_free`` (m) are required; ``effector_weights`` (m,
    one per effector row, > 0) default to one. ``lambda_lower``/``lambda_upper``
    bound the actuator efforts (±inf allowed). Actuator displacement bounds need
    ``W_aa`` (n×n) and ``delta_a_free`` (n). ``lambda0`` (n) is a warm start (the
    current actuation), ``regularisation`` the dimensionless ``ε`` above.
    """

    W_ea: np.ndarray
    delta_e_free: np.ndarray
    lambda_lower: np.ndarray | float = -np.inf
    lambda_upper: np.ndarray | float = np.inf
    effector_weights: np.ndarray | float = 1.0
    W_aa: np.ndarray | None = None
    delta_a_free: np.ndarray | None = None
    displacement_lower: np.ndarray | float = -np.inf
    displacement_upper: np.ndarray | float = np.inf
    lambda0: np.ndarray | None = None
    regularisation: float = DEFAULT_REGULARISATION
    _has_rows: bool = field(default=False, init=False, repr=False, compare=False)
    # derived from the bounds (here so that the controller's per-tick problems share them):
    # actuators with a finite displacement bound, and |λ_lower| where finite (else 0)
    _rows: np.ndarray = field(default=None, init=False, repr=False, compare=False)
    _lower_magnitude: np.ndarray = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        W_ea = np.asarray(self.W_ea, dtype=float)
        if W_ea.ndim != 2 or W_ea.shape[1] == 0:
            raise ValueError(f"W_ea must be a 2-D (m, n) array with n ≥ 1, got shape {W_ea.shape}")
        if not np.isfinite(W_ea).all():
            raise ValueError("W_ea contains non-finite values")
        m, n = W_ea.shape
        set_("W_ea", W_ea)
        de = _vector("delta_e_free", self.delta_e_free, m)
        if not np.isfinite(de).all():
            raise ValueError("delta_e_free contains non-finite values")
        set_("delta_e_free", de)
        lo = _vector("lambda_lower", self.lambda_lower, n)
        hi = _vector("lambda_upper", self.lambda_upper, n)
        if (lo > hi).any():
            i = int(np.flatnonzero(lo > hi)[0])
            raise ValueError(f"lambda_lower[{i}] = {lo[i]} > lambda_upper[{i}] = {hi[i]}")
        set_("lambda_lower", lo)
        set_("lambda_upper", hi)
        w = _vector("effector_weights", self.effector_weights, m)
        if not (np.isfinite(w).all() and (w > 0).all()):
            raise ValueError(f"effector_weights must be finite and > 0, got min {w.min()}")
        set_("effector_weights", w)
        if (self.W_aa is None) != (self.delta_a_free is None):
            raise ValueError("W_aa and delta_a_free must be given together")
        if self.W_aa is not None:
            W_aa = np.asarray(self.W_aa, dtype=float)
            if W_aa.shape != (n, n):
                raise ValueError(f"W_aa.shape = {W_aa.shape}, but it must be ({n}, {n})")
            if not np.isfinite(W_aa).all():
                raise ValueError("W_aa contains non-finite values")
            set_("W_aa", W_aa)
            da = _vector("delta_a_free", self.delta_a_free, n)
            if not np.isfinite(da).all():
                raise ValueError("delta_a_free contains non-finite values")
            set_("delta_a_free", da)
        dlo = _vector("displacement_lower", self.displacement_lower, n)
        dhi = _vector("displacement_upper", self.displacement_upper, n)
        if (dlo > dhi).any():
            i = int(np.flatnonzero(dlo > dhi)[0])
            raise ValueError(f"displacement_lower[{i}] = {dlo[i]} > displacement_upper[{i}] = {dhi[i]}")
        has_rows = bool(np.isfinite(dlo).any() or np.isfinite(dhi).any())
        if self.W_aa is None and has_rows:
            raise ValueError("displacement bounds need W_aa and delta_a_free")
        set_("displacement_lower", dlo)
        set_("displacement_upper", dhi)
        set_("_has_rows", has_rows)
        set_("_rows", np.flatnonzero(np.isfinite(dlo) | np.isfinite(dhi)))
        set_("_lower_magnitude", np.where(np.isfinite(lo), np.abs(lo), 0.0))
        if self.lambda0 is not None:
            l0 = _vector("lambda0", self.lambda0, n)
            set_("lambda0", np.where(np.isfinite(l0), l0, 0.0))
        eps = float(self.regularisation)
        if not (np.isfinite(eps) and eps >= 0):
            raise ValueError(f"regularisation must be finite and ≥ 0, got {eps}")
        set_("regularisation", eps)

    @property
    def n_actuators(self) -> int:
        return self.W_ea.shape[1]

    @property
    def n_rows(self) -> int:
        return self.W_ea.shape[0]

    def _relinearised(self, W_ea, delta_e_free, W_aa, delta_a_free, lambda0,
                      holders=None, owned=False) -> "ConstraintProblem | None":
        """This problem's bounds, weights and regulariser with a new linearisation, without
        re-validating what this (validated) problem already holds; ``None`` when the new
        arrays need the validation (then build a :class:`ConstraintProblem`, which raises
        the usual error or accepts them). For callers passing float arrays they built
        themselves (the controller, every tick). What is left to check is that the values
        are finite: one sum of squares per vector and of the row sums of each matrix, which
        is NaN or inf when any value is (a finite sum that overflows only sends the arrays
        to the full validation). Dot products, because a numpy reduction to a scalar costs
        ~2 µs on these small arrays and a dot ~0.4 µs. ``holders``: contiguous arrays holding
        every value of ``W_ea`` and ``W_aa`` (the controller's ``Je K⁻¹[r, B]`` and
        ``Ja K⁻¹[r, B]``), whose other values enter ``delta_e_free`` or ``delta_a_free`` (so a
        non-finite one makes a vector non-finite, which the validation rejects too): one sum
        of squares each replaces the row sums. ``owned``: nobody changes these arrays
        afterwards (then a solution's prediction ``δe`` may be computed when first read).
        """
        f64 = np.float64
        if (self.W_aa is None or W_aa is None or lambda0 is None
                or W_ea.shape != self.W_ea.shape or W_aa.shape != self.W_aa.shape
                or delta_e_free.shape != self.delta_e_free.shape
                or delta_a_free.shape != self.delta_a_free.shape or lambda0.shape != self.delta_a_free.shape
                or not (W_ea.dtype == W_aa.dtype == delta_e_free.dtype == delta_a_free.dtype
                        == lambda0.dtype == f64)):
            return None
        if holders is None:
            ones = _ONES.get(W_ea.shape[1])
            if ones is None:
                ones = _ONES[W_ea.shape[1]] = _read_only(np.ones(W_ea.shape[1]))
            e, a = W_ea.dot(ones), W_aa.dot(ones)  # row sums
            total = e.dot(e) + a.dot(a)
        else:
            total = 0.0
            for h in holders:
                total += _vdot(h, h)
        total += (delta_e_free.dot(delta_e_free) + delta_a_free.dot(delta_a_free) + lambda0.dot(lambda0))
        if not math.isfinite(total):  # a NaN or ±inf somewhere (or an overflow)
            return None
        new = object.__new__(ConstraintProblem)
        d = new.__dict__
        d.update(self.__dict__)
        d["W_ea"], d["delta_e_free"], d["W_aa"], d["delta_a_free"] = W_ea, delta_e_free, W_aa, delta_a_free
        d["lambda0"] = lambda0.copy()  # what the validated path stores (np.where of finite values)
        if owned:
            d["_owned"] = True
        return new

    def start(self) -> np.ndarray:
        """Warm start clipped into the λ box (zeros clipped when none is given)."""
        l0 = np.zeros(self.n_actuators) if self.lambda0 is None else self.lambda0
        return _clip(l0, self.lambda_lower, self.lambda_upper)

    def predict(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Linearised effector gaps and actuator displacements for efforts ``lam``."""
        de = self.delta_e_free + self.W_ea @ lam
        da = None if self.W_aa is None else self.delta_a_free + self.W_aa @ lam
        return de, da


@dataclass(frozen=True)
class QuadraticForm:
    """``½ λᵀPλ + qᵀλ + c`` with box ``lower ≤ λ ≤ upper`` and rows ``row_lower ≤ G λ ≤ row_upper``.

    ``G`` holds only the actuator-displacement rows with at least one finite bound.
    """

    P: np.ndarray
    q: np.ndarray
    c: float
    lower: np.ndarray
    upper: np.ndarray
    G: np.ndarray
    row_lower: np.ndarray
    row_upper: np.ndarray
    rows: np.ndarray  # actuator index of each row of G
    regularisation_weight: float  # ρ = ε·s, absolute
    energy_diagonal: np.ndarray  # d_i


def quadratic_form(problem: ConstraintProblem, displacement_lower=None, displacement_upper=None) -> QuadraticForm:
    """Build the QP of paper eq. 13 with the scale-free energy regulariser (module docstring)."""
    return _quadratic_form(problem, displacement_lower, displacement_upper)[0]


def _quadratic_form(problem: ConstraintProblem, displacement_lower, displacement_upper):
    """:func:`quadratic_form` and the weighted squared free gap ``δe_freeᵀ Wₑ δe_free`` (= 2c)."""
    P, q, gap2, rho, d, _ = _hessian(problem)
    dlo = problem.displacement_lower if displacement_lower is None else displacement_lower
    dhi = problem.displacement_upper if displacement_upper is None else displacement_upper
    if dlo is problem.displacement_lower and dhi is problem.displacement_upper:
        rows = problem._rows  # the problem's own bounds: rows known (empty without finite bounds)
    else:
        rows = (np.flatnonzero(np.isfinite(dlo) | np.isfinite(dhi))
                if (problem._has_rows or displacement_lower is not None) else np.zeros(0, dtype=int))
    if rows.size:
        G = problem.W_aa[rows]
        row_lower = dlo[rows] - problem.delta_a_free[rows]
        row_upper = dhi[rows] - problem.delta_a_free[rows]
    else:
        G = np.zeros((0, problem.n_actuators))
        row_lower = row_upper = np.zeros(0)
    return _new(QuadraticForm,
        P=P, q=q, c=0.5 * gap2, lower=problem.lambda_lower, upper=problem.lambda_upper,
        G=G, row_lower=row_lower, row_upper=row_upper, rows=rows,
        regularisation_weight=rho, energy_diagonal=d,
    ), gap2


def _hessian(problem: ConstraintProblem):
    """``P`` (with the regulariser), ``q``, ``δe_freeᵀ Wₑ δe_free``, ``ρ``, ``d`` and the view of
    ``P``'s diagonal (module docstring)."""
    w, de = problem.effector_weights, problem.delta_e_free
    Wsq = problem.W_ea * w[:, None]
    H = problem.W_ea.T @ Wsq
    q = Wsq.T @ de
    gap2 = float(de @ (w * de))
    n = H.shape[0]
    diagonal = H.reshape(-1)[:: n + 1]  # a view (H is a new C-contiguous array)
    if problem.W_aa is not None:
        d = np.abs(problem.W_aa.diagonal())
        h = diagonal  # read below before the regulariser is added: no copy needed
    else:
        h = diagonal.copy()  # H's diagonal before the regulariser is added
        d = h.copy()
    # An actuator with no own displacement (d = 0) would be left unregularised:
    # floor d relative to the others so the Hessian stays definite.
    values = d.tolist()  # no NaN in d: Python's max and min are what numpy's would be
    dmax = max(values) if values else 0.0
    floor = 1e-12 * dmax if dmax > 0 else 1.0
    if values and min(values) < floor:  # else np.maximum(d, floor) would return d's values (d is a new array)
        d = np.maximum(d, floor)
    s = float(np.add.reduce(h / d)) / n  # the mean (what ndarray.mean computes, without its wrapper)
    s = s if s > 0 else 1.0
    rho = problem.regularisation * s
    diagonal += rho * d  # P = H + ρ diag(d), symmetric by construction (Wᵀ diag(w) W)
    return H, q, gap2, rho, d, diagonal


def _new(cls, **fields):
    """An instance of the frozen dataclass ``cls`` from all its fields, without the generated
    ``__init__`` (one ``object.__setattr__`` per field: ~1 µs a QuadraticForm). For values this
    module computed itself; fields with a default may be left out."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


@dataclass(frozen=True)
class BackendOutput:
    actuation: np.ndarray
    iterations: int
    converged: bool
    status: str


class QPBackend(Protocol):
    """What an inverse QP solver provides. ``solve`` never raises for a feasible box."""

    name: str

    def solve(self, qp: QuadraticForm, start: np.ndarray, *, tolerance: float,
              max_iterations: int) -> BackendOutput: ...


@dataclass(frozen=True)
class ConstraintSolution:
    """Result of one constraint-space solve, with diagnostics."""

    actuation: np.ndarray  # λ (n,)
    delta_e: np.ndarray  # predicted effector gaps (m,)
    delta_a: np.ndarray | None  # predicted actuator displacements (n,)
    effector_error: float  # ‖δe‖ (m), unweighted
    objective: float
    stationarity: float  # projected-gradient step in effector units (m), 0 at a box-QP optimum; NaN with displacement rows
    iterations: int
    converged: bool
    status: str  # "optimal" | "max_iterations" | "relaxed" | backend status
    backend: str
    time_s: float
    active_lower: np.ndarray  # bool (n,)
    active_upper: np.ndarray
    active_displacement_lower: np.ndarray
    active_displacement_upper: np.ndarray
    displacement_relaxation: np.ndarray  # how far infeasible displacement bounds were widened (n,)
    regularisation_weight: float = 0.0
    extras: dict = field(default_factory=dict)

    def __getattr__(self, name):
        # Only reached for attributes not set: the diagnostics (objective, stationarity,
        # active sets) that solve_constraint_problem leaves to _Diagnostics until first read,
        # and for the controller's problems the prediction δe (_Prediction).
        d = self.__dict__
        key = "_diagnostics" if name in _DIAGNOSTICS else "_prediction" if name in _PREDICTION else None
        if key is not None:
            pending = d.get(key)
            if pending is not None:
                d.update(pending.values())
                d.pop(key, None)
            if name in d:
                return d[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


_DIAGNOSTICS = frozenset({"objective", "stationarity", "active_lower", "active_upper",
                          "active_displacement_lower", "active_displacement_upper"})
_PREDICTION = frozenset({"delta_e", "effector_error", "displacement_relaxation"})


class _Prediction:
    """``δe``, ``‖δe‖`` and the (zero) displacement relaxation of a box-only solve, computed
    when first read (the controller's real-time step reads none). Only for problems whose
    arrays nobody changes afterwards (:meth:`ConstraintProblem._relinearised` with ``owned``);
    ``lam`` is a copy of the answer."""

    __slots__ = ("lam", "problem")

    def __init__(self, problem, lam):
        self.problem, self.lam = problem, lam

    def values(self) -> dict:
        p, lam = self.problem, self.lam
        de = p.delta_e_free + p.W_ea @ lam
        return {"delta_e": de, "effector_error": math.sqrt(de.dot(de)), "displacement_relaxation": np.zeros(lam.size)}


class _Diagnostics:
    """Objective, stationarity and active sets of one solve, computed when one of them is
    first read (the controller's real-time step reads none; ~10 numpy calls saved a tick).
    Holds copies of what the caller could change in place afterwards."""

    __slots__ = ("lam", "lower", "upper", "lower_magnitude", "da", "dlo", "dhi", "P", "q", "c", "n_rows", "root")

    def __init__(self, problem, P, q, c, n_rows, lam, da, dlo, dhi, root):
        """``P``, ``q``, ``c``: the (unscaled) quadratic form, ``n_rows`` its displacement rows."""
        self.lam, self.root = lam.copy(), root
        self.P, self.q, self.c, self.n_rows = P, q, c, n_rows
        self.lower, self.upper = _kept(problem.lambda_lower), _kept(problem.lambda_upper)
        self.lower_magnitude = problem._lower_magnitude
        if da is not None and problem._has_rows:
            self.da, self.dlo, self.dhi = da.copy(), _kept(dlo), _kept(dhi)
        else:
            self.da = self.dlo = self.dhi = None

    def values(self) -> dict:
        P, q, lam, lo, hi = self.P, self.q, self.lam, self.lower, self.upper
        n = lam.size
        g = P @ lam + q
        objective = 0.5 * float(lam @ (g + q)) + self.c
        # "active" = within 1e-9 of the bound, relative to the bound or the effort itself
        atol_l = 1e-9 * np.maximum(np.abs(lam), self.lower_magnitude) + 1e-300
        act_lo = lam <= lo + atol_l
        act_hi = lam >= hi - atol_l
        if self.da is not None:
            da = self.da
            atol_d = 1e-9 * np.abs(da) + 1e-300
            act_dlo = da <= self.dlo + atol_d
            act_dhi = da >= self.dhi - atol_d
        else:
            act_dlo = act_dhi = np.zeros(n, dtype=bool)
        if self.n_rows:
            stationarity = float("nan")
        else:
            diag = P.diagonal()
            proj = _clip(lam - g / diag, lo, hi)
            stationarity = float((np.abs(proj - lam) * (np.sqrt(diag) if self.root is None else self.root)).max())
        return dict(objective=objective, stationarity=stationarity, active_lower=act_lo, active_upper=act_hi,
                    active_displacement_lower=act_dlo, active_displacement_upper=act_dhi)


def _kept(a: np.ndarray) -> np.ndarray:
    """``a`` as it is now: a copy unless read-only (as the controller's bounds are)."""
    return a if not a.flags.writeable else a.copy()


# --------------------------------------------------------------------------- registry

BACKENDS: dict[str, Callable[[], QPBackend]] = {}


def register_backend(name: str, factory: Callable[[], QPBackend]) -> None:
    """Register a backend factory under ``name`` (adding a solver touches one place)."""
    BACKENDS[name] = factory


def available_backends() -> list[str]:
    """Backend names whose libraries import here."""
    names = ["gauss-seidel"]
    try:
        import daqp  # noqa: F401

        names.append("daqp")
    except ImportError:
        pass
    try:
        import qpsolvers

        names += [f"qpsolvers:{s}" for s in qpsolvers.available_solvers]
    except ImportError:
        pass
    return names


def get_backend(name: str) -> QPBackend:
    if name in BACKENDS:
        return BACKENDS[name]()
    if name.startswith("qpsolvers:"):
        return QpsolversBackend(name.split(":", 1)[1])
    raise ValueError(f"unknown QP backend {name!r}; known: {sorted(BACKENDS)} or 'qpsolvers:<solver>'")


# --------------------------------------------------------------------------- Gauss–Seidel


class GaussSeidelBackend:
    """Projected Gauss–Seidel (paper §IV, after [6]).

    Box bounds only: the primal coordinate sweep ``λᵢ ← clip(λᵢ − (Pλ + q)ᵢ / Pᵢᵢ)``.
    With actuator-displacement rows: the same sweep with each coordinate step also
    clipped to keep every row feasible (bounds hold at every iterate; see ``_rows``).
    Stops when the largest update, measured in
    effector units (``√Pᵢᵢ·|Δλᵢ|``, metres), or the motion of the effectors over a
    whole sweep (``√(ΔλᵀPΔλ)``), falls under ``tolerance``.
    In the redundant case the sweep converges quickly in effector space but only
    slowly (rate ~ε) along the null space that the regulariser decides: Gauss–Seidel
    then stops at "one solution among all the possible" (paper §IV) that depends
    on the warm start, not at the unique regularised optimum of the exact QP.
    """

    name = "gauss-seidel"

    def __init__(self, relaxation: float = 1.0):
        self.relaxation = relaxation

    def solve(self, qp, start, *, tolerance, max_iterations):
        if qp.G.shape[0] == 0:
            return self._primal(qp, start, tolerance, max_iterations)
        return self._rows(qp, start, tolerance, max_iterations)

    def _primal(self, qp, start, tol, max_it):
        P, q, lo, hi = qp.P, qp.q, qp.lower, qp.upper
        lam = start.astype(float).copy()
        diag = np.diag(P).copy()
        sq = np.sqrt(diag)
        n = lam.size
        Pl = P.tolist()  # python floats: the sweep is scalar work, lists beat numpy here
        lam_l = lam.tolist()
        ql, lol, hil, dl = q.tolist(), lo.tolist(), hi.tolist(), diag.tolist()
        omega = self.relaxation
        it = 0
        converged = False
        while it < max_it:
            it += 1
            step = 0.0
            for i in range(n):
                row = Pl[i]
                g = ql[i]
                for j in range(n):
                    g += row[j] * lam_l[j]
                new = lam_l[i] - omega * g / dl[i]
                new = lol[i] if new < lol[i] else (hil[i] if new > hil[i] else new)
                dv = abs(new - lam_l[i]) * sq[i]
                if dv > step:
                    step = dv
                lam_l[i] = new
            lam_new = np.array(lam_l)
            moved = lam_new - lam
            lam = lam_new
            # effector-space motion of the whole sweep, ‖Wₑ^{1/2} W_ea Δλ‖ = √(Δλᵀ H Δλ)
            if step <= tol or float(moved @ (P @ moved)) <= tol * tol:
                converged = True
                break
        return BackendOutput(lam, it, converged, "optimal" if converged else "max_iterations")

    def _rows(self, qp, start, tol, max_it):
        """Feasible coordinate descent: each coordinate step is clipped so that every
        displacement row stays inside its bounds (the start is feasible, see the driver).
        Bounds therefore hold at every iterate; with a row active the sweep can stall
        short of the optimum (coordinate descent under coupled constraints), which the
        exact backends do not — use them when stroke limits bind."""
        P, q, G = qp.P, qp.q, qp.G
        lam = start.astype(float).copy()
        diag = np.diag(P)
        sq = np.sqrt(diag)
        n = lam.size
        g_row = G @ lam
        rlo, rhi = qp.row_lower, qp.row_upper
        it, converged = 0, False
        while it < max_it:
            it += 1
            before = lam.copy()
            step = 0.0
            for i in range(n):
                g = q[i] + P[i] @ lam
                delta = -g / diag[i]
                lo_i, hi_i = qp.lower[i] - lam[i], qp.upper[i] - lam[i]
                col = G[:, i]
                pos, neg = col > 0, col < 0
                # rows: rlo - g_row ≤ col·Δ ≤ rhi - g_row
                if pos.any():
                    hi_i = min(hi_i, np.min((rhi[pos] - g_row[pos]) / col[pos]))
                    lo_i = max(lo_i, np.max((rlo[pos] - g_row[pos]) / col[pos]))
                if neg.any():
                    hi_i = min(hi_i, np.min((rlo[neg] - g_row[neg]) / col[neg]))
                    lo_i = max(lo_i, np.max((rhi[neg] - g_row[neg]) / col[neg]))
                delta = min(max(delta, min(lo_i, 0.0)), max(hi_i, 0.0))
                if delta != 0.0:
                    lam[i] += delta
                    g_row += col * delta
                    step = max(step, abs(delta) * sq[i])
            moved = lam - before
            if step <= tol or float(moved @ (P @ moved)) <= tol * tol:
                converged = True
                break
        return BackendOutput(np.clip(lam, qp.lower, qp.upper), it, converged,
                             "optimal" if converged else "max_iterations")


register_backend("gauss-seidel", GaussSeidelBackend)


# --------------------------------------------------------------------------- exact QPs


class DaqpBackend:
    """DAQP dual active-set solver, called directly (no conversion layer), warm-started."""

    name = "daqp"
    wants_scaling = True

    def solve(self, qp, start, *, tolerance, max_iterations):
        import daqp  # lazy: optional at import time

        n = qp.P.shape[0]
        if qp.G.shape[0]:
            A = np.ascontiguousarray(qp.G)
            bupper = np.concatenate([qp.upper, qp.row_upper])
            blower = np.concatenate([qp.lower, qp.row_lower])
        else:  # box only (copies, as the concatenation makes with rows)
            A = np.zeros((0, n))
            bupper, blower = np.array(qp.upper, dtype=float), np.array(qp.lower, dtype=float)
        sense = np.zeros(bupper.size, dtype=np.int32)
        x, _f, flag, info = daqp.solve(
            np.ascontiguousarray(qp.P), qp.q.copy(), A, bupper, blower, sense,
            iter_limit=max_iterations, primal_start=start.copy(), eps_prox=0.0,
        )
        ok = flag in (1, 2)
        status = _DAQP_STATUS.get(flag) or f"daqp exitflag {flag}"
        lam = _clip(np.asarray(x, dtype=float), qp.lower, qp.upper) if ok else start.copy()
        return BackendOutput(lam, int(info.get("iterations", 0)), ok, status)


_DAQP_STATUS = {1: "optimal", 2: "optimal", -1: "infeasible", -2: "cycling", -3: "unbounded",
                -4: "max_iterations", -5: "nonconvex"}


register_backend("daqp", DaqpBackend)


_QPSOLVERS_SETTINGS = {
    # tight settings so that the comparison in bench_qp.py is about speed at equal accuracy
    "clarabel": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10),
    "osqp": dict(eps_abs=1e-10, eps_rel=1e-10, max_iter=100000, polishing=True),
    "proxqp": dict(eps_abs=1e-12, eps_rel=0.0),
}


class QpsolversBackend:
    """Any solver known to ``qpsolvers`` (imported lazily)."""

    def __init__(self, solver: str):
        self.solver = solver
        self.name = f"qpsolvers:{solver}"
        self.wants_scaling = True

    def solve(self, qp, start, *, tolerance, max_iterations):
        import qpsolvers

        G_rows, h_rows = [], []
        gu, gl = np.isfinite(qp.row_upper), np.isfinite(qp.row_lower)
        if gu.any():
            G_rows.append(qp.G[gu])
            h_rows.append(qp.row_upper[gu])
        if gl.any():
            G_rows.append(-qp.G[gl])
            h_rows.append(-qp.row_lower[gl])
        G = np.vstack(G_rows) if G_rows else None
        h = np.concatenate(h_rows) if h_rows else None
        problem = qpsolvers.Problem(qp.P, qp.q, G, h, lb=qp.lower, ub=qp.upper)
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = qpsolvers.solve_problem(problem, solver=self.solver, initvals=start, verbose=False,
                                          **_QPSOLVERS_SETTINGS.get(self.solver, {}))
        ok = bool(sol.found) and sol.x is not None
        lam = np.clip(np.asarray(sol.x, dtype=float), qp.lower, qp.upper) if ok else start.copy()
        iters = sol.extras.get("iter", sol.extras.get("iterations", 0)) if isinstance(sol.extras, dict) else 0
        if not isinstance(iters, (int, np.integer)):
            iters = getattr(iters, "iter", 0) if iters is not None else 0
        return BackendOutput(lam, int(iters or 0), ok, "optimal" if ok else "failed")


# --------------------------------------------------------------------------- driver


def _minimal_displacement_violation(problem: ConstraintProblem):
    """Closest reachable actuator displacements when the displacement bounds cannot all hold.

    Bounded least squares (``scipy.optimize.lsq_linear``) over λ in its box and a
    point ``t`` in the displacement box: ``min ‖δa_free + W_aa λ − t‖²``.
    Returns the best λ and the displacement ``δa`` there.
    """
    from scipy.optimize import lsq_linear

    n = problem.n_actuators
    A = np.hstack([problem.W_aa, -np.eye(n)])
    # scale columns so that λ (N or Pa) and t (m or m³) are comparable for the solver
    col = np.maximum(np.abs(A).max(axis=0), 1e-300)
    lb = np.concatenate([problem.lambda_lower, problem.displacement_lower]) * col
    ub = np.concatenate([problem.lambda_upper, problem.displacement_upper]) * col
    res = lsq_linear(A / col, -problem.delta_a_free, bounds=(lb, ub), method="bvls", tol=1e-14)
    lam = np.clip(res.x[:n] / col[:n], problem.lambda_lower, problem.lambda_upper)
    return lam, problem.delta_a_free + problem.W_aa @ lam


def solve_constraint_problem(
    problem: ConstraintProblem,
    backend: str | QPBackend = DEFAULT_BACKEND,
    *,
    tolerance: float = 1e-10,
    absolute_tolerance: float = 0.0,
    max_iterations: int | None = None,
) -> ConstraintSolution:
    """Solve one inverse step; never violates the λ box.

    ``tolerance`` (iterative backends) is relative to the weighted free gap
    ``‖Wₑ^{1/2} δe_free‖``: Gauss–Seidel stops when no sweep moves the effectors
    by more than ``tolerance`` times it, or by more than ``absolute_tolerance`` (m).
    (An absolute tolerance of 1e-9 m made Gauss–Seidel 100× faster inside the converged
    inverse of the 16-tendon robot but left it 1e-5 m short of the targets: on these
    ill-conditioned problems small sweeps do not mean a small error. The controller
    therefore keeps the relative rule.) When the actuator
    displacement bounds cannot all be met inside the λ box (linearisation error
    near a stroke limit), they are widened by the least amount that makes them
    feasible, ``status`` says ``"relaxed"`` and ``displacement_relaxation`` by how
    much. An unreachable target needs nothing special: the QP returns the closest
    reach and ``effector_error`` says how far it is.
    """
    t0 = time.perf_counter()
    if not problem._has_rows and (backend == "daqp" if type(backend) is str else type(backend) is DaqpBackend) \
            and BACKENDS.get("daqp") is DaqpBackend:
        return _solve_box_daqp(problem, 1000 if max_iterations is None else max_iterations, t0)
    be = get_backend(backend) if isinstance(backend, str) else backend
    if max_iterations is None:
        max_iterations = 5000 if be.name == "gauss-seidel" else 1000
    n = problem.n_actuators
    start = problem.start()
    dlo, dhi = problem.displacement_lower, problem.displacement_upper
    relaxation = np.zeros(n)
    relaxed = False
    if problem._has_rows:
        _, da0 = problem.predict(start)
        slack = 1e-9 * np.maximum(np.abs(da0), np.abs(np.where(np.isfinite(dlo), dlo, 0.0))) + 1e-300
        if ((da0 < dlo - slack) | (da0 > dhi + slack)).any():
            # the warm start breaks a stroke limit: start from the least-violating λ instead
            start, da_best = _minimal_displacement_violation(problem)
            slack = 1e-9 * np.maximum(np.abs(da_best), np.abs(np.where(np.isfinite(dlo), dlo, 0.0))) + 1e-300
            below, above = da_best < dlo - slack, da_best > dhi + slack
            if below.any() or above.any():  # infeasible: widen by the least amount
                relaxation = np.where(below, dlo - da_best, 0.0) + np.where(above, da_best - dhi, 0.0)
                dlo = np.where(below, da_best, dlo)
                dhi = np.where(above, da_best, dhi)
                relaxed = True
    qp, gap2 = _quadratic_form(problem, dlo, dhi)
    # iterative backends stop on an effector-unit step relative to the free gap
    scale_m = math.sqrt(gap2)
    tol = max(tolerance * scale_m, absolute_tolerance, 1e-300)
    root = None  # √Pᵢᵢ
    if getattr(be, "wants_scaling", False):
        # Jacobi scaling λ = S y, S = diag(1/√Pᵢᵢ): unit diagonal whatever the units of
        # the actuators, so absolute pivot/singularity tolerances inside the library
        # see a well-scaled problem (the raw P of a stiff robot is ~1e-8 in SI units).
        root = np.sqrt(qp.P.diagonal())
        S = 1.0 / root
        G, row_lower, row_upper = qp.G, qp.row_lower, qp.row_upper
        if G.shape[0]:  # and unit rows for the displacement constraints
            G = G * S[None, :]
            rs = 1.0 / np.maximum(np.abs(G).max(axis=1), 1e-300)
            G, row_lower, row_upper = G * rs[:, None], row_lower * rs, row_upper * rs
        scaled = _new(
            QuadraticForm, P=qp.P * (S[:, None] * S), q=qp.q * S, c=qp.c, lower=qp.lower / S, upper=qp.upper / S,
            G=G, row_lower=row_lower, row_upper=row_upper, rows=qp.rows,
            regularisation_weight=qp.regularisation_weight, energy_diagonal=qp.energy_diagonal,
        )
        out = be.solve(scaled, start / S, tolerance=tol, max_iterations=max_iterations)
        lam = _clip(out.actuation * S, problem.lambda_lower, problem.lambda_upper)
    else:
        out = be.solve(qp, start, tolerance=tol, max_iterations=max_iterations)
        lam = out.actuation
    de, da = problem.predict(lam)
    # a ConstraintSolution whose objective, stationarity and active sets are computed on
    # first read (_Diagnostics: same values, same arithmetic)
    return _new(
        ConstraintSolution, actuation=lam, delta_e=de, delta_a=da, effector_error=math.sqrt(de.dot(de)),
        iterations=out.iterations, converged=out.converged,
        status="relaxed" if (relaxed and out.converged) else out.status, backend=be.name,
        displacement_relaxation=relaxation, regularisation_weight=qp.regularisation_weight, extras={},
        _diagnostics=_Diagnostics(problem, qp.P, qp.q, qp.c, qp.G.shape[0], lam, da, dlo, dhi, root),
        time_s=time.perf_counter() - t0,
    )


_daqp = None  # the daqp module, once imported


def _solve_box_daqp(problem: ConstraintProblem, max_iterations: int, t0: float) -> ConstraintSolution:
    """:func:`solve_constraint_problem` with the default ``"daqp"`` backend and no displacement
    rows (the controller's tick): the same arithmetic on the same arrays, the same call to
    DAQP (:class:`DaqpBackend` after the Jacobi scaling), without the intermediate objects
    (``QuadraticForm``, scaled copy, ``BackendOutput``) and copies of arrays made here."""
    global _daqp
    if _daqp is None:
        import daqp as _daqp_module  # lazy: optional at import time

        _daqp = _daqp_module
    lo, hi, l0 = problem.lambda_lower, problem.lambda_upper, problem.lambda0
    n = lo.size
    start = _clip(np.zeros(n) if l0 is None else l0, lo, hi)  # problem.start()
    P, q, gap2, rho, _, diagonal = _hessian(problem)
    root = np.sqrt(diagonal)  # √Pᵢᵢ: Jacobi scaling λ = S y, as in solve_constraint_problem
    S = 1.0 / root
    lower, upper = lo / S, hi / S
    # what DaqpBackend passes, without its copies: DAQP reads its arguments (given a linear
    # term it works on copies of the bounds and of the constraint states: daqp's setup_daqp_ldp)
    x, _f, flag, info = _daqp.solve(
        P * (S[:, None] * S), q * S, _no_rows(n), upper, lower,
        np.zeros(n, dtype=np.int32), iter_limit=max_iterations, primal_start=start / S, eps_prox=0.0,
    )
    ok = flag in (1, 2)
    y = _clip(np.asarray(x, dtype=float), lower, upper) if ok else start / S
    lam = _clip(y * S, lo, hi)
    da = None if problem.W_aa is None else problem.delta_a_free + problem.W_aa @ lam  # problem.predict(lam)
    diagnostics = _Diagnostics(problem, P, q, 0.5 * gap2, 0, lam, da, problem.displacement_lower,
                               problem.displacement_upper, root)
    solution = _new(
        ConstraintSolution, actuation=lam, delta_a=da, iterations=int(info.get("iterations", 0)), converged=ok,
        status=_DAQP_STATUS.get(flag) or f"daqp exitflag {flag}", backend=DaqpBackend.name,
        regularisation_weight=rho, extras={}, _diagnostics=diagnostics)
    d = solution.__dict__
    if problem.__dict__.get("_owned", False):
        d["_prediction"] = _Prediction(problem, diagnostics.lam)
    else:
        de = problem.delta_e_free + problem.W_ea @ lam
        d["delta_e"], d["effector_error"], d["displacement_relaxation"] = de, math.sqrt(de.dot(de)), np.zeros(n)
    d["time_s"] = time.perf_counter() - t0
    return solution


_NO_ROWS: dict = {}  # n -> the (0, n) constraint matrix passed to DAQP (empty: nothing in it to change)


def _no_rows(n: int) -> np.ndarray:
    a = _NO_ROWS.get(n)
    if a is None:
        a = _NO_ROWS[n] = np.zeros((0, n))  # writeable: DAQP's wrapper takes a writeable buffer
    return a
