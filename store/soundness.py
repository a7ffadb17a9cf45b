"""Physical soundness of a catalogue entry: what its parameters allow its numbers to be.

A checksum proves that an entry is what its writer stored, not that the writer stored
something physical: a crafted entry (compliance × 1e290, re-checksummed) or a mis-scaled
one would pass it and break a solve. :func:`soundness_problems` checks, for every entry:

* **generic** (any family): compliance finite, symmetric, positive definite (the whole
  (6+n)×(6+n) matrix: it is a complementary energy) with diagonal entries in
  [1e-60, 1e60] (SI units; far outside any segment); mass, centre of mass, rest pose and
  cavity volumes finite, mass ≥ 0, cavity volumes ≥ 0.
* **for the built-in families** whose parameters are complete (an :class:`Envelope`):
  rest pose ``d0 = (0, 0, length)``, ``R0 = I``; the number of cavities; mass = density ×
  solid volume within [0.5, 1.2] (a coarse mesh loses volume at curved walls); the centre
  of mass inside the enclosing cylinder; cavity volumes within [0.5, 1.5] × exact; and the
  six diagonal compliances between bounds derived from the material and geometry:

  - **lower bounds** (the segment cannot be stiffer than the solid cylinder of its outer
    radius with rigid end faces, and no stiffer than any admissible displacement field makes
    it: linear interpolation of the end-frame motion, and the Euler–Bernoulli field, with the
    constrained modulus λ + 2μ, which already covers rigid faces that stop the Poisson
    contraction): axial ``L / (M A)``, torsion ``L / (G J)``, lateral
    ``max(L / (G A), L³ / (12 M I))``, bending ``max(1 / (M I / L + G A L / 3), L / (4 M I))``.
    Finite elements are stiffer than the continuum (first-order tetrahedra lock for ν → 0.5),
    so an entry must only be above ``lower / 100``.
  - **upper bounds** (complementary energy: any stress field in equilibrium with the load
    bounds the compliance from above; the Saint-Venant fields of a *core* — a prismatic
    annulus that lies inside the solid over the whole length, away from every cavity —
    are such fields): axial ``L / (E A_c)``, torsion ``L / (G J_c)``, bending ``L / (E I_c)``,
    lateral ``L³ / (3 E I_c) + L / (κ G A_c)`` (κ: Cowper's shear coefficient of the annulus).
    Finite elements are more compliant than the continuum only through the polygonal
    approximation of curved walls, so an entry must be below ``10 × upper``. A corrugated
    bellows whose wall holds no straight annulus gets its torsion bound from a stress
    function across its wall (rigorous) and its axial, bending and lateral bounds from
    thin-walled curved-beam theory (an estimate, hence the same factor 10).

The bounds catch entries that are wrong by large factors (crafted, mis-scaled, another
family's numbers); accidental corruption is the checksum's job, and discretisation error
is the accuracy estimate's. ``benchmarks/bench_accuracy.py`` records where designed entries
sit between their bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vertebra.core.energy import EnergyFit, EnergyModel, linear_terms

#: factor below the stiffness-side bound an entry may be (locking first-order elements)
LOWER_FACTOR = 100.0
#: factor above the compliance-side bound an entry may be (polygonal walls, estimates)
UPPER_FACTOR = 10.0
#: any diagonal compliance outside this range (SI units) is outside any physical segment
MAGNITUDE = (1e-60, 1e60)
MASS_RATIO = (0.5, 1.2)
CAVITY_RATIO = (0.5, 1.5)
POSE_TOLERANCE = 1e-9
LABELS = ("x", "y", "z", "θx", "θy", "θz")


@dataclass(frozen=True)
class Envelope:
    """What a known family's parameters imply about its segment (SI units)."""

    length: float
    outer_radius: float                 # the solid lies in r ≤ outer_radius, 0 ≤ z ≤ length
    solid_volume: float
    cavity_volumes: tuple[float, ...]   # exact rest volumes of the cavities
    density: float
    lower: np.ndarray                   # (6,) diagonal compliance bounds, before LOWER_FACTOR
    upper: np.ndarray | None            # (6,) before UPPER_FACTOR; None if no bound is known
    upper_method: str = "core"


