"""Contact forces as variables of the inverse's constraint-space QP (docs/contact.md, "Inverse
and control ticks").

At a state with candidate contacts (gaps ``g``, ``G = ∂g/∂q``; ``solver/contact.py``) the
linearisation's motion under efforts ``λ`` and contact forces ``μ ≥ 0`` is
``dq = K⁻¹(r + B(λ − λ0) + Gᵀμ)`` — the contact forces are total forces, like ``λ`` (at a contact
equilibrium ``r = −Gᵀμ0``). Projected into constraint space with one banded solve
``K⁻¹[r, B, Gᵀ]`` (the paper's compliance projection, as SoftRobots.Inverse does for contacts)::

    δe(λ, μ) = δe(λ) + W_ec μ                     W_ec = Je K⁻¹Gᵀ
    w(λ, μ)  = c + W_ca λ + W_cc μ   (the gaps)    c = g + G K⁻¹r − W_ca λ0,  W_ca = G K⁻¹B,  W_cc = G K⁻¹Gᵀ

and the step's QP asks for the efforts that bring the effectors closest, with the actuators
free within their bounds and the contacts complementary: ``w ≥ 0, μ ≥ 0, wᵀμ = 0``. For a set
``A`` of pressed contacts the complementarity is linear: ``w_A = 0`` gives
``μ_A(λ) = −W_AA⁻¹(c_A + W_Aa λ)``, and the problem is the ordinary QP in ``λ`` with the contacts
condensed into ``W_ea``, ``δe_free`` (and ``W_aa``, ``δa_free``), plus the rows ``μ_A(λ) ≥ 0`` and
``w_I(λ) ≥ 0`` for the others. Its answer is complementary; where it rests on a row, the set
changes — a pressed contact whose force the answer brings to zero is released, an open one whose
gap it closes is pressed — and the QP is solved again (a few times at most: the active-set
method of a QP with complementarity constraints, to a local optimum). The controller so leans
on an obstacle where that brings the effectors closer, instead of ignoring it or fighting it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vertebra.solver import contact
from vertebra.solver.inverse.qp import ConstraintSolution, _unit_rows, least_effort_form, quadratic_form
from vertebra.solver.inverse.space import ConstraintProblem

ROUNDS = 8                 # active-set changes per step before the last complementary answer is kept
RELEASES = 4              # up to this many pressed contacts, each is also tried released
PRESSED = 1e-9             # (when the start's complementarity problem fails) a gap below this share of the length is pressed


def penetration(model, state) -> float:
    """How deep (m, ≥ 0) ``state`` lies in an obstacle or a disc (contact model ``model``): its
    most negative gap among the candidates."""
    found = contact.evaluate(model, state)
    return max(0.0, -float(found.gap.min(initial=0.0)))


@dataclass
class ContactProjection:
    """A projection (:class:`~vertebra.solver.inverse.space.Projection`) with the contacts of the
    chosen set condensed in: ``problem`` is the condensed problem (its ``predict`` includes the
    contact forces), :meth:`state_change` adds ``K⁻¹G_Aᵀ μ_A(λ)``; the rest is the base's."""

    base: object
    problem: ConstraintProblem
    active: np.ndarray            # indices of the pressed candidates
    contacts: object              # contact.ContactSet at the state
    force_of: tuple               # (F0, F1): μ_A(λ) = F0 + F1 λ
    K_inv_Gt: np.ndarray          # (n_dof, m) K⁻¹Gᵀ
    G: np.ndarray                 # (m, n_dof) ∂g/∂q of the candidates
    W_ec: np.ndarray              # (n_rows, m) Je K⁻¹Gᵀ
    model: object                 # contact.ContactModel
    normal: np.ndarray | None = None   # with friction: which of the rows are gaps (the others slip rows)
    law: object = None            # with friction: the statuses of the chosen set (contact_friction.Friction)

    def forces(self, actuation: np.ndarray) -> np.ndarray:
        """The contact forces ``μ`` of the candidates' rows under ``actuation`` (normal forces ≥ 0;
        with friction, after them the tangential forces of the frictional contacts)."""
        mu = np.zeros(self.G.shape[0])
        F0, F1 = self.force_of
        forces = F0 + F1 @ actuation
        if self.normal is None:
            mu[self.active] = np.maximum(forces, 0.0)
        else:
            mu[self.active] = np.where(self.normal[self.active], np.maximum(forces, 0.0), forces)
        return mu

    def state_change(self, actuation: np.ndarray, change: np.ndarray | None = None) -> np.ndarray:
        return self.base.state_change(actuation, change) + self.K_inv_Gt @ self.forces(actuation)

    def penetration(self, state) -> float:
        """How deep (m, ≥ 0) ``state`` lies in an obstacle or a disc: its most negative gap."""
        return penetration(self.model, state)

    def contact_forces(self, actuation: np.ndarray) -> np.ndarray:
        """``Gᵀμ(λ)`` (n_dof,): the generalised forces of the contacts under ``actuation``."""
        return self.G.T @ self.forces(actuation)

    @property
    def Je_K_inv_r(self):
        """``Je K⁻¹(r + Gᵀμ(λ0))``: how far the start lies from its equilibrium with the contacts."""
        return self.base.Je_K_inv_r + self.W_ec @ self.forces(self.base.problem.lambda0)

    def effector_motion(self, force: np.ndarray) -> np.ndarray:
        return self.base.effector_motion(force)


