"""Where a scene takes its segments: the strain, load and pressure ranges a fitted entry must cover.

A nonlinear entry stores its energy ψ(ξ, p) fitted over a sampled range of strains and
pressures (catalogue schema v2); a scene that leaves that range extrapolates the fit. Before
such entries are designed for a scene, this module estimates, for every segment, what the scene
asks of it (:func:`estimate_ranges`), and turns that into the sampling settings of the
segment's entry (:func:`choose_sampling`):

* **pressures** — exactly, from the scene: for each cavity of the segment, the bounds
  ``[min_pressure, max_pressure]`` of the chambers that act on it (``inf`` when a chamber has
  no upper bound: the fit then samples up to the inflation limit);
* **strains and loads** — by solving the scene with the *linear* entries of its segments (the
  same designs with ``material = "linear"``, cheap to design and exact at small strain) at
  every corner of its actuation box (each actuator at its lower or upper bound; an actuator
  without a finite upper bound at its forward value), at its forward actuation, always under
  its loads and gravity; then taking, per segment, the extremes over those equilibria and over
  the segment's links of the strain ``s = ξ − ξ₀`` and of the load ``w = ∂ψ/∂ξ`` in the group
  coordinates of the fitted entries (lateral ``|s_xy|``, axial ``s_z``, bending ``|φ_xy|``,
  twist ``φ_z``), and enlarging them about zero by :data:`ENLARGE`.

Why corners: with a linear response, every such coordinate is a linear function of the
actuation, whose extremes over a box are at corners; the chain of linear entries is
geometrically nonlinear, so the corners are an estimate, and the enlargement covers what lies
between. The loads ``w`` are fixed by statics (the wrench the distal part of the trunk puts on
the segment), so the linear entries estimate them well (measured: linear entries put the tips of
trunks of squat soft segments within 0.1–3 % of length of a full nonlinear FE model up to ~90°
under loads). Pressure-driven strains are underestimated by linear entries (bending 24–64 %
too small at 0.5–1.4 bar for CBHA-like slices): the fit's pressure paths, which run to the
scene's pressure bounds and add the free pose the pressures alone produce to the pose caps,
sample those.

From a range to sampling settings (:func:`choose_sampling`). The sampled box of a fitted entry
is set by the angle caps ``bending`` and ``twist``, the outer-fibre ``strain`` that also bounds
them (``· L/r``), the ``shear`` and ``axial`` fractions of the length and the top ``pressure``
(:func:`vertebra.designer.energy_sampling.load_box`): its loads are the linear loads of those
caps. Each setting is therefore raised to what both the estimated strain and the estimated
load need through the segment's linear compliance (a load ``w`` needs a cap ``w · c``), with the
couplings of the box (the lateral force bound is at most ``2 M / L`` of the bending moment, the
axial one at most the lateral one); then rounded up onto a coarse grid (:data:`ANGLE_STEP` for
angles, two significant digits for the other settings and the pressure) so that small scene
edits keep the same settings and key; and never set below the default settings (a scene inside
them keeps the plain entry's key). The pressure is the exception: the scene bounds it exactly,
so the fit samples up to the chambers' largest ``max_pressure`` (rounded up) instead of up to
the inflation limit — its pressure paths then resolve the range the scene uses. Settings the
scene gives itself (``sampling = {…}`` on the segment) win over the estimate.

With more than :data:`MAX_CORNERS` corners (``2^n`` for ``n`` free actuators), the corners
solved are all-lower, all-upper, each actuator alone at its upper bound, each alone at its
lower bound, and seeded random corners up to the limit.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vertebra.core.energy import linear_terms
from vertebra.core.errors import ConvergenceError
from vertebra.designer.energy_sampling import SOFTENING_STRAIN, SamplingSettings

#: factor by which the strain and load extremes are enlarged about zero (covers the response
#: between corners and the constitutive difference of nonlinear entries under loads)
ENLARGE = 1.25
#: largest number of actuation corners solved (beyond it, a deterministic subset)
MAX_CORNERS = 64
#: the group coordinates of strains and loads, as fitted entries bound them
GROUPS = ("lateral", "axial", "bending", "twist")
_RADIAL = (0, 2)                      # groups that are norms (lower bound 0)


def group_coordinates(v: np.ndarray) -> np.ndarray:
    """(…, 4) ``[|v_xy|, v_z, |v_θxy|, v_θz]`` of (…, 6) strains or loads ``[translation; rotation]``."""
    return np.stack([np.hypot(v[..., 0], v[..., 1]), v[..., 2], np.hypot(v[..., 3], v[..., 4]), v[..., 5]], axis=-1)


@dataclass(frozen=True)
class SegmentRange:
    """What a scene asks of one segment: bounds of the group coordinates (:data:`GROUPS`) of
    its links' strain ``s = ξ − ξ₀`` and load ``w = ∂ψ/∂ξ`` (each range contains zero, the
    rest state), and per cavity the pressure bounds ``{cavity: (lower, upper)}`` of the
    chambers acting on it (cavities no chamber uses are absent: their pressure stays 0)."""

    segment: int
    strain_lower: np.ndarray          # (4,)
    strain_upper: np.ndarray          # (4,)
    load_lower: np.ndarray            # (4,)
    load_upper: np.ndarray            # (4,)
    pressures: dict

    def to_json(self) -> dict:
        return {"segment": self.segment, "groups": list(GROUPS),
                "strain": [self.strain_lower.tolist(), self.strain_upper.tolist()],
                "load": [self.load_lower.tolist(), self.load_upper.tolist()],
                "pressures": {str(c): list(bounds) for c, bounds in sorted(self.pressures.items())}}


@dataclass(frozen=True)
class RangeEstimate:
    """Per-segment ranges of a scene and how they were estimated."""

    segments: tuple                   # SegmentRange, one per scene segment
    actuations: np.ndarray            # (k, n_actuators) the actuations solved
    failed: tuple                     # indices into ``actuations`` with no equilibrium (left out)
    enlarge: float
    seconds: float = 0.0              # the forward solves

    def to_json(self) -> dict:
        return {"enlarge": self.enlarge, "actuations": len(self.actuations), "failed": list(self.failed),
                "solve_s": self.seconds, "segments": [s.to_json() for s in self.segments]}


def actuation_corners(lower: np.ndarray, upper: np.ndarray, *, max_corners: int = MAX_CORNERS,
                      seed: int = 0) -> np.ndarray:
    """Corners of the box ``[lower, upper]`` (k, n): all of them when there are at most
    ``max_corners``, else all-lower, all-upper, each free actuator alone at its upper bound and
    alone at its lower bound, then seeded random corners up to ``max_corners`` (or fewer when
    those alone exceed it). Actuators with ``lower == upper`` are fixed."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    free = np.flatnonzero(upper > lower)
    if 2 ** free.size <= max_corners:
        picks = np.array(list(itertools.product((False, True), repeat=free.size)), dtype=bool).reshape(2 ** free.size, free.size)
    else:
        eye = np.eye(free.size, dtype=bool)
        picks = np.vstack([np.zeros((1, free.size), bool), np.ones((1, free.size), bool), eye, ~eye])
        rng = np.random.default_rng(seed)
        seen = {row.tobytes() for row in picks}
        extra = []
        for _ in range(100 * max_corners):          # bounded: the box has far more corners than needed
            if len(seen) >= max_corners:
                break
            row = rng.random(free.size) < 0.5
            if row.tobytes() not in seen:
                seen.add(row.tobytes())
                extra.append(row)
        if extra:
            picks = np.vstack([picks, np.array(extra)])
    corners = np.broadcast_to(lower, (picks.shape[0], lower.size)).copy()
    corners[:, free] = np.where(picks, upper[free], lower[free])
    return corners


