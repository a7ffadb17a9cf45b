"""Nonlinear catalogue entries for tests: synthetic ones with a known fitted energy (tests of
the runtime's ``nonlinear-entry`` link kind without the nonlinear FE), and one designed coarse
neo-Hookean rod (:func:`nonlinear_rod`, designed once per test process).

:func:`with_energy` gives a linear entry a ψ_nl of degree 3–4 in the scaled variables
``u = [s; p] / scales``: a convex quartic ``κ E₀ |u|⁴`` (so Newton has a minimum to find at any
load) plus ``strength E₀`` times seeded random coefficients on every monomial of degree 3 and 4
(so every derivative, pressure couplings included, is exercised). ``E₀`` is the linear energy
of a unit scaled strain along its softest direction. The range is a box around the scales.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from vertebra.core.energy import EnergyFit, EnergyRange, linear_terms, monomial_exponents


ROD = {"radius": 0.01, "length": 0.04, "youngs_modulus": 1e6, "poisson_ratio": 0.3}
ROD_MESH = 0.008                                         # 1.1k DoFs: a coarse P2 rod
ROD_SAMPLING = {"paths": 8, "steps": 4, "degree": 6}


@functools.cache
def nonlinear_rod():
    """The neo-Hookean rod entry (``ROD`` on ``ROD_MESH``, ``ROD_SAMPLING``; ~6 s, once)."""
    from vertebra import designer

    return designer.design_segment("rod", ROD, mesh_size=ROD_MESH, material="neo_hookean", sampling=ROD_SAMPLING,
                                   estimate_accuracy=False, executor="serial")


def with_energy(entry, *, strength=0.05, convex=0.5, seed=0, bending=0.8, twist=0.6, stretch=0.2,
                pressure=1.5e5, fold_pressure=None, limit_pressure=None, load_factor=4.0):
    """``entry`` with a fitted energy (module docstring); ``bending``/``twist`` (rad) and
    ``stretch`` (fraction of the length) are the variable scales and the strain range, the load
    range is ``load_factor`` × the linear loads of those strains, pressures in [0, pressure]."""
    m = entry.n_cavities
    length = float(np.linalg.norm(entry.rest_translation))
    scales = np.array([stretch * length] * 3 + [bending, bending, twist] + [pressure] * m)
    K, _, _ = linear_terms(entry.compliance, entry.rest_translation)
    unit = np.diag(scales[:6]) @ K @ np.diag(scales[:6])
    E0 = 0.5 * float(np.linalg.eigvalsh(unit).min())
    exponents = monomial_exponents(6 + m, 4, 3)
    coefficients = strength * E0 * np.random.default_rng(seed).normal(size=exponents.shape[0])
    degree = exponents.sum(1)
    quartic = degree == 4
    # κ|u|⁴ = κ Σ u_i⁴ + 2κ Σ_{i<j} u_i² u_j²: the even monomials of degree 4 with two squares
    squares = quartic & np.all(exponents % 2 == 0, axis=1)
    coefficients[squares] += np.where(exponents[squares].max(1) == 4, 1.0, 2.0) * convex * E0
    loads = load_factor * np.abs(K) @ scales[:6]
    lateral = math.hypot(loads[0], loads[1])
    bend = math.hypot(loads[3], loads[4])
    fitted_range = EnergyRange(
        pose_lower=[0.0, -stretch * length, 0.0, -twist],
        pose_upper=[stretch * length, stretch * length, bending, twist],
        load_lower=[0.0, -loads[2], 0.0, -loads[5]], load_upper=[lateral, loads[2], bend, loads[5]],
        pressure_lower=np.zeros(m), pressure_upper=np.full(m, pressure), limit_pressure=limit_pressure)
    fit = EnergyFit(exponents=exponents, coefficients=coefficients, scales=scales, range=fitted_range,
                    fit_error={"held_out": {"load_max": 0.0}}, material={"model": "synthetic"},
                    sampling={"samples": 0}, fold_pressure=fold_pressure)
    return dataclasses.replace(entry, key=entry.key + "-nl", name=entry.name + "-nl", energy=fit)
