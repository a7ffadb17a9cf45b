"""A stand-in for a segment's nonlinear FE with a known energy, for tests of the sampling and the fit.

``OracleSegment`` answers ``solve(R, t, pressures)`` like the nonlinear FE (load and tangent
in the pose chart of a left perturbation of frame b, cavity volumes and their derivatives)
from an energy it knows in closed form::

    ψ(s, p) = ψ_lin(s, p) + poly(s, p) + κ F(|φ⊥|²/θ₀²) + Σ_k f(p_k)

``ψ_lin`` from a Timoshenko rod's compliance (the entry); ``poly``: a given invariant
polynomial of degree ≥ 3; ``F(b) = cosh √b − 1 − b/2`` (not a polynomial: degree-d fits
approximate it); ``f`` a chamber that balloons to an inflation limit point at ``p_limit``
(``ΔV = c (1 − √(1 − p/p_limit))`` minus its linear part), beyond which ``solve`` raises
ConvergenceError. Every term has no part below degree 3 except ``ψ_lin``, so the Hessian
at rest is the entry's.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from vertebra.designer.energy_fit import FitResult, pose_derivatives
from vertebra.solver.timoshenko import Section, timoshenko_compliance
from vertebra.core.energy import EnergyFit, EnergyModel, EnergyRange, linear_terms, rest_strain
from vertebra.store.entry import SegmentEntry
from vertebra.core.errors import ConvergenceError


def rod_entry(length=0.04, radius=0.01, youngs_modulus=1e6, poisson_ratio=0.3, cavities=0,
              cavity_coupling=2e-9, cavity_compliance=4e-12) -> SegmentEntry:
    """A linear entry: Timoshenko rod compliance; with cavities, a pressure → displacement
    coupling G (bending away from each cavity at angle 2πk/n) and a volume compliance V."""
    C = timoshenko_compliance(length, youngs_modulus, youngs_modulus / (2 * (1 + poisson_ratio)),
                              Section.circle(radius, poisson_ratio))
    n = cavities
    G = np.zeros((6, n))
    for k in range(n):
        angle = 2 * math.pi * k / n
        G[2, k] = cavity_coupling * 0.2                               # stretch
        G[3:5, k] = cavity_coupling / radius * np.array([math.sin(angle), -math.cos(angle)])
    V = cavity_compliance * (np.eye(n) * 1.0 + 0.05 * (np.ones((n, n)) - np.eye(n)))
    V = V + G.T @ np.linalg.solve(C, G)          # keeps [[C, G], [Gᵀ, V]] positive definite
    compliance = np.block([[C, G], [G.T, V]])
    return SegmentEntry(key="oracle", name="oracle", family="rod", parameters={"length": length},
                        compliance=compliance, cavity_volumes=np.full(n, 2e-6), mass=0.0,
                        center_of_mass=np.array([0, 0, length / 2]), rest_translation=np.array([0, 0, length]))


def _cosh_terms(b):
    """F(b), F'(b), F''(b) of F(b) = cosh √b − 1 − b/2 (series below b = 1e-2)."""
    small = b < 1e-2
    bs = np.where(small, 1.0, b)
    r = np.sqrt(bs)
    F = np.where(small, b ** 2 / 24 + b ** 3 / 720 + b ** 4 / 40320, np.cosh(r) - 1 - bs / 2)
    F1 = np.where(small, b / 12 + b ** 2 / 240 + b ** 3 / 10080, np.sinh(r) / (2 * r) - 0.5)
    F2 = np.where(small, 1 / 12 + b / 120 + b ** 2 / 3360, np.cosh(r) / (4 * bs) - np.sinh(r) / (4 * bs * r))
    return F, F1, F2


@dataclass
class Response:
    wrench: np.ndarray
    tangent: np.ndarray
    volumes: np.ndarray
    dvolume_dpose: np.ndarray
    dvolume_dpressure: np.ndarray
    state: object = None