ENVELOPES: dict[str, Callable[[dict], Envelope]] = {}


def register_envelope(family: str):
    """Decorator: ``fn(parameters) -> Envelope`` for entries of ``family``."""
    def add(fn):
        ENVELOPES[family] = fn
        return fn
    return add


class _Incomplete(Exception):
    """The parameters do not name every quantity the family's bounds need."""


def _number(p: dict, name: str, default=None) -> float:
    value = p.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _Incomplete(name)
    return float(value)


def _moduli(p: dict) -> tuple[float, float, float, float, float]:
    E, nu, rho = _number(p, "youngs_modulus"), _number(p, "poisson_ratio"), _number(p, "density", 0.0)
    if not (E > 0 and -1.0 < nu < 0.5 and rho >= 0):
        raise ValueError(f"material youngs_modulus={E}, poisson_ratio={nu}, density={rho} is impossible")
    G = E / (2 * (1 + nu))
    M = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))     # constrained (P-wave) modulus λ + 2μ
    return E, nu, rho, G, M


def cylinder_lower_bounds(length: float, radius: float, p: dict) -> np.ndarray:
    """Diagonal compliances no segment inside the cylinder (radius, length) can be below."""
    _, _, _, G, M = _moduli(p)
    L, R = length, radius
    A, I, J = math.pi * R ** 2, math.pi * R ** 4 / 4, math.pi * R ** 4 / 2
    lateral = max(L / (G * A), L ** 3 / (12 * M * I))
    bending = max(1.0 / (M * I / L + G * A * L / 3), L / (4 * M * I))
    return np.array([lateral, lateral, L / (M * A), bending, bending, L / (G * J)])


def core_upper_bounds(length: float, inner: float, outer: float, p: dict) -> np.ndarray:
    """Diagonal compliances of the Saint-Venant fields of the core annulus (inner, outer)."""
    E, nu, _, G, _ = _moduli(p)
    L = length
    A = math.pi * (outer ** 2 - inner ** 2)
    I = math.pi * (outer ** 4 - inner ** 4) / 4
    m2 = (inner / outer) ** 2
    kappa = 6 * (1 + nu) * (1 + m2) ** 2 / ((7 + 6 * nu) * (1 + m2) ** 2 + (20 + 12 * nu) * m2)
    lateral = L ** 3 / (3 * E * I) + L / (kappa * G * A)
    return np.array([lateral, lateral, L / (E * A), L / (E * I), L / (E * I), L / (G * 2 * I)])


def _best_core(length: float, cores, p: dict) -> np.ndarray | None:
    bounds = [core_upper_bounds(length, a, b, p) for a, b in cores if b > a >= 0 and b > 0]
    return np.min(bounds, axis=0) if bounds else None


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


# ---------------------------------------------------------------- built-in families

@register_envelope("rod")
def _rod(p):
    R, L = _number(p, "radius"), _number(p, "length")
    _require(R > 0 and L > 0, f"radius={R}, length={L} must be > 0")
    rho = _moduli(p)[2]
    return Envelope(L, R, math.pi * R * R * L, (), rho, cylinder_lower_bounds(L, R, p),
                    _best_core(L, [(0.0, R)], p))


@register_envelope("tube")
def _tube(p):
    Ro, Ri, L = _number(p, "outer_radius"), _number(p, "inner_radius"), _number(p, "length")
    _require(Ro > Ri > 0 and L > 0, f"outer_radius={Ro} > inner_radius={Ri} > 0, length={L} > 0 violated")
    rho = _moduli(p)[2]
    return Envelope(L, Ro, math.pi * (Ro * Ro - Ri * Ri) * L, (), rho, cylinder_lower_bounds(L, Ro, p),
                    _best_core(L, [(Ri, Ro)], p))


