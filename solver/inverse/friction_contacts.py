"""Friction at obstacle contacts in the inverse's constraint-space QP (docs/contact.md, "Friction").

The frictionless QP (:mod:`~vertebra.solver.inverse.contacts`) has one row per candidate contact,
its gap. With friction each frictional candidate adds its two slip rows
(:class:`~vertebra.solver.contact_friction.Anchors`, anchored at the friction state the step
starts from), with tangential forces as variables beside the normal ones::

    w(λ, μ) = c + W_ca λ + W_cc μ        (gaps, then slips)

and the answer must respect the friction law: a pressed contact *sticks* (its slips stay zero,
its tangential force within the cone ``|μ_t| ≤ μ μ_n`` — in the QP the inscribed polygon of
:data:`FACETS` sides) or *slips* (``μ_t = −μ μ_n d``, the slip along ``d``). For a set of
statuses the forces are affine in the efforts, ``μ_A(λ) = F0 + F1 λ`` (the pressed contacts'
gaps and the stuck ones' slips closed, the slipping ones' tangential forces tied to their normal
ones), and the QP is the ordinary one on the condensed problem with the rows: normal forces ≥ 0,
the stuck contacts' cones, the slipping ones' slips along ``d``, the open gaps ≥ 0. The set starts
as the frictional complementarity problem's answer at the current efforts
(:func:`~vertebra.solver.contact_friction.coulomb`) and changes where the answer rests on a row
(a force brought to zero opens its contact, a gap closed presses it, a cone reached slips the
contact opposite its tangential force, a slip reversed sticks it): an active-set method to a
local optimum, as without friction. The controller so uses friction — a trunk pressing on a wall
holds a tangential load there — instead of assuming the contacts slide freely.
"""

from __future__ import annotations

import math

import numpy as np

from vertebra.solver import contact, contact_friction
from vertebra.solver.contact_friction import Friction, coefficients, coulomb
from vertebra.solver.inverse.contacts import ROUNDS, ContactProjection, condensed_qp, project_rows, settle

FACETS = 16                # sides of the polygon inscribed in each stuck contact's cone (in the QP)


def frictional_step(trunk, state, lin, projection, backend, history, *, tolerance: float, slack):
    """:func:`~vertebra.solver.inverse.contacts.contact_step` with friction (module docstring):
    ``history`` the friction state whose state anchors the contacts. Returns (the projection, the
    solution), or None when no contact is near."""
    model = trunk.contact
    found = contact.evaluate(model, state)
    if not found.count:
        return None
    mu_all = coefficients(model, found.key)
    fr = np.flatnonzero(mu_all > 0.0)
    mu = mu_all[fr]
    anchors = contact_friction.Anchors.at(model, history.state, found.key[fr])
    rows = contact_friction._joined(found, anchors.rows(state))
    m, total = found.count, rows.count
    problem = projection.problem
    G = rows.jacobian(trunk.frames.count)
    KG, W_ec, W_ac, W_ca, W_cc, c = project_rows(lin, problem, G, rows.gap)
    lam0 = problem.lambda0
    law = (m, fr, mu)

    def solve(status):
        return _solve_set(problem, backend, tolerance, slack, status, law, c, W_ca, W_cc, W_ec, W_ac)

    at_start = coulomb(W_cc, c + W_ca @ lam0, m, fr, mu)
    start = (at_start[1] if at_start is not None else
             Friction(found.gap <= 1e-9 * model.length, np.zeros(fr.size, bool), np.tile([1.0, 0.0], (fr.size, 1))))
    answer = _settle(solve, start, law, model.length)
    if answer is None:
        return None
    _, _, _, condensed, force_of, sol, active, status = answer
    normal = np.arange(total) < m
    return (ContactProjection(projection, condensed, active, found, force_of, KG, G, W_ec, model, normal, status),
            sol)


def _set_rows(status: Friction, law) -> tuple[np.ndarray, np.ndarray]:
    """The rows whose forces a set carries (the pressed contacts' gaps and their slip rows, when
    frictional), and which of those the set closes (``w = 0``; the others are tied)."""
    m, fr, _ = law
    pressed = np.flatnonzero(status.closed)
    active, closes = list(pressed), [True] * pressed.size
    for c, i in enumerate(fr.tolist()):
        if status.closed[i]:
            active += [m + 2 * c, m + 2 * c + 1]
            closes += [not status.slip[c]] * 2
    return np.array(active, int), np.array(closes, bool)


