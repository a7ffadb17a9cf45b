"""Solvers of the constraint-space QP (``solver.inverse.qp``) behind one Protocol and one registry.

A backend receives a :class:`~solver.inverse.qp.QuadraticForm` — ``½ λᵀPλ + qᵀλ`` with a box
and displacement rows — and a feasible start, and returns a :class:`BackendOutput`. It
declares whether it wants the Jacobi-scaled form (``scaled``: ``λ = S y``, ``S =
diag(1/√Pᵢᵢ)``, unit diagonal whatever the units of the actuators, so absolute tolerances
inside a library see a well-scaled problem) and its default iteration budget. A backend may
keep state between calls (DAQP keeps the least-effort stage's model: :class:`DaqpBackend`).

Every backend is reached through :func:`get_backend` by name. A registration is one name
(``"daqp"``) or a family of names sharing a prefix (``"qpsolvers:"``, whose factory takes the
rest of the name: ``"qpsolvers:osqp"``); each also says which of its names can run here
(:func:`available_backends`). Registered here:

* ``"daqp"`` (default): DAQP, a dual active-set solver for small dense QPs, exact at the
  optimum, warm-started (``benchmarks/bench_qp.py``);
* ``"gauss-seidel"``: the paper's projected Gauss–Seidel (pure Python/numpy);
* ``"qpsolvers:<name>"``: any solver the ``qpsolvers`` package knows (clarabel, osqp, …).

Libraries are imported when a backend first solves, so importing this module stays light.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, ClassVar, Protocol

import numpy as np

from vertebra.core.errors import OptionError

if TYPE_CHECKING:
    from vertebra.solver.inverse.qp import QuadraticForm

__all__ = ["BackendOutput", "QPBackend", "BACKENDS", "DEFAULT_BACKEND", "register_backend", "get_backend",
           "available_backends", "DaqpBackend", "GaussSeidelBackend", "QpsolversBackend"]

DEFAULT_BACKEND = "daqp"


@dataclass
class BackendOutput:
    """What a backend returns: efforts (in the coordinates of the form it was given), its
    iteration count, whether it met its stopping rule, and a status word."""

    actuation: np.ndarray
    iterations: int
    converged: bool
    status: str


class QPBackend(Protocol):
    """An inverse QP solver. ``solve`` never raises for a feasible box; the driver clips what it
    returns into the box. ``tolerance`` is in effector units (m), for iterative solvers."""

    name: str
    scaled: ClassVar[bool]  # wants the Jacobi-scaled form
    default_max_iterations: ClassVar[int]

    def solve(self, form: "QuadraticForm", start: np.ndarray, *, tolerance: float,
              max_iterations: int) -> BackendOutput: ...


@dataclass(frozen=True)
class _Registration:
    factory: Callable[..., QPBackend]  # () -> backend, or (member name) -> backend for a family
    available: Callable[[], list]  # the names it can run here


BACKENDS: dict[str, _Registration] = {}


def register_backend(name: str, factory: Callable[..., QPBackend], *,
                     available: Callable[[], list] | None = None) -> None:
    """Register ``factory`` under ``name``; a ``name`` ending in ``":"`` registers a family whose
    factory takes the member's name. ``available`` lists the names that can run here (default:
    ``[name]``)."""
    BACKENDS[name] = _Registration(factory, available or (lambda: [name]))


def get_backend(name: str) -> QPBackend:
    """The backend registered under ``name`` (or its family's prefix); :class:`OptionError`
    naming the known ones otherwise."""
    registration = BACKENDS.get(name)
    if registration is not None and not name.endswith(":"):
        return registration.factory()
    prefix, colon, member = name.partition(":")
    family = BACKENDS.get(prefix + colon) if colon and member else None
    if family is None:
        known = ", ".join(sorted(k + "<name>" if k.endswith(":") else k for k in BACKENDS))
        raise OptionError(f"unknown QP backend {name!r}; known: {known}", field="backend")
    return family.factory(member)


def available_backends() -> list[str]:
    """Names of the registered backends whose libraries are installed here."""
    return [n for registration in BACKENDS.values() for n in registration.available()]


def _if_installed(module: str, names: Callable[[], list]) -> Callable[[], list]:
    return lambda: names() if importlib.util.find_spec(module) is not None else []


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
    scaled = False
    default_max_iterations = 5000

    def __init__(self, relaxation: float = 1.0):
        self.relaxation = relaxation

    def solve(self, form, start, *, tolerance, max_iterations):
        if form.G.shape[0] == 0:
            return self._primal(form, start, tolerance, max_iterations)
        return self._rows(form, start, tolerance, max_iterations)

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


def _writeable(a: np.ndarray) -> np.ndarray:
    """``a``, or a writeable copy when read-only (DAQP's wrapper takes writeable buffers; it only
    reads them). The copy of a read-only array that owns its data (no view of another) is kept
    with it: the least-effort form's identity is the same array every tick."""
    if a.flags.writeable:
        return a
    kept = _COPIES.get(id(a))
    if kept is not None and kept[0] is a:
        return kept[1]
    copy = a.copy()
    if a.base is None:
        if len(_COPIES) > 64:
            _COPIES.clear()
        _COPIES[id(a)] = (a, copy)     # (holds ``a``: its id stays its own)
    return copy


_COPIES: dict = {}  # id(read-only array owning its data) -> (the array, its copy, which DAQP only reads)


class DaqpBackend:
    """DAQP dual active-set solver, called directly with numpy arrays, warm-started through
    ``primal_start``. DAQP reads its arguments and writes none of them (checked on 0.11), so
    the form's arrays are passed as they are.

    A form whose Hessian is a read-only array owning its data — the same array at every call
    (the least-effort stage's scaled identity, :func:`~vertebra.solver.inverse.qp.least_effort_form`)
    — is solved by a ``daqp.Model`` this backend keeps per Hessian and size: set up once (from the
    first answer's working set), then each call updates its cost vector, rows and bounds and solves
    from the working set the last solve left. From one tick to the next that set barely changes:
    1–2 active-set iterations instead of ~25, and no workspace set up per call. The answer is the
    QP's optimum either way, to the solver's rounding along its other path (the least-effort rows
    are held to 1e-9 for that, ``QuadraticForm.feasibility``); a solve from there that fails is
    done again from ``start``. The models are this backend's: a controller's own backend warm-starts
    its stages, a backend made per call (a name given to ``solve_constraint_problem``) does not."""

    name = "daqp"
    scaled = True
    default_max_iterations = 1000
    _daqp = None  # the module, imported at the first solve
    _primal_tol = None  # its default primal (feasibility) tolerance

    def __init__(self):
        # (id(P), constraints) -> [P, daqp.Model, its (iteration limit, primal tolerance), its linear term
        # when a read-only array owning its data (the same at every call: not updated), else None]
        self._models: dict = {}

    def solve(self, form, start, *, tolerance, max_iterations):
        daqp = DaqpBackend._daqp
        if daqp is None:
            import inspect

            import daqp

            # (its default feasibility tolerance, for the forms that ask none of their own)
            DaqpBackend._primal_tol = inspect.signature(daqp.solve).parameters["primal_tol"].default
            DaqpBackend._daqp = daqp
        if form.G.shape[0]:
            upper = np.concatenate([form.upper, form.row_upper])
            lower = np.concatenate([form.lower, form.row_lower])
        else:
            upper, lower = _writeable(form.upper), _writeable(form.lower)
        P = form.P
        feasibility = DaqpBackend._primal_tol if form.feasibility is None else form.feasibility
        settings = (max_iterations, feasibility)
        constant = not P.flags.writeable and P.base is None     # (the same array at every call)
        if constant:
            key = (id(P), upper.size)
            kept = self._models.get(key)
            if kept is not None and kept[0] is P:
                model = kept[1]
                if kept[2] != settings:
                    model.settings = {"iter_limit": max_iterations, "primal_tol": feasibility}
                    kept[2] = settings
                if form.q is kept[3]:       # (the same read-only linear term: the model has it)
                    model.update(A=_writeable(form.G), bupper=upper, blower=lower)
                else:
                    model.update(f=_writeable(form.q), A=_writeable(form.G), bupper=upper, blower=lower)
                    kept[3] = form.q if not form.q.flags.writeable and form.q.base is None else None
                x, _f, flag, info = model.solve()
                if flag == 1 or flag == 2:
                    return BackendOutput(x, info["iterations"], True, "optimal")
                del self._models[key]       # (from ``start`` below, and a new model from that answer)
        sense = _SENSES.get(upper.size)
        if sense is None:
            sense = _SENSES[upper.size] = np.zeros(upper.size, dtype=np.int32)
        # (DAQP makes A C-contiguous itself)
        x, _f, flag, info = daqp.solve(
            _writeable(P), _writeable(form.q), _writeable(form.G), upper, lower, sense,
            iter_limit=max_iterations, primal_start=_writeable(start), eps_prox=0.0, primal_tol=feasibility)
        if flag == 1 or flag == 2:
            if constant:
                model = daqp.Model()
                model.settings = {"iter_limit": max_iterations, "primal_tol": feasibility, "eps_prox": 0.0}
                model.setup(_writeable(P), _writeable(form.q), _writeable(form.G), upper, lower, sense,
                            dual_start=info["lam"])
                self._models[key] = [P, model, settings,
                                     form.q if not form.q.flags.writeable and form.q.base is None else None]
            return BackendOutput(x, info["iterations"], True, "optimal")
        return BackendOutput(start.copy(), int(info.get("iterations", 0)), False,
                             _DAQP_STATUS.get(flag) or f"daqp exitflag {flag}")


_SENSES: dict = {}  # size -> the zeros (every constraint an inequality) passed as DAQP's ``sense`` (read, never written)


_DAQP_STATUS = {1: "optimal", 2: "optimal", -1: "infeasible", -2: "cycling", -3: "unbounded",
                -4: "max_iterations", -5: "nonconvex"}


register_backend("daqp", DaqpBackend, available=_if_installed("daqp", lambda: ["daqp"]))


_QPSOLVERS_SETTINGS = {
    # tight settings so that the comparison in bench_qp.py is about speed at equal accuracy
    "clarabel": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10),
    "osqp": dict(eps_abs=1e-10, eps_rel=1e-10, max_iter=100000, polishing=True),
    "proxqp": dict(eps_abs=1e-12, eps_rel=0.0),
}