@register_envelope("bellows")
def _bellows(p):
    Ri, Ro, t, L = (_number(p, k) for k in ("inner_radius", "outer_radius", "wall_thickness", "length"))
    N = _number(p, "convolutions", 2)
    _require(Ri > 0 and t > 0 and L > 0 and N >= 1 and Ro - Ri - t >= 0,
             f"inner_radius={Ri}, outer_radius={Ro}, wall_thickness={t}, convolutions={N}, length={L} "
             "describe no bellows")
    E, _, rho, G, _ = _moduli(p)
    A = 0.5 * (Ro - Ri - t)                     # corrugation amplitude of the mid-wall radius
    mean = 0.5 * (Ro + Ri)
    z = np.linspace(0.0, L, 2001)
    r_mid = mean - A * np.cos(2 * math.pi * N * z / L)
    slope = A * 2 * math.pi * N / L * np.sin(2 * math.pi * N * z / L)
    cavity = float(np.trapezoid(math.pi * (r_mid - t / 2) ** 2, z))
    r_in = r_mid - t / 2
    # torsion: stress function ψ = T/(2π) (r - r_in(z)) / t across the wall (rigorous)
    torsion = float(np.trapezoid((1 + slope ** 2) * (0.5 / r_in ** 2 - 0.5 / (r_in + t) ** 2), z)) \
        / (2 * math.pi * G * t ** 2)
    core = _best_core(L, [(mean + A - t / 2, mean - A + t / 2)], p) if t > 2 * A else None
    if core is not None:
        upper, method = core, "core"
    else:
        # thin-walled curved beam: each radian of wall carries F/(2π) with the bending moment
        # of its offset from the line of action, r̄ chosen to minimise the energy
        ds = np.sqrt(1 + slope ** 2)
        t_n = t / ds
        w = 12.0 / (E * t_n ** 3 * r_mid) * ds
        r_bar = float(np.trapezoid(w * r_mid, z) / np.trapezoid(w, z))
        axial = float(np.trapezoid((12 * (r_mid - r_bar) ** 2 / (E * t_n ** 3) + 1 / (E * t_n)) / r_mid * ds, z)) \
            / (2 * math.pi)
        bending = 2 * axial / mean ** 2
        shear = float(np.trapezoid(ds / t_n, z)) / (math.pi * G * mean)
        lateral = bending * L ** 2 / 3 + shear
        upper, method = np.array([lateral, lateral, axial, bending, bending, torsion]), "thin-walled estimate"
    upper = upper.copy()
    upper[5] = min(upper[5], torsion)
    return Envelope(L, Ro, math.pi * t * L * (Ro + Ri), (cavity,), rho, cylinder_lower_bounds(L, Ro, p),
                    upper, method)


def _chambered(p, bottom, top):
    """Pneumatic segments: bottom/top = (outer_radius, chamber_radius, chamber_offset)."""
    L, n, ri = _number(p, "length"), int(_number(p, "chambers", 3)), _number(p, "inner_radius", 0.0)
    (R0, r0, d0), (R1, r1, d1) = bottom, top
    _require(L > 0 and n >= 1 and ri >= 0 and min(R0, R1, r0, r1) > 0 and min(d0, d1) >= 0
             and R0 - d0 - r0 > 0 and R1 - d1 - r1 > 0,
             "outer radius, chamber radius and chamber offset describe no chambered segment")
    rho = _moduli(p)[2]
    frustum = (lambda a, b: math.pi * L * (a * a + a * b + b * b) / 3)
    chamber = frustum(r0, r1)
    solid = frustum(R0, R1) - n * chamber - math.pi * ri * ri * L
    _require(solid > 0, "chambers and bore leave no solid")
    cores = [(max(d0 + r0, d1 + r1), min(R0, R1)), (ri, min(d0 - r0, d1 - r1))]
    return Envelope(L, max(R0, R1), solid, (chamber,) * n, rho, cylinder_lower_bounds(L, max(R0, R1), p),
                    _best_core(L, cores, p))


@register_envelope("pneumatic")
def _pneumatic(p):
    section = tuple(_number(p, k) for k in ("outer_radius", "chamber_radius", "chamber_offset"))
    return _chambered(p, section, section)


