"""Plausibility of physical inputs: warnings that name the likely unit slip, never errors.

vertebra reads SI units (m, Pa, N). A value that is valid but implausible for a continuum robot
is most likely a number written in another unit — a pressure of ``1.5`` meant as bar, a
Young's modulus of ``5`` meant as MPa, a mesh size of ``4`` meant as mm. Each check here issues
a :class:`~vertebra.core.errors.PlausibilityWarning` naming where the value came from, the
value, and what it would be in the unit the writer probably meant; the computation goes on
(a soft gel at 500 Pa or a 50 Pa balloon is rare, not impossible). The command line prints
each warning as one line on stderr.

The thresholds are below anything the project's robots use: elastomers start near 10 kPa
(soft silicones, Ecoflex 00-10 ≈ 55 kPa) and the softest pneumatic actuators run at
kilopascals, so 1 kPa and 100 Pa are far below both.
"""

from __future__ import annotations

import math
import warnings

from vertebra.core.errors import PlausibilityWarning

MIN_PRESSURE = 100.0          # Pa: a nonzero pressure (or pressure bound) below this is likely bar or kPa
MIN_MODULUS = 1.0e3           # Pa: a Young's modulus below this is likely MPa or GPa
REACH_FACTOR = 10.0           # a target farther from the base than this × the trunk's length is likely mm


def warn(message: str, stacklevel: int = 3) -> None:
    warnings.warn(PlausibilityWarning(message), stacklevel=stacklevel)


def _where(source: str | None, field: str) -> str:
    return f"{source}: {field}" if source else field


def pressure(value: float, field: str, source: str | None = None) -> None:
    """Warn when a nonzero pressure (Pa) is below :data:`MIN_PRESSURE`."""
    if math.isfinite(value) and 0.0 < abs(value) < MIN_PRESSURE:
        warn(f"{_where(source, field)} = {value:g} Pa is below {MIN_PRESSURE:g} Pa; pressures are in Pa: did you "
             f"mean {value:g} bar ({value * 1e5:g} Pa) or {value:g} kPa ({value * 1e3:g} Pa)?")


def modulus(value: float, field: str, source: str | None = None) -> None:
    """Warn when a positive Young's modulus (Pa) is below :data:`MIN_MODULUS`."""
    if math.isfinite(value) and 0.0 < value < MIN_MODULUS:
        warn(f"{_where(source, field)} = {value:g} Pa is below 1 kPa, softer than any elastomer; moduli are in Pa: "
             f"did you mean {value:g} MPa ({value * 1e6:g} Pa) or {value:g} GPa ({value * 1e9:g} Pa)?")


def part_size(parameters: dict) -> float | None:
    """The largest extent of a segment described by its design parameters (m): its length or
    its outer diameter, from the parameters named ``length``, ``radius`` or ``…outer_radius``;
    None when there are none."""
    lengths = [float(v) for k, v in parameters.items() if k == "length" and _number(v)]
    radii = [float(v) for k, v in parameters.items() if (k == "radius" or k.endswith("outer_radius")) and _number(v)]
    sizes = lengths + [2.0 * r for r in radii]
    return max(sizes) if sizes else None


def outer_radius(parameters: dict) -> float | None:
    """The outer radius of a segment described by its design parameters (m), or None."""
    radii = [float(v) for k, v in parameters.items() if (k == "radius" or k.endswith("outer_radius")) and _number(v)]
    return max(radii) if radii else None


def design(parameters: dict, mesh_size: float | None, source: str | None = None, *,
           parameters_field: str = "parameters", mesh_field: str = "mesh_size") -> None:
    """The checks of a segment design: its Young's modulus, and a mesh size larger than the part."""
    if _number(parameters.get("youngs_modulus")):
        modulus(float(parameters["youngs_modulus"]),
                f"{parameters_field}.youngs_modulus" if parameters_field else "youngs_modulus", source)
    size = part_size(parameters)
    if mesh_size is not None and size is not None and math.isfinite(mesh_size) and mesh_size > size:
        warn(f"{_where(source, mesh_field)} = {mesh_size:g} m is larger than the part ({size:g} m across); lengths "
             f"are in m: did you mean {mesh_size:g} mm ({mesh_size * 1e-3:g} m)?")


def cable_radius(radius: float, vertebra_radius: float, field: str, source: str | None = None) -> None:
    """Warn when a cable's hole lies outside the vertebra it passes through."""
    if math.isfinite(radius) and radius > vertebra_radius > 0.0:
        warn(f"{_where(source, field)} = {radius:g} m puts the cable outside the vertebra ({vertebra_radius:g} m "
             f"radius); lengths are in m: did you mean {radius:g} mm ({radius * 1e-3:g} m)?")


def cable_length_scale(radius: float, length: float, field: str, source: str | None = None) -> None:
    """Warn when a cable's hole is farther from the axis than the whole trunk is long."""
    if math.isfinite(radius) and radius > length > 0.0:
        warn(f"{_where(source, field)} = {radius:g} m is larger than the whole trunk ({length:g} m long); lengths "
             f"are in m: did you mean {radius:g} mm ({radius * 1e-3:g} m)?")


def reach(distance: float, length: float, field: str, source: str | None = None) -> None:
    """Warn when a target ``distance`` (m) from the base exceeds :data:`REACH_FACTOR` × the trunk's ``length``."""
    if math.isfinite(distance) and length > 0.0 and distance > REACH_FACTOR * length:
        warn(f"{_where(source, field)} lies {distance:g} m from the base, {distance / length:.0f} times the trunk's "
             f"length of {length:g} m; lengths are in m: did you mean mm ({distance * 1e-3:g} m)?")


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