def _solve_set(problem, backend, tolerance, slack, status: Friction, law, c, W_ca, W_cc, W_ec, W_ac):
    m, fr, mu = law
    n = problem.n_actuators
    active, closes = _set_rows(status, law)
    total = c.size
    inactive = np.setdiff1d(np.arange(m), active)               # open contacts (their gaps)
    k = active.size
    if k:
        # closed rows: w_row = 0 → W[row, A] μ_A = −(c_row + W_ca[row] λ); tied rows: μ_t + μ d μ_n = 0
        M = np.zeros((k, k))
        h0, h1 = np.zeros(k), np.zeros((k, n))
        position = {int(r): j for j, r in enumerate(active.tolist())}
        for j, row in enumerate(active.tolist()):
            if closes[j]:
                M[j] = W_cc[row, active]
                h0[j], h1[j] = c[row], W_ca[row]
            else:
                contact_index = (row - m) // 2
                M[j, j] = 1.0
                M[j, position[int(fr[contact_index])]] = mu[contact_index] * status.direction[contact_index, (row - m) % 2]
        try:
            F1 = -np.linalg.solve(M, h1)
            F0 = -np.linalg.solve(M, h0)
        except np.linalg.LinAlgError:
            return None
    else:
        F0, F1 = np.zeros(0), np.zeros((0, n))
    position = {int(r): j for j, r in enumerate(active.tolist())}
    rows, low = [], []
    for j, row in enumerate(active.tolist()):
        if row < m:                                               # normal forces ≥ 0
            rows.append(F1[j])
            low.append(-F0[j])
    angles = 2.0 * math.pi * np.arange(FACETS) / FACETS
    inscribed = math.cos(math.pi / FACETS)
    for index, i in enumerate(fr.tolist()):
        if not status.closed[i]:
            continue
        a, b, nn = position[m + 2 * index], position[m + 2 * index + 1], position[int(i)]
        if not status.slip[index]:
            # the polygon inside the cone: μ cos(π/N) μ_n − (cos θ, sin θ)·μ_t ≥ 0
            for theta in angles.tolist():
                u = np.array([math.cos(theta), math.sin(theta)])
                rows.append(mu[index] * inscribed * F1[nn] - u[0] * F1[a] - u[1] * F1[b])
                low.append(-(mu[index] * inscribed * F0[nn] - u[0] * F0[a] - u[1] * F0[b]))
        else:
            # the slip along its direction: d·w_t ≥ 0
            d = status.direction[index]
            t = np.array([m + 2 * index, m + 2 * index + 1])
            w1 = W_ca[t] + W_cc[np.ix_(t, active)] @ F1
            w0 = c[t] + W_cc[np.ix_(t, active)] @ F0
            rows.append(d @ w1)
            low.append(-(d @ w0))
    for i in inactive.tolist():                                  # open gaps ≥ 0
        rows.append(W_ca[i] + W_cc[i, active] @ F1)
        low.append(-(c[i] + W_cc[i, active] @ F0))
    rows = np.array(rows, float).reshape(-1, n)
    low = np.array(low, float)
    found = condensed_qp(problem, backend, tolerance, slack, active, F0, F1, rows, low, c, W_ca, W_cc, W_ec, W_ac)
    if found is None:
        return None
    return found + (status,)


def _settle(solve, status: Friction, law, length: float):
    """The active-set rounds from ``status`` (module docstring): the last answer consistent with it."""
    m, fr, mu = law

    def change(status, found):
        _, mu_A, w, _, _, _, active, _ = found
        force = np.zeros(w.size)
        force[active] = mu_A
        scale = max(float(np.abs(force[:m]).max(initial=0.0)), 1e-300)
        new = Friction(status.closed.copy(), status.slip.copy(), status.direction.copy())
        changed = False
        for i in range(m):
            if status.closed[i] and force[i] <= 1e-12 * scale:
                new.closed[i], changed = False, True
            elif not status.closed[i] and w[i] <= 1e-12 * length:
                new.closed[i], changed = True, True
        for c, i in enumerate(fr.tolist()):
            if not (status.closed[i] and new.closed[i]):
                new.slip[c] = False
                continue
            f_t = force[m + 2 * c:m + 2 * c + 2]
            w_t = w[m + 2 * c:m + 2 * c + 2]
            if not status.slip[c]:
                if math.hypot(*f_t) >= (1.0 - 1e-9) * mu[c] * math.cos(math.pi / FACETS) * force[i]:
                    new.slip[c], changed = True, True          # on the cone: slips opposite its force
                    new.direction[c] = -f_t / max(math.hypot(*f_t), 1e-300)
            elif float(w_t @ status.direction[c]) <= 1e-12 * length:
                new.slip[c], changed = False, True              # its slip reversed: sticks
        return new if changed else None

    return settle(solve, status, lambda s: (tuple(s.closed.tolist()), tuple(s.slip.tolist())), change, 2 * ROUNDS)