@dataclass
class OracleSegment:
    entry: SegmentEntry
    polynomial: FitResult | None = None       # the polynomial part (scaled monomials)
    kappa: float = 0.0                        # J, weight of F(|φ⊥|²/θ₀²)
    theta0: float = 0.5
    balloon: float = 0.0                      # c of the chamber term, m³
    p_limit: float = math.inf
    solves: int = field(default=0)

    @property
    def n_cavities(self) -> int:
        return self.entry.n_cavities

    def derivatives(self, s, p):
        """(gradient (n, 6+m), Hessian (n, 6+m, 6+m)) of ψ in the strain chart."""
        return self.terms(s, p)[1:]

    def terms(self, s, p):
        """(ψ (n,), gradient (n, 6+m), Hessian (n, 6+m, 6+m)) in the strain chart."""
        linear = linear_terms(self.entry.compliance, self.entry.rest_translation)
        m = self.n_cavities
        poly = self.polynomial
        exponents = np.zeros((0, 6 + m), dtype=np.int64) if poly is None else poly.exponents
        wide, low = np.full(4, 1e300), np.array([0.0, -1e300, 0.0, -1e300])
        model = EnergyModel(EnergyFit(exponents, np.zeros(0) if poly is None else poly.coefficients,
                                      np.ones(6 + m) if poly is None else poly.scales,
                                      EnergyRange(low, wide, low, wide, np.full(m, -1e300), np.full(m, 1e300))),
                            *linear)
        values = model.evaluate(s, p)
        energy = values.energy.copy()
        g = np.concatenate([values.gradient, values.pressure_gradient], 1)
        H = np.concatenate([np.concatenate([values.hessian, values.mixed_hessian], 2),
                            np.concatenate([values.mixed_hessian.mT, values.pressure_hessian], 2)], 1)
        if self.kappa:
            phi = s[:, 3:5] / self.theta0
            F, F1, F2 = _cosh_terms((phi * phi).sum(1))
            d = 2 * phi / self.theta0
            energy += self.kappa * F
            g[:, 3:5] += self.kappa * F1[:, None] * d
            H[:, 3:5, 3:5] += self.kappa * (F2[:, None, None] * d[:, :, None] * d[:, None, :]
                                            + F1[:, None, None] * 2 * np.eye(2) / self.theta0 ** 2)
        if self.balloon and m:
            x = p / self.p_limit
            root = np.sqrt(np.clip(1 - x, 1e-300, None))
            dV = self.balloon * (1 - root) - self.balloon * x / 2            # ΔV minus its linear part
            ddV = self.balloon / (2 * self.p_limit) * (1 / root - 1)
            energy -= self.balloon * (p + 2 * self.p_limit / 3 * (root ** 3 - 1) - p * x / 4).sum(1)
            g[:, 6:] -= dV
            H[:, 6:, 6:] -= ddV[:, :, None] * np.eye(m)[None]
        return energy, g, H

    def solve(self, R, t, pressures=None, initial=None, min_load_step=None):
        from scipy.spatial.transform import Rotation
        from vertebra.core.lie import se3_log

        m = self.n_cavities
        p = np.zeros(m) if pressures is None else np.asarray(pressures, float).reshape(m)
        if m and np.any(p >= self.p_limit):
            raise ConvergenceError(f"oracle: pressure {p.max():.4g} beyond the limit point {self.p_limit:.4g}")
        x, y, zq, w = Rotation.from_matrix(np.asarray(R)).as_quat()
        xi, _ = se3_log(np.array([[w, x, y, zq]]), np.asarray(t, float)[None])
        xi0, _ = rest_strain(self.entry.rest_translation)
        s = xi - xi0
        g, H = self.derivatives(s, p[None])
        wrench, tangent, mixed = pose_derivatives(s, self.entry.rest_translation, g[:, :6], H[:, :6, :6],
                                                  H[:, :6, 6:])
        self.solves += 1
        return Response(wrench=wrench[0], tangent=tangent[0],
                        volumes=self.entry.cavity_volumes - g[0, 6:], dvolume_dpose=-mixed[0].T,
                        dvolume_dpressure=-H[0, 6:, 6:])


class OracleEnergy:
    """The oracle's ψ as a chain segment (reference.energy_chain.SegmentEnergy): the true chain."""

    def __init__(self, oracle: OracleSegment):
        self.oracle = oracle
        self.rest_translation = oracle.entry.rest_translation
        self.n_cavities = oracle.n_cavities

    def evaluate(self, s, p):
        energy, g, H = self.oracle.terms(s[None], p[None])
        return float(energy[0]), g[0, :6], H[0, :6, :6], -g[0, 6:]


@dataclass(frozen=True)
class OracleSpec:
    """ModelSpec of an :class:`OracleSegment` (picklable: its arguments as plain data)."""

    cavities: int = 0
    kappa: float = 0.0
    coupling: float = 0.0                 # weight of ρ_z |φ⊥|² (J) in the polynomial part
    balloon: float = 0.0
    p_limit: float = math.inf

    def key(self) -> str:
        return json.dumps([self.cavities, self.kappa, self.coupling, self.balloon, self.p_limit])

    def build(self) -> OracleSegment:
        entry = rod_entry(cavities=self.cavities)
        polynomial = None
        if self.coupling:
            nv = 6 + self.cavities
            exponents = np.zeros((2, nv), dtype=np.int64)
            exponents[0, [2, 3]] = [1, 2]
            exponents[1, [2, 4]] = [1, 2]
            polynomial = FitResult(exponents=exponents, coefficients=np.array([self.coupling, self.coupling]),
                                   scales=np.ones(nv), unknowns=0, errors={})
        return OracleSegment(entry=entry, polynomial=polynomial, kappa=self.kappa, balloon=self.balloon,
                             p_limit=self.p_limit)