@register_envelope("tapered_pneumatic")
def _tapered(p):
    bottom = tuple(_number(p, f"bottom_{k}") for k in ("outer_radius", "chamber_radius", "chamber_offset"))
    top = tuple(_number(p, f"top_{k}") for k in ("outer_radius", "chamber_radius", "chamber_offset"))
    return _chambered(p, bottom, top)


# ---------------------------------------------------------------- checks

def envelope(family: str, parameters: dict) -> Envelope | None:
    """The family's envelope, None when the family is unknown or its parameters incomplete.
    Raises ValueError when complete parameters describe an impossible segment."""
    fn = ENVELOPES.get(family)
    if fn is None or not isinstance(parameters, dict):
        return None
    try:
        return fn(parameters)
    except _Incomplete:
        return None
    except (ZeroDivisionError, OverflowError) as error:
        raise ValueError(f"parameters give no finite bounds ({error})") from None


def _generic(entry) -> list[str]:
    problems = []
    c = entry.compliance
    arrays = {"compliance": c, "cavity_volumes": entry.cavity_volumes, "center_of_mass": entry.center_of_mass,
              "rest_translation": entry.rest_translation, "rest_quaternion": entry.rest_quaternion}
    for name, arr in arrays.items():
        if not np.all(np.isfinite(arr)):
            problems.append(f"{name} is not finite")
    if problems:
        return problems
    if not (math.isfinite(entry.mass) and entry.mass >= 0):
        problems.append(f"mass {entry.mass} is not a finite non-negative number")
    diag = np.diag(c)
    lo, hi = MAGNITUDE
    if np.any(diag < lo) or np.any(diag > hi):
        problems.append(f"compliance diagonal {diag.min():.3g} … {diag.max():.3g} outside [{lo:g}, {hi:g}]")
        return problems
    d = 1.0 / np.sqrt(diag)
    scaled = c * np.outer(d, d)                      # unit diagonal: scale-free tests
    if np.max(np.abs(scaled - scaled.T)) > 1e-8:
        problems.append("compliance is not symmetric")
    try:
        np.linalg.cholesky(0.5 * (scaled + scaled.T))
    except np.linalg.LinAlgError:
        problems.append(f"compliance ({c.shape[0]}×{c.shape[0]}) is not positive definite")
    if np.any(entry.cavity_volumes < 0):
        problems.append("a cavity rest volume is negative")
    return problems


def _against(entry, env: Envelope) -> list[str]:
    problems = []
    L = env.length
    if np.max(np.abs(entry.rest_translation - [0.0, 0.0, L])) > POSE_TOLERANCE * L \
            or np.max(np.abs(entry.rest_quaternion - [1.0, 0, 0, 0])) > POSE_TOLERANCE:
        problems.append(f"rest pose d0={entry.rest_translation.tolist()}, R0={entry.rest_quaternion.tolist()} "
                        f"is not the straight segment of length {L:g} its parameters describe")
    if entry.n_cavities != len(env.cavity_volumes):
        problems.append(f"{entry.n_cavities} cavities, its parameters describe {len(env.cavity_volumes)}")
        return problems
    expected_mass = env.density * env.solid_volume
    lo, hi = MASS_RATIO
    if expected_mass == 0:
        if entry.mass != 0:
            problems.append(f"mass {entry.mass:.6g} kg but density 0")
    elif not lo * expected_mass <= entry.mass <= hi * expected_mass:
        problems.append(f"mass {entry.mass:.6g} kg outside [{lo}, {hi}] × density × solid volume = "
                        f"{expected_mass:.6g} kg")
    if entry.mass > 0:
        com = entry.center_of_mass
        if math.hypot(com[0], com[1]) > 1.01 * env.outer_radius or not -0.01 * L <= com[2] <= 1.01 * L:
            problems.append(f"centre of mass {com.tolist()} outside the segment's cylinder "
                            f"(radius {env.outer_radius:g}, length {L:g})")
    lo, hi = CAVITY_RATIO
    for k, (stored, exact) in enumerate(zip(entry.cavity_volumes, env.cavity_volumes)):
        if not lo * exact <= stored <= hi * exact:
            problems.append(f"cavity {k} rest volume {stored:.6g} m^3 outside [{lo}, {hi}] × {exact:.6g}")
    diag = np.diag(entry.compliance)[:6]
    for i, label in enumerate(LABELS):
        floor = env.lower[i] / LOWER_FACTOR
        if diag[i] < floor:
            problems.append(f"compliance {label}{label} = {diag[i]:.4g} below {floor:.4g} (1/{LOWER_FACTOR:g} "
                            "of the stiffest the material and outer radius allow)")
        if env.upper is not None:
            ceiling = env.upper[i] * UPPER_FACTOR
            if diag[i] > ceiling:
                problems.append(f"compliance {label}{label} = {diag[i]:.4g} above {ceiling:.4g} "
                                f"({UPPER_FACTOR:g} × the {env.upper_method} bound of its geometry)")
    return problems


