"""Closed forms and one-dimensional references for validating the nonlinear FE models.

Independent of the FE discretisation: tests and benchmarks compare the 3-D models
with these (not part of the installed package).

* :func:`lame_plane_strain_radial` — Lamé's thick-walled cylinder under internal
  pressure, plane strain, small strain.
* :func:`neo_hookean_tube_plane_strain` — the same cylinder at finite strain for
  the compressible neo-Hooke law of :mod:`vertebra.designer.nonlinear.materials` (Abaqus/CalculiX form),
  plane strain (axial stretch 1), follower pressure on the deformed bore: the
  radial equilibrium ``d/dR (R P_rr) = P_θθ`` in the reference configuration with
  ``P_rr(A) = −p r(A)/A`` (Cauchy ``σ_rr = −p`` on the deformed bore) and
  ``P_rr(B) = 0``, solved with ``scipy.integrate.solve_bvp``. ``P_rr = ∂W/∂λ_r``,
  ``P_θθ = ∂W/∂λ_θ`` are written out here from ``W(λ_r, λ_θ, 1)``, not taken from
  the FE material code.
* :func:`planar_elastica_tip` — the planar elastica of an inextensible cantilever
  under a dead tip force (Euler–Bernoulli, large rotation).
"""

from __future__ import annotations

import numpy as np


def lame_plane_strain_radial(r, pressure, inner_radius, outer_radius, youngs_modulus, poisson_ratio):
    """Radial displacement at radius ``r`` (plane strain, small strain, bore pressure ``pressure``)."""
    a, b, E, nu = inner_radius, outer_radius, youngs_modulus, poisson_ratio
    r = np.asarray(r, dtype=float)
    return pressure * a ** 2 * (1 + nu) / (E * (b ** 2 - a ** 2)) * ((1 - 2 * nu) * r + b ** 2 / r)


def _neo_hookean_principal(l1, l2, mu, K):
    """``∂W/∂λ₁`` and its derivatives ``∂²W/∂λ₁²``, ``∂²W/∂λ₁∂λ₂`` for
    ``W = μ/2 (J^(−2/3) I₁ − 3) + K/2 (J − 1)²`` with ``λ₃ = 1``, ``J = λ₁ λ₂``, ``I₁ = λ₁² + λ₂² + 1``."""
    J = l1 * l2
    I1 = l1 ** 2 + l2 ** 2 + 1.0
    a = J ** (-2.0 / 3.0)
    P = mu * a * l1 - mu / 3.0 * a * I1 / l1 + K * (J - 1.0) * l2
    P11 = mu * a * (-1.0 / 3.0 + 5.0 / 9.0 * I1 / l1 ** 2) + K * l2 ** 2
    P12 = mu * a * (-2.0 / 3.0 * (l1 / l2 + l2 / l1) + 2.0 / 9.0 * I1 / J) + K * (2.0 * J - 1.0)
    return P, P11, P12


def neo_hookean_tube_plane_strain(pressure, inner_radius, outer_radius, youngs_modulus, poisson_ratio,
                                  n_points: int = 201, tol: float = 1e-9, steps: int = 8):
    """Deformed radius ``r(R)`` of the plane-strain neo-Hookean tube; returns ``(R, r)`` on a grid.
    Solved in units of the bore radius and the shear modulus, by continuation in ``steps``
    pressure increments (each solution is the next initial guess)."""
    from scipy.integrate import solve_bvp

    A, B = float(inner_radius), float(outer_radius)
    E, nu = youngs_modulus, poisson_ratio
    mu = E / (2 * (1 + nu))
    K = E / (3 * (1 - 2 * nu)) / mu
    p = pressure / mu

    def rhs(R, y):
        r, dr = y
        l1, l2 = dr, r / R
        # d/dR (R P(λ_r, λ_θ)) = P(λ_θ, λ_r) with λ_r = r', λ_θ = r/R (unit shear modulus)
        P1, P11, P12 = _neo_hookean_principal(l1, l2, 1.0, K)
        P2 = _neo_hookean_principal(l2, l1, 1.0, K)[0]
        dl2 = (dr - r / R) / R
        return np.vstack([dr, (P2 - P1 - R * P12 * dl2) / (R * P11)])

    R = np.linspace(1.0, B / A, n_points)
    guess = np.vstack([R, np.ones_like(R)])
    for step in range(1, steps + 1):
        q = p * step / steps

        def bc(ya, yb, q=q):
            return np.array([_neo_hookean_principal(ya[1], ya[0], 1.0, K)[0] + q * ya[0],
                             _neo_hookean_principal(yb[1], yb[0] / (B / A), 1.0, K)[0]])

        solution = solve_bvp(rhs, bc, R, guess, tol=tol, max_nodes=100000)
        if not solution.success:
            raise RuntimeError(f"solve_bvp at {q * mu:.6g} Pa: {solution.message} (past the inflation limit point?)")
        guess = solution.sol(R)
    return R * A, guess[0] * A


def planar_elastica_tip(force_ratio: float, angle: float = np.pi / 2, n_points: int = 401):
    """Tip of an inextensible cantilever of unit length, clamped along ``e_x``... (see module doc).

    ``force_ratio = P L² / EI`` for a dead force perpendicular to the clamped tangent
    (``angle`` = π/2) or at ``angle`` from it; returns the tip position ``(x, y)/L`` and the
    tip rotation (rad). Solves ``θ'' = −k (cos α sin θ' ...)`` as the BVP
    ``θ'' + k (sin(α) cos θ − cos(α) sin θ) = 0``, ``θ(0) = 0``, ``θ'(1) = 0``."""
    from scipy.integrate import solve_bvp

    k = float(force_ratio)
    fx, fy = np.cos(angle), np.sin(angle)

    def rhs(s, y):
        theta, kappa = y
        # moment balance of the part beyond s: EI θ' = (r_tip − r(s)) × F  ⇒  EI θ'' = −t(s) × F
        return np.vstack([kappa, -k * (np.cos(theta) * fy - np.sin(theta) * fx)])

    def bc(ya, yb):
        return np.array([ya[0], yb[1]])

    s = np.linspace(0.0, 1.0, n_points)
    solution = solve_bvp(rhs, bc, s, np.vstack([0.0 * s, 0.0 * s]), tol=1e-10, max_nodes=100000)
    if not solution.success:
        raise RuntimeError(f"solve_bvp: {solution.message}")
    theta = solution.sol(s)[0]
    from scipy.integrate import trapezoid
    x = trapezoid(np.cos(theta), s)
    y = trapezoid(np.sin(theta), s)
    return np.array([x, y]), float(theta[-1])
