"""A transmission play that grows with the tension the tendon carries.

Friction between servo, spool and the tendon's sheath or base holes is proportional to the force
the tendon carries: the stroke that reaches the tendon trails a rising command and leads a
falling one by ``w = b0 + b1·T``, ``T`` the tendon's tension at the sample's equilibrium
(``backlash`` b0, m, and ``backlash_rate`` b1, m/N, per driven tendon). Within the play the
stroke stays where it was (:func:`~vertebra.solver.calibration.data.play` is the case
``b1 = 0``). ``T`` depends on the strokes of the sample's equilibrium, so the strokes are an
implicit relation along the time-ordered samples:

    s_k,i = s_k−1,i                     if |s_k−1,i − c_k,i| ≤ w_k,i   (held)
    s_k,i = c_k,i − σ_i w_k,i           otherwise, σ_i = sign(c_k,i − s_k−1,i)
    w_k,i = b0_i + b1_i T_i(s_k)

Solved by Newton over the whole sequence (:class:`~vertebra.solver.calibration.backend.RuntimePredictor`):
every sample's equilibrium and its tensions' derivatives by the strokes ``G_k = ∂T/∂s`` at the
current strokes, then :func:`march` — the rows in order, each one's strokes from its predecessor's
with the tensions linearised, ``T(s) ≈ T_k + G_k (s − s̄_k)`` (a small linear system per row, its
held/moving statuses iterated) — until no stroke moves by more than the tolerance.

The derivatives (:func:`stroke_derivatives`) follow the rows in the same order: a moving stroke's
``(I + Σ b1 G_k) ds_k = −σ (db0 + T db1 + b1 ∂T/∂θ dθ)``, a held one's ``ds_k = ds_k−1``; the
markers' ``∂m/∂θ + ∂m/∂s ds_k``, both partials the model's exact sensitivities at the sample.
"""

from __future__ import annotations

import numpy as np

__all__ = ["march", "stroke_derivatives"]

#: status iterations of one row in :func:`march` (moving/held switches of its tendons)
ROW_ITERATIONS = 20


def _widths(b0, b1, tension):
    return b0 + b1 * np.maximum(tension, 0.0)


#: a tendon's status in a row: trailing a rising command, leading a falling one, held where it was,
#: held by the friction at its entry at the tension it can hold
RISING, FALLING, HELD, HOLDING = 1, -1, 0, -2


def march(commands, b0, b1, tension, gradient, at, hold=None):
    """Strokes (n, a) and statuses (n, a: :data:`RISING`, :data:`FALLING`, :data:`HELD`,
    :data:`HOLDING`) of the time-ordered ``commands`` (n, a) through the play ``b0 + b1·T``
    with each row's tensions linearised about the strokes ``at`` (n, a): ``T(s) = tension +
    gradient (s − at)`` (``tension`` (n, a), ``gradient`` (n, a, a)). ``hold`` (a,) N: the
    friction at each tendon's entry — a released tendon slides back into the robot only while
    its tension there exceeds ``hold``, so a falling stroke stops where ``T(s) = hold``
    (None: no such friction). The first row starts where it is commanded."""
    commands = np.asarray(commands, float)
    n, a = commands.shape
    hold = np.zeros(a) if hold is None else np.asarray(hold, float)
    holding = bool(np.any(hold > 0.0))
    strokes, status = commands.copy(), np.zeros((n, a), int)
    eye = np.eye(a)
    for k in range(1, n):
        c, previous, G = commands[k], strokes[k - 1], gradient[k]
        offset = tension[k] - G @ at[k]                    # T(s) = offset + G s
        guess = at[k]
        sigma = None
        for _ in range(ROW_ITERATIONS):
            T = offset + G @ guess
            w = _widths(b0, b1, T)
            new = np.where(previous < c - w, RISING, np.where(previous > c + w, FALLING, HELD))
            if holding:
                # a falling tendon's own tension where it was and where the play would take it (the
                # others' strokes at the guess): held below ``hold``, stopped at ``T = hold`` between
                diagonal = np.diag(G)
                there = T + diagonal * (previous - guess)
                played = T + diagonal * (c + w - guess)
                falling = new == FALLING
                new = np.where(falling & (hold > 0.0) & (there <= hold), HELD,
                               np.where(falling & (hold > 0.0) & (played < hold), HOLDING, new))
            if sigma is not None and np.array_equal(new, sigma):
                break
            sigma = new
            moving = (sigma == RISING) | (sigma == FALLING)
            sign = np.where(moving, sigma, 0)
            # moving rows: s_i + σ_i b1_i (G s)_i = c_i − σ_i (b0_i + b1_i offset_i); holding rows:
            # (G s)_i = hold_i − offset_i; held rows: s_i = previous_i
            A = eye + (sign * b1)[:, None] * G
            A[sigma == HOLDING] = G[sigma == HOLDING]
            rhs = np.where(moving, c - sign * (b0 + b1 * offset),
                           np.where(sigma == HOLDING, hold - offset, previous))
            guess = np.linalg.solve(A, rhs)
        strokes[k], status[k] = guess, sigma
    return strokes, status


def stroke_derivatives(status, b1, tension, gradient, d_tension, d_b0, d_b1, d_hold=None):
    """(n, a, P): the strokes' derivatives by P parameters along the sequence, for the statuses
    of :func:`march` and the sample's exact tensions ``tension`` (n, a), their derivatives by the
    strokes ``gradient`` (n, a, a) and by the parameters at fixed strokes ``d_tension`` (n, a, P);
    ``d_b0``, ``d_b1``, ``d_hold`` (a, P): each tendon's play, rate and entry friction as
    functions of the parameters (1 where a column is that element)."""
    n, a = status.shape
    P = d_tension.shape[-1]
    d_hold = np.zeros((a, P)) if d_hold is None else d_hold
    out = np.zeros((n, a, P))
    eye = np.eye(a)
    for k in range(1, n):
        sigma = status[k]
        moving = (sigma == RISING) | (sigma == FALLING)
        sign = np.where(moving, sigma, 0)
        A = eye + (sign * b1)[:, None] * gradient[k]
        holds = sigma == HOLDING
        A[holds] = gradient[k][holds]
        taut = (tension[k] > 0.0)[:, None]
        rhs = np.where(moving[:, None],
                       -sign[:, None] * (d_b0 + np.maximum(tension[k], 0.0)[:, None] * d_b1
                                         + b1[:, None] * taut * d_tension[k]),
                       np.where(holds[:, None], d_hold - d_tension[k], out[k - 1]))
        out[k] = np.linalg.solve(A, rhs)
    return out