def _qpsolvers_names() -> list:
    import qpsolvers

    return [f"qpsolvers:{s}" for s in qpsolvers.available_solvers]


class QpsolversBackend:
    """One solver of the ``qpsolvers`` package (the family ``"qpsolvers:<solver>"``)."""

    scaled = True
    default_max_iterations = 1000

    def __init__(self, solver: str):
        if f"qpsolvers:{solver}" not in _if_installed("qpsolvers", _qpsolvers_names)():
            raise OptionError(f"qpsolvers has no solver {solver!r} installed here; available: "
                              f"{', '.join(_if_installed('qpsolvers', _qpsolvers_names)()) or 'none'}",
                              field="backend")
        self.solver = solver
        self.name = f"qpsolvers:{solver}"

    def solve(self, form, start, *, tolerance, max_iterations):
        import warnings

        import qpsolvers

        G_rows, h_rows = [], []
        gu, gl = np.isfinite(form.row_upper), np.isfinite(form.row_lower)
        if gu.any():
            G_rows.append(form.G[gu])
            h_rows.append(form.row_upper[gu])
        if gl.any():
            G_rows.append(-form.G[gl])
            h_rows.append(-form.row_lower[gl])
        G = np.vstack(G_rows) if G_rows else None
        h = np.concatenate(h_rows) if h_rows else None
        problem = qpsolvers.Problem(form.P, form.q, G, h, lb=form.lower, ub=form.upper)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = qpsolvers.solve_problem(problem, solver=self.solver, initvals=start, verbose=False,
                                          **_QPSOLVERS_SETTINGS.get(self.solver, {}))
        ok = bool(sol.found) and sol.x is not None
        lam = np.asarray(sol.x, dtype=float) if ok else start.copy()
        iters = sol.extras.get("iter", sol.extras.get("iterations", 0)) if isinstance(sol.extras, dict) else 0
        if not isinstance(iters, (int, np.integer)):
            iters = getattr(iters, "iter", 0) if iters is not None else 0
        return BackendOutput(lam, int(iters or 0), ok, "optimal" if ok else "failed")


register_backend("qpsolvers:", QpsolversBackend, available=_if_installed("qpsolvers", _qpsolvers_names))