def contact_step(trunk, state, lin, projection, backend, *, tolerance: float, slack: float | None = None):
    """The QP of one inverse step with the contacts of ``state`` (module docstring): returns the
    :class:`ContactProjection` and the :class:`~vertebra.solver.inverse.qp.ConstraintSolution`
    (``slack``: the least-effort second stage, as :func:`~vertebra.solver.inverse.qp.solve_constraint_problem`).
    None when no contact is near. (With friction at obstacles:
    :func:`~vertebra.solver.inverse.friction_contacts.frictional_step`.)"""
    model = trunk.contact
    found = contact.evaluate(model, state)
    if not found.count:
        return None
    problem = projection.problem
    G = found.jacobian(trunk.frames.count)
    m = G.shape[0]
    KG, W_ec, W_ac, W_ca, W_cc, c = project_rows(lin, problem, G, found.gap)
    lam0 = problem.lambda0
    solve = lambda chosen: _solve_with(problem, backend, tolerance, slack, chosen, c, W_ca, W_cc, W_ec, W_ac)  # noqa: E731
    # the contacts pressed under the current efforts: the complementarity problem at λ0 (whose
    # set makes λ0 itself feasible: every step's QP has an answer)
    at_start = contact.complementarity(W_cc, c + W_ca @ lam0)
    pressed = (np.flatnonzero(at_start > 0.0) if at_start is not None
               else np.flatnonzero(found.gap <= PRESSED * model.length))
    # from the contacts pressed now, and from each of them released (the active-set moves only
    # where the answer rests on a row; a contact the target wants left is tried open): the
    # complementary answer that brings the effectors closest
    starts = [pressed] + ([np.delete(pressed, k) for k in range(pressed.size)] if pressed.size <= RELEASES else [])
    answer = None
    for start in starts:
        found_here = _settle(solve, start, m, model.length)
        if found_here is not None and (answer is None or found_here[5].effector_error
                                       < answer[5].effector_error - 1e-12 * model.length):
            answer = found_here
    if answer is None:
        return None
    _, _, _, condensed, force_of, sol, chosen = answer
    return ContactProjection(projection, condensed, chosen, found, force_of, KG, G, W_ec, model), sol


def project_rows(lin, problem, G: np.ndarray, gap: np.ndarray):
    """The contacts' rows ``G`` (with their gaps) in constraint space, one banded solve
    ``K⁻¹[r, B, Gᵀ]``: (K⁻¹Gᵀ, W_ec, W_ac, W_ca, W_cc, c) of the module docstring."""
    n = problem.n_actuators
    rhs = np.empty((G.shape[1], 1 + n + G.shape[0]), order="F")
    rhs[:, 0] = lin.residual
    rhs[:, 1:1 + n] = lin.actuator_forces
    rhs[:, 1 + n:] = G.T
    X = lin.solve(rhs, overwrite=True)
    Kr, KB, KG = X[:, 0], X[:, 1:1 + n], X[:, 1 + n:]
    W_ca = G @ KB
    return (KG, lin.effector_jacobian @ KG, lin.actuator_jacobian @ KG, W_ca, G @ KG,
            gap + G @ Kr - W_ca @ problem.lambda0)


def settle(solve, start, key, change, rounds: int = ROUNDS):
    """The active-set rounds from the set ``start`` (module docstring): ``solve(set)`` answers a
    set (None: no answer), ``change(set, answer)`` gives the next set or None when the answer
    rests on no row, ``key(set)`` identifies a set (a set seen before ends the rounds). Returns
    the last answer."""
    seen, answer, current = set(), None, start
    for _ in range(rounds):
        if key(current) in seen:
            break
        seen.add(key(current))
        found = solve(current)
        if found is None:
            break
        answer = found
        current = change(current, found)
        if current is None:
            break
    return answer


def _settle(solve, active, m: int, length: float):
    """The rounds on sets of pressed contacts: the last complementary answer."""
    def change(active, found):
        mu_A, w = found[1], found[2]
        released = active[mu_A <= 1e-12 * max(float(np.abs(mu_A).max(initial=0.0)), 1e-300)]
        inactive = np.setdiff1d(np.arange(m), active)
        closed = inactive[w[inactive] <= 1e-12 * length]
        if not released.size and not closed.size:
            return None
        return np.union1d(np.setdiff1d(active, released), closed)

    return settle(solve, active, lambda active: tuple(active.tolist()), change)