# ---------------------------------------------------------------- the fitted energy (schema v2)

#: highest total degree of a fitted ψ (the designer's sampling settings allow at most 10)
MAX_DEGREE = 10
#: each variable's scale within this factor of the range's extent in its group (the designer
#: takes the sampled extent itself)
SCALE_RATIO = 1e-2
#: the strain range: translations within this many lengths of rest, rotations within 4π (a
#: sampled rotation vector stays within π; hand-made fits get room)
MAX_TRANSLATION_LENGTHS = 2.0
MAX_ROTATION = 4 * math.pi
#: the load range within this factor of the linear load of the strain range's extents
LOAD_RATIO = 1e3
#: the pressure range within this factor of the pressure scales
PRESSURE_RATIO = 1e3
#: strains sampled in the range for the convexity and stiffness tests (seeded: the same points
#: on every read), and how far the tangent stiffness may exceed the linear one there
CONVEXITY_SAMPLES = 48
MAX_STIFFENING = 1e6
#: a fit records the least relative eigenvalue of its Hessian over its samples
#: (``fit_error["convexity_min_relative_eigenvalue"]``); the sampled strains, which reach the
#: corners of the range, may be below it by this slack (recorded ≥ 0), or below this factor
#: times it minus the slack (recorded < 0)
CONVEXITY_SLACK = 0.5
CONVEXITY_FACTOR = 4.0
CONVEXITY_SEED = 20240601