def actuation_box(model) -> tuple[np.ndarray, np.ndarray]:
    """The box the corners span: the actuator bounds (scene lower bounds are finite), an
    unbounded upper bound replaced by the forward value (the scene names no larger value)."""
    lower, upper = (np.asarray(b, float) for b in model.actuator_bounds)
    return lower, np.where(np.isfinite(upper), upper, np.maximum(model.default_actuation, lower))


def _segment_of_link(scene) -> np.ndarray:
    return np.repeat(np.arange(len(scene.segments)), [s.count * s.elements for s in scene.segments])


def _pressures(scene) -> list[dict]:
    """Per segment, ``{cavity: (lower, upper)}`` over the chambers acting on it."""
    out = [dict() for _ in scene.segments]
    first = 1
    for i, segment in enumerate(scene.segments):
        last = first + segment.count - 1              # the vertebrae the segment's repetitions end at
        for chamber in scene.chambers:
            if chamber.first <= last and chamber.last >= first:
                low, high = out[i].get(chamber.cavity, (np.inf, -np.inf))
                out[i][chamber.cavity] = (min(low, chamber.min_pressure), max(high, chamber.max_pressure))
        first = last + 1
    return out


def _enlarged(lower: np.ndarray, upper: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.minimum(lower, 0.0) * factor, np.maximum(upper, 0.0) * factor
    lower[list(_RADIAL)] = 0.0
    return lower, upper


def estimate_ranges(model, *, enlarge: float = ENLARGE, max_corners: int = MAX_CORNERS, seed: int = 0,
                    progress: Callable[[int, int, float], None] | None = None) -> RangeEstimate:
    """The strain, load and pressure ranges a scene asks of each of its segments (module
    docstring), from its model ``model`` (a :class:`~vertebra.solver.TrunkModel`, built with
    linear entries for its design segments). Actuations without an equilibrium are left out
    and listed in ``failed``; if none has one, ConvergenceError. ``progress(done, total,
    seconds)`` is called after each actuation."""
    if not enlarge >= 1.0:
        raise ValueError(f"enlarge must be >= 1, got {enlarge!r}")
    scene = model.scene
    lower, upper = actuation_box(model)
    actuations = np.vstack([model.default_actuation[None, :],
                            actuation_corners(lower, upper, max_corners=max_corners, seed=seed)])
    strains, loads, failed = [], [], []
    start = time.perf_counter()
    for k, actuation in enumerate(actuations):
        try:
            result = model.solve(actuation)
        except ConvergenceError:
            failed.append(k)
        else:
            evaluation = model.evaluate(result.state, actuation)
            strains.append(group_coordinates(evaluation.links.xi - model.link_rest))
            loads.append(group_coordinates(evaluation.w))
        if progress is not None:
            progress(k + 1, len(actuations), time.perf_counter() - start)
    if not strains:
        raise ConvergenceError(f"no equilibrium at any of the {len(actuations)} actuations of {scene.source}")
    strains, loads = np.stack(strains), np.stack(loads)          # (solved, n_links, 4)
    of = _segment_of_link(scene)
    pressures = _pressures(scene)
    segments = []
    for i in range(len(scene.segments)):
        s, w = strains[:, of == i], loads[:, of == i]
        s_low, s_high = _enlarged(s.min(axis=(0, 1)), s.max(axis=(0, 1)), enlarge)
        w_low, w_high = _enlarged(w.min(axis=(0, 1)), w.max(axis=(0, 1)), enlarge)
        segments.append(SegmentRange(i, s_low, s_high, w_low, w_high, pressures[i]))
    return RangeEstimate(tuple(segments), actuations, tuple(failed), float(enlarge),
                         time.perf_counter() - start)


def union(ranges) -> SegmentRange:
    """The smallest range containing every one of ``ranges`` (segments that share one entry);
    it is reported under the first one's segment."""
    ranges = list(ranges)
    pressures: dict = {}
    for r in ranges:
        for cavity, (low, high) in r.pressures.items():
            old = pressures.get(cavity, (np.inf, -np.inf))
            pressures[cavity] = (min(old[0], low), max(old[1], high))
    stack = {name: np.array([getattr(r, name) for r in ranges]) for name in
             ("strain_lower", "strain_upper", "load_lower", "load_upper")}
    return SegmentRange(ranges[0].segment, stack["strain_lower"].min(0), stack["strain_upper"].max(0),
                        stack["load_lower"].min(0), stack["load_upper"].max(0), pressures)


# ------------------------------------------------------------------ from a range to sampling settings

#: angle caps (bending, twist) are rounded up to multiples of this (5°)
ANGLE_STEP = math.radians(5.0)
#: the largest angle cap an entry samples: the rotation log of the strain chart is singular at π
MAX_ANGLE = math.radians(175.0)
#: the largest axial cap (stretch or compression as a fraction of the length; the setting is < 1)
MAX_AXIAL = 0.9
#: the sampling settings a scene's range sets, in the order reported
RANGE_SETTINGS = ("bending", "twist", "strain", "shear", "axial", "pressure")
#: where a setting's value came from
SOURCES = ("scene estimate", "scene chambers", "scene setting", "default")


def round_angle(value: float) -> float:
    """``value`` (rad, ≥ 0) rounded up to a multiple of :data:`ANGLE_STEP`."""
    return ANGLE_STEP * math.ceil(value / ANGLE_STEP - 1e-9)


def round_ratio(value: float) -> float:
    """``value`` (> 0) rounded up to two significant digits (a relative step of 1–10 %)."""
    exponent = math.floor(math.log10(value)) - 1
    digits = math.ceil(value / 10.0 ** exponent - 1e-9)
    return float(f"{digits}e{exponent}")


def describe_setting(name: str, value) -> str:
    """A setting as the prepare report prints it (angles in degrees, pressures in Pa)."""
    if name in ("bending", "twist"):
        return f"{name} {math.degrees(value):.4g}°"
    if name == "pressure":
        return "pressure up to the inflation limit" if value is None else f"pressure {value:.4g} Pa"
    return f"{name} {value:.4g}"


@dataclass(frozen=True)
class SamplingChoice:
    """The sampling settings of a nonlinear entry prepared for a scene, and why.

    ``settings``: the design's ``sampling`` option (the settings that differ from the
    defaults, plus every one the scene gives; part of the content key); ``values``: the value
    of each of :data:`RANGE_SETTINGS`; ``sources``: where it came from (:data:`SOURCES`);
    ``needed``: what the scene's estimated range asks of it before rounding (None: nothing
    asked); ``warnings``: where the entry cannot cover what the scene asks."""

    settings: dict
    values: dict
    sources: dict
    needed: dict
    warnings: tuple = ()
    cavities: int = 0                 # the segment's cavities (none: the pressure setting is moot)
    slenderness: float = math.inf     # length / outer radius: ``strain · L/r`` also caps the angles

    def caps(self) -> dict:
        """The angle caps the sampling applies: ``min(angle, strain · L/r)``."""
        return {name: min(self.values[name], self.values["strain"] * self.slenderness) for name in ("bending", "twist")}

    def describe(self) -> str:
        caps = self.caps()
        parts = []
        for name in RANGE_SETTINGS:
            if name == "pressure" and not self.cavities:
                continue
            text = f"{describe_setting(name, self.values[name])} ({self.sources[name]})"
            if name in caps and caps[name] < self.values[name]:
                text += f" capped at {math.degrees(caps[name]):.3g}° by the strain"
            parts.append(text)
        if self.cavities and self.settings.get("cavities") is not None:
            named = self.settings["cavities"]
            parts.append("pressurised cavities: " + (", ".join(map(str, named)) if named else "none"))
        return ", ".join(parts)

    def to_json(self) -> dict:
        return {"settings": dict(self.settings), "values": dict(self.values), "sources": dict(self.sources),
                "needed": dict(self.needed), "warnings": list(self.warnings)}


def _needed_caps(estimate: SegmentRange, compliance: np.ndarray, length: float) -> dict:
    """The settings the estimated strains and loads need (unrounded), through the linear
    compliance ``compliance`` (the diagonal of the strain chart's, ``[lat, lat, axial, bend,
    bend, twist]``) and the couplings of :func:`~vertebra.designer.energy_sampling.load_box`."""
    s = np.maximum(np.abs(estimate.strain_lower), np.abs(estimate.strain_upper))
    w = np.maximum(np.abs(estimate.load_lower), np.abs(estimate.load_upper))
    axial_force = max(w[1], s[1] / compliance[2])
    lateral_force = max(w[0], s[0] / compliance[0], axial_force)      # the axial bound is ≤ the lateral one
    moment = max(w[2], s[2] / compliance[3], lateral_force * length / 2.0)  # the lateral bound is ≤ 2 M / L
    return {"bending": moment * compliance[3], "twist": max(s[3], w[3] * compliance[5]),
            "shear": lateral_force * compliance[0] / length, "axial": axial_force * compliance[2] / length}


def choose_sampling(estimate: SegmentRange, *, compliance, rest_translation, radius: float, material: str,
                    user: dict | None = None) -> SamplingChoice:
    """The sampling settings of a nonlinear entry of ``material`` whose sampled box covers
    ``estimate`` (module docstring): ``compliance`` and ``rest_translation`` of the segment's
    linear entry, its outer ``radius``; ``user``: the settings the scene gives (they win). The
    outer-fibre strain of a material that softens in compression (St Venant–Kirchhoff) is not
    raised above its default (:data:`~vertebra.designer.energy_sampling.SOFTENING_STRAIN`:
    fits sampled beyond it near the compressive limit point fail); the report warns instead."""
    cavities = np.shape(compliance)[0] - 6
    defaults = SamplingSettings().resolved(cavities, material)
    user = dict(user or {})
    K, _, _ = linear_terms(compliance, rest_translation)
    c = np.diag(np.linalg.inv(K))
    length = float(np.linalg.norm(rest_translation))
    needed = {name: float(value) for name, value in _needed_caps(estimate, c, length).items()}
    warnings = []
    values, sources = {}, {}
    limits = {"bending": MAX_ANGLE, "twist": MAX_ANGLE, "axial": MAX_AXIAL}
    for name in ("bending", "twist", "shear", "axial"):
        want = needed[name]
        if name in limits and want > limits[name]:
            unit = "rad" if name != "axial" else "of the length"
            warnings.append(f"the scene asks for {name} {want:.3g} {unit}, beyond what an entry samples: "
                            f"clamped to {limits[name]:.3g}")
            want = limits[name]
        rounded = round_angle(want) if name in ("bending", "twist") else round_ratio(want) if want > 0 else 0.0
        if name in limits:
            rounded = min(rounded, limits[name])
        default = getattr(defaults, name)
        values[name], sources[name] = (rounded, "scene estimate") if rounded > default else (default, "default")
    # the outer-fibre strain also caps the angles (· L/r): raise it to let the angles reach their caps
    needed["strain"] = max(min(needed["bending"], MAX_ANGLE), min(needed["twist"], MAX_ANGLE)) * radius / length
    rounded = round_ratio(needed["strain"]) if needed["strain"] > 0 else 0.0
    if material in SOFTENING_STRAIN and rounded > SOFTENING_STRAIN[material]:
        warnings.append(f"the scene asks for strain {needed['strain']:.3g} (outer fibre), beyond the "
                        f"{SOFTENING_STRAIN[material]:.3g} a {material} entry is sampled to (it softens in "
                        f"compression towards a limit point): clamped, angles above "
                        f"{math.degrees(SOFTENING_STRAIN[material] * length / radius):.3g}° leave its range")
        rounded = SOFTENING_STRAIN[material]
    values["strain"], sources["strain"] = ((rounded, "scene estimate") if rounded > defaults.strain
                                           else (defaults.strain, "default"))
    values["pressure"], sources["pressure"], needed["pressure"] = _pressure(estimate, warnings)
    for name, value in user.items():
        if name not in RANGE_SETTINGS:
            continue
        asked = needed.get(name)
        if value is not None and asked is not None and value < asked:
            warnings.append(f"the scene's setting sampling.{name} = {value!r} is below what the scene asks "
                            f"({asked:.4g}): states beyond it leave the fitted range")
        values[name], sources[name] = value, "scene setting"
    settings = {name: value for name, value in values.items() if value != getattr(defaults, name)}
    pressurised = _pressurised(estimate, cavities)
    if pressurised is not None:
        settings["cavities"] = pressurised
    settings.update(user)
    SamplingSettings.from_dict(settings)                        # the result must be valid settings
    return SamplingChoice(settings, values, sources, needed, tuple(warnings), cavities=cavities,
                          slenderness=length / radius)


def _pressurised(estimate: SegmentRange, cavities: int) -> list | None:
    """``sampling.cavities`` for the scene: ``[]`` when it pressurises none of the segment's
    cavities (a positive pressure), so the entry skips the inflation-limit search and the
    pressures nothing applies; None (all) when it pressurises any — one ramp serves every
    cavity by symmetry and the paths cost the same, so naming a subset would save nothing and
    only narrow the entry."""
    if not cavities or any(high > 0.0 and c < cavities for c, (_, high) in estimate.pressures.items()):
        return None
    return []


def _pressure(estimate: SegmentRange, warnings: list) -> tuple:
    """``(setting, source, needed)`` of the top pressure from the chambers acting on the
    segment: the largest ``max_pressure`` rounded up; None (up to the inflation limit) when one
    is unbounded or when no chamber acts on the segment."""
    if not estimate.pressures:
        return None, "default", None
    lower = min(low for low, _ in estimate.pressures.values())
    upper = max(high for _, high in estimate.pressures.values())
    if lower < 0.0:
        warnings.append(f"chamber pressures down to {lower:.4g} Pa: entries sample pressures from 0 up only")
    if upper == math.inf:
        return None, "scene chambers", math.inf
    if upper <= 0.0:
        return None, "default", None
    return round_ratio(upper), "scene chambers", upper


def uncovered(estimate: SegmentRange, fitted) -> list[str]:
    """Where the estimated range ``estimate`` leaves an entry's fitted range ``fitted``
    (:class:`~vertebra.core.energy.EnergyRange`), one sentence each (an unbounded pressure
    is covered up to the inflation limit, where the runtime stops)."""
    out = []
    for kind, lower, upper, f_lower, f_upper in (
            ("strain", estimate.strain_lower, estimate.strain_upper, fitted.pose_lower, fitted.pose_upper),
            ("load", estimate.load_lower, estimate.load_upper, fitted.load_lower, fitted.load_upper)):
        for g, group in enumerate(GROUPS):
            if upper[g] > f_upper[g] or lower[g] < f_lower[g]:
                out.append(f"{group} {kind} [{lower[g]:.3g}, {upper[g]:.3g}] estimated, "
                           f"[{f_lower[g]:.3g}, {f_upper[g]:.3g}] fitted")
    for cavity, (low, high) in sorted(estimate.pressures.items()):
        if cavity >= fitted.n_cavities:
            continue
        top = float(fitted.pressure_upper[cavity])
        limit = "" if fitted.limit_pressure is None else f" (inflation limit point {fitted.limit_pressure:.4g} Pa)"
        if math.isfinite(high) and high > top:
            out.append(f"cavity {cavity} pressure up to {high:.4g} Pa in the scene, fitted up to {top:.4g} Pa{limit}")
    return out