def _with_rows(form, rows, low, scaled: bool):
    """``form`` with the rows ``rows λ ≥ low`` appended (in its coordinates)."""
    extra = rows * form.scale if scaled else rows.copy()
    high = np.full(low.size, np.inf)
    if scaled:
        extra, low, high = _unit_rows(extra, low.copy(), high)
    form.G = np.vstack([form.G, extra])
    form.row_lower = np.concatenate([form.row_lower, low])
    form.row_upper = np.concatenate([form.row_upper, high])
    return form


def _solve_with(problem, backend, tolerance, slack, active, c, W_ca, W_cc, W_ec, W_ac):
    """The QP with the contacts ``active`` pressed (condensed) and the others open."""
    n = problem.n_actuators
    m = c.size
    inactive = np.setdiff1d(np.arange(m), active)
    if active.size:
        W_AA = W_cc[np.ix_(active, active)]
        try:
            F1 = -np.linalg.solve(W_AA, W_ca[active])            # μ_A(λ) = F0 + F1 λ
            F0 = -np.linalg.solve(W_AA, c[active])
        except np.linalg.LinAlgError:
            return None
    else:
        F0, F1 = np.zeros(0), np.zeros((0, n))
    # rows: the pressed contacts' forces μ_A(λ) ≥ 0 and the open ones' gaps w_I(λ) ≥ 0
    rows = np.vstack([F1, W_ca[inactive] + W_cc[np.ix_(inactive, active)] @ F1])
    low = np.concatenate([-F0, -(c[inactive] + W_cc[np.ix_(inactive, active)] @ F0)])
    return condensed_qp(problem, backend, tolerance, slack, active, F0, F1, rows, low, c, W_ca, W_cc, W_ec, W_ac)


def condensed_qp(problem, backend, tolerance, slack, active, F0, F1, rows, low, c, W_ca, W_cc, W_ec, W_ac):
    """The QP with the forces of the rows ``active`` condensed in (``μ_A(λ) = F0 + F1 λ``) and the
    rows ``rows λ ≥ low`` (their forces' signs, the open gaps, …). Returns (λ, μ_A, the rows'
    linearised gaps w, the condensed problem, (F0, F1), the solution, ``active``), or None."""
    space, n = problem.space, problem.n_actuators
    m = c.size
    W_eA, W_aA = W_ec[:, active], W_ac[:, active]
    W_ea = problem.W_ea + W_eA @ F1
    delta_e = problem.delta_e_free + W_eA @ F0
    W_aa = delta_a = None
    if problem.W_aa is not None:
        W_aa = problem.W_aa + W_aA @ F1
        delta_a = problem.delta_a_free + W_aA @ F0
    condensed = ConstraintProblem(space, W_ea, delta_e, W_aa, delta_a, problem.lambda0, problem.box, problem.damping)
    form = _with_rows(quadratic_form(condensed, scaled=backend.scaled), rows, low, backend.scaled)
    tol = max(tolerance * math.sqrt(2.0 * form.c), 1e-300)
    out = backend.solve(form, condensed.start() / form.scale, tolerance=tol,
                        max_iterations=backend.default_max_iterations)
    if not out.converged:
        return None
    lam = np.minimum(np.maximum(out.actuation * form.scale, condensed.lambda_lower), condensed.lambda_upper)
    iterations = out.iterations
    if slack is not None:
        # the least effort among the efforts that keep the effector gaps (solver.inverse.qp)
        limits = (space.displacement_lower, space.displacement_upper)
        second = _with_rows(least_effort_form(condensed, lam, slack, limits, scaled=backend.scaled,
                                              energy=form.energy_diagonal if condensed.W_aa is not None else None),
                            rows, low, backend.scaled)
        out = backend.solve(second, lam / second.scale, tolerance=tol, max_iterations=backend.default_max_iterations)
        iterations += out.iterations
        if out.converged:
            lam = np.minimum(np.maximum(out.actuation * second.scale, condensed.lambda_lower), condensed.lambda_upper)
    mu_A = F0 + F1 @ lam
    mu = np.zeros(m)
    mu[active] = mu_A
    w = c + W_ca @ lam + W_cc @ mu
    de, da = condensed.predict(lam)
    zeros = np.zeros(n)
    zeros.flags.writeable = False
    sol = ConstraintSolution(actuation=lam, delta_e=de, delta_a=da, effector_error=math.sqrt(float(de @ de)),
                             iterations=iterations, converged=True, status="optimal", backend=backend.name,
                             time_s=0.0, displacement_relaxation=zeros,
                             regularisation_weight=form.regularisation_weight, problem=condensed,
                             displacement_bounds=(space.displacement_lower, space.displacement_upper))
    return lam, mu_A, w, condensed, (F0, F1), sol, active