def _range_samples(fit, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(strains (n, 6), pressures (n, m)) inside the range's strain box and pressure bounds,
    rest first; seeded."""
    rng = np.random.default_rng(CONVEXITY_SEED)
    r = fit.range
    lo, hi = r.pose_lower, r.pose_upper
    t = rng.uniform(size=(n, 4))
    t[0] = 0.0
    radial = lambda k: np.maximum(lo[k], 0.0) + t[:, k] * (hi[k] - np.maximum(lo[k], 0.0))
    signed = lambda k: np.clip(0.0, lo[k], hi[k]) + t[:, k] * (np.where(rng.uniform(size=n) < 0.5, lo[k], hi[k])
                                                                - np.clip(0.0, lo[k], hi[k]))
    angle = rng.uniform(0, 2 * math.pi, size=(n, 2))
    s = np.zeros((n, 6))
    s[:, 0], s[:, 1] = radial(0) * np.cos(angle[:, 0]), radial(0) * np.sin(angle[:, 0])
    s[:, 2] = signed(1)
    s[:, 3], s[:, 4] = radial(2) * np.cos(angle[:, 1]), radial(2) * np.sin(angle[:, 1])
    s[:, 5] = signed(3)
    s[0] = 0.0
    m = fit.n_cavities
    p = r.pressure_lower + rng.uniform(size=(n, m)) * (r.pressure_upper - r.pressure_lower)
    p[0] = np.clip(0.0, r.pressure_lower, r.pressure_upper)
    return s, p


def _stored_convexity(fit) -> float | None:
    value = fit.fit_error.get("convexity_min_relative_eigenvalue") if isinstance(fit.fit_error, dict) else None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) else None


def energy_problems(entry) -> list[str]:
    """Why an entry's fitted energy ψ (or its absence) is not sound ([] = sound): the checks a
    reader can afford on every read.

    * metadata: an entry whose provenance records a nonlinear design carries its energy; the
      fit's degree ≤ :data:`MAX_DEGREE` and ≤ its stored sampling degree, no monomial twice;
    * scales: each within :data:`SCALE_RATIO` (either way) of the range's extent in its group;
    * range: contains rest (``EnergyFit.check``, with the Hessian at rest equal to the
      linear one); translations within :data:`MAX_TRANSLATION_LENGTHS` lengths, rotations within
      4π; loads within :data:`LOAD_RATIO` × the linear load of the strain extents; pressures
      within :data:`PRESSURE_RATIO` × their scales;
    * convexity: at :data:`CONVEXITY_SAMPLES` seeded strains and pressures inside the range, the
      strain Hessian of ψ is finite, its relative eigenvalues (of ``K^-1/2 H K^-1/2``) within
      ±:data:`MAX_STIFFENING`, and not below what the fit records as its least one (a designed
      fit records it; see :data:`CONVEXITY_SLACK`): a convex fit stays convex.
    """
    fit = entry.energy
    if not isinstance(fit, EnergyFit) or fit.n_cavities != entry.n_cavities \
            or np.any(entry.rest_quaternion != [1.0, 0.0, 0.0, 0.0]):
        return []                                  # none, or SegmentEntry refuses it
    problems = []
    exponents = fit.exponents
    degree = fit.degree
    if degree > MAX_DEGREE:
        problems.append(f"energy: degree {degree} above {MAX_DEGREE}")
    settings = fit.sampling.get("settings") if isinstance(fit.sampling, dict) else None
    stated = settings.get("degree") if isinstance(settings, dict) else None
    if isinstance(stated, int) and not isinstance(stated, bool) and degree > stated:
        problems.append(f"energy: degree {degree} above the degree {stated} its sampling settings state")
    if np.unique(exponents, axis=0).shape[0] != exponents.shape[0]:
        problems.append("energy: a monomial appears more than once")
    if problems:
        return problems
    length = float(np.linalg.norm(entry.rest_translation))
    r = fit.range
    extent = np.maximum(np.abs(r.pose_lower), np.abs(r.pose_upper))
    group_of = (0, 0, 1, 2, 2, 3)
    strain_extent = extent[list(group_of)]
    ratio = fit.scales[:6] / strain_extent
    if np.any(ratio < SCALE_RATIO) or np.any(ratio > 1 / SCALE_RATIO):
        problems.append(f"energy: strain scales {np.array2string(fit.scales[:6], precision=3)} are not within "
                        f"{1 / SCALE_RATIO:g}× of the range's extents {np.array2string(strain_extent, precision=3)}")
    if length > 0 and (extent[0] > MAX_TRANSLATION_LENGTHS * length or extent[1] > MAX_TRANSLATION_LENGTHS * length):
        problems.append(f"energy: the strain range reaches translations {extent[0]:.3g}, {extent[1]:.3g} m, "
                        f"beyond {MAX_TRANSLATION_LENGTHS:g} × the length {length:.3g} m")
    if extent[2] > MAX_ROTATION or extent[3] > MAX_ROTATION:
        problems.append(f"energy: the strain range reaches rotations {extent[2]:.3g}, {extent[3]:.3g} rad, beyond 4π")
    m = fit.n_cavities
    pressure_extent = np.maximum(np.abs(r.pressure_lower), np.abs(r.pressure_upper))
    if m and np.any(pressure_extent > PRESSURE_RATIO * fit.scales[6:]):
        problems.append(f"energy: the pressure range {pressure_extent.tolist()} Pa exceeds {PRESSURE_RATIO:g} × "
                        f"its scales {fit.scales[6:].tolist()}")
    try:
        K = linear_terms(entry.compliance, entry.rest_translation).stiffness
    except Exception as error:                       # noqa: BLE001 - any failure is a problem to report
        return problems + [str(error)]
    linear_load = np.abs(K) @ strain_extent
    load_reach = np.array([math.hypot(linear_load[0], linear_load[1]), linear_load[2],
                           math.hypot(linear_load[3], linear_load[4]), linear_load[5]])
    load_extent = np.maximum(np.abs(r.load_lower), np.abs(r.load_upper))
    if np.any(load_extent > LOAD_RATIO * load_reach):
        problems.append(f"energy: the load range {np.array2string(load_extent, precision=3)} exceeds "
                        f"{LOAD_RATIO:g} × the linear loads {np.array2string(load_reach, precision=3)} of its "
                        "strain range")
    if problems:
        return problems
    try:
        problems.extend(fit.check(entry.compliance, entry.rest_translation))
        if problems:
            return problems
        model = EnergyModel.of_entry(entry)
        s, p = _range_samples(fit, CONVEXITY_SAMPLES)
        with np.errstate(all="ignore"):
            hessian = model.evaluate(s, p).hessian
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as error:
        return [f"energy: cannot be evaluated in its range ({error})"]
    if not np.all(np.isfinite(hessian)):
        return ["energy: its Hessian is not finite inside its range"]
    w, U = np.linalg.eigh(K)
    root = U @ np.diag(1.0 / np.sqrt(w)) @ U.T            # K^-1/2
    relative = np.linalg.eigvalsh(root @ (0.5 * (hessian + hessian.transpose(0, 2, 1))) @ root)
    low, high = float(relative.min()), float(relative.max())
    stored = _stored_convexity(fit)
    floor = None if stored is None else (-CONVEXITY_SLACK if stored >= 0 else CONVEXITY_FACTOR * stored
                                        - CONVEXITY_SLACK)
    where = np.array2string(s[int(np.argmin(relative.min(1)))], precision=3)
    if floor is not None and low < floor:
        problems.append(f"energy: its fit records a least relative eigenvalue of {stored:.3g} but it is {low:.3g} "
                        f"at strain {where} inside its range")
    if low < -MAX_STIFFENING:
        problems.append(f"energy: relative eigenvalue {low:.3g} at strain {where} inside its range "
                        f"(at least {-MAX_STIFFENING:g})")
    if high > MAX_STIFFENING:
        problems.append(f"energy: its tangent stiffness reaches {high:.3g} × the linear one inside its range "
                        f"(at most {MAX_STIFFENING:g})")
    return problems


def stored_problems(entry) -> list[str]:
    """Problems of an entry read from a file that its metadata show: a stored entry whose
    provenance records a nonlinear design (``provenance["nonlinear"]``) carries its energy (an
    entry made in memory may drop it to compare with the linear response)."""
    provenance = entry.provenance if isinstance(entry.provenance, dict) else {}
    if entry.energy is None and "nonlinear" in provenance:
        return ["its provenance records a nonlinear design but it has no energy group"]
    return []


def soundness_problems(entry) -> list[str]:
    """Why ``entry`` is not physically sound ([] = sound): its compliance and masses
    (:func:`_generic`, the family's envelope) and its fitted energy (:func:`energy_problems`).
    Never raises."""
    problems = _generic(entry)
    if problems:
        return problems
    try:
        env = envelope(entry.family, entry.parameters)
    except ValueError as error:
        return [f"parameters impossible for family {entry.family!r}: {error}"]
    problems = _against(entry, env) if env is not None else []
    return problems or energy_problems(entry)


def bound_ratios(entry) -> dict | None:
    """Where an entry's diagonal compliances sit: ``{"lower": C_ii / lower_i, "upper": C_ii /
    upper_i}`` (must stay above 1/LOWER_FACTOR and below UPPER_FACTOR), None without envelope."""
    env = envelope(entry.family, entry.parameters)
    if env is None:
        return None
    diag = np.diag(entry.compliance)[:6]
    return {"lower": (diag / env.lower).tolist(),
            "upper": (diag / env.upper).tolist() if env.upper is not None else None,
            "upper_method": env.upper_method}
