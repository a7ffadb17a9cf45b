"""Independent reference solutions for canonical problems (tests, benchmarks, docs).

None of these use the frame/link machinery: they come from closed forms or from
scipy's boundary-value solver on the planar elastica.
"""

from __future__ import annotations

import numpy as np


def elastica_tip(load_parameter: float, length: float = 1.0) -> np.ndarray:
    """Tip ``(x, z)`` of an inextensible, shear-rigid cantilever along +z under a dead tip
    force along +x with ``P L² / EI = load_parameter``.

    Planar elastica in arc length scaled to ``[0, 1]``: ``θ'' = −k cos θ``, ``θ(0) = 0``,
    ``θ'(1) = 0``, ``x' = sin θ``, ``z' = cos θ``. Solved by shooting on the root curvature
    ``θ'(0) ∈ [0, k]`` (``brentq``) with an 8th-order Runge–Kutta integrator at rtol 1e-13.
    """
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    k = float(load_parameter)

    def integrate(kappa0):
        rhs = lambda s, y: [y[1], -k * np.cos(y[0]), np.sin(y[0]), np.cos(y[0])]
        return solve_ivp(rhs, (0.0, 1.0), [0.0, kappa0, 0.0, 0.0], method="DOP853",
                         rtol=1e-13, atol=1e-15).y[:, -1]

    if k == 0.0:
        return np.array([0.0, length])
    kappa0 = brentq(lambda c: integrate(c)[1], 0.0, k, xtol=1e-15, rtol=1e-15)
    end = integrate(kappa0)
    return length * np.array([end[2], end[3]])


def arc_tip(moment_parameter: float, length: float = 1.0) -> np.ndarray:
    """Tip ``(x, z)`` of a cantilever along +z under a pure end moment bending it toward +x,
    ``M L / EI = moment_parameter`` (the total turning angle): a circular arc."""
    angle = float(moment_parameter)
    if angle == 0.0:
        return np.array([0.0, length])
    radius = length / angle
    return np.array([radius * (1.0 - np.cos(angle)), radius * np.sin(angle)])


def cantilever_deflection_uniform_load(load_per_length: float, length: float, bending_stiffness: float) -> float:
    """Euler–Bernoulli tip deflection ``qL⁴ / 8EI`` of a cantilever under a uniform load."""
    return load_per_length * length ** 4 / (8.0 * bending_stiffness)


def column_tip_angle(load_ratio: float) -> float:
    """Tip rotation (rad) of the buckled inextensible clamped-free column (the elastica) under an
    axial dead tip force of ``load_ratio`` × the Euler load ``π²EI/4L²``:
    ``load_ratio = (2K(k)/π)²`` with ``k = sin(α/2)`` (K the complete elliptic integral of the
    first kind). 0 below the Euler load."""
    from scipy.optimize import brentq
    from scipy.special import ellipk

    if load_ratio <= 1.0:
        return 0.0
    m = brentq(lambda m: (2.0 * ellipk(m) / np.pi) ** 2 - load_ratio, 0.0, 1.0 - 1e-16, xtol=1e-15, rtol=1e-15)
    return 2.0 * float(np.arcsin(np.sqrt(m)))
