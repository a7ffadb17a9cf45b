"""Geometry families of intervertebral segments: a registry (STYLE.md §4).

A family names its parameters (with defaults), checks the geometric conditions
BEFORE any meshing (``GeometryError`` naming the parameter and the violated
condition), builds its solid with the gmsh OpenCASCADE kernel and classifies
the boundary surfaces of that solid into the physical groups every segment has:
``bottom`` (z = 0, coupled rigidly to frame a), ``top`` (z = length, coupled to
frame b), ``cavity_k`` (walls of sealed cavity k) and ``wall`` (free surface).

Cavities run through the whole segment and are sealed by the rigid vertebrae at
both ends (as the chambers of a CBHA-like section pass through its vertebrae):
the pressure acts on the cavity walls and on the two caps, i.e. on the rigid
end faces, over the hole area (see ``designer.fem``).

Adding a family touches one module: define a :class:`Family` subclass and
decorate it with ``@register_family`` (and name the module in ``designer/families/__init__.py``).
This module holds the base class and the registry; the family modules import it, and the
package imports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from vertebra.core.errors import GeometryError

FAMILIES: dict[str, "Family"] = {}


def register_family(cls):
    """Class decorator: instantiate the family and register it by its ``name``."""
    family = cls()
    if family.name in FAMILIES:
        raise ValueError(f"family {family.name!r} registered twice")
    FAMILIES[family.name] = family
    return cls


@dataclass(frozen=True)
class SegmentSymmetry:
    """Isometries that map a segment onto itself (its nonlinear energy is invariant under them).

    ``order``: rotations about the axis by 2π/order (0: every angle, an axisymmetric
    segment); ``mirror``: mirror planes through the axis, one at ``mirror_angle`` from +x
    (with the rotations, the dihedral group); ``end_flip``: the segment is the same seen
    from either end (a half turn about a horizontal axis in the mirror plane swaps a and b);
    ``cavity_angles``: per cavity, the angle of its centre about the axis, or ``None`` for a
    cavity on the axis (how the isometries permute cavities)."""

    order: int = 1
    mirror: bool = False
    mirror_angle: float = 0.0
    end_flip: bool = False
    cavity_angles: tuple = ()

    def describe(self) -> dict:
        return {"order": self.order, "mirror": self.mirror, "mirror_angle": self.mirror_angle,
                "end_flip": self.end_flip, "cavity_angles": list(self.cavity_angles)}


#: a solid of revolution symmetric about its mid-plane (rod, tube)
AXISYMMETRIC = SegmentSymmetry(order=0, mirror=True, end_flip=True)


@dataclass(frozen=True)
class Parameter:
    """One design parameter. ``default=None`` means required."""

    name: str
    description: str
    default: float | int | None = None
    integer: bool = False
    unit: str = ""


MATERIAL = (
    Parameter("youngs_modulus", "Young's modulus", unit="Pa"),
    Parameter("poisson_ratio", "Poisson's ratio"),
    Parameter("density", "mass density (0 = massless)", default=0.0, unit="kg/m^3"),
)


#: plausible sizes of a segment's dimensions, m (beyond: not a segment, and meshing would not end)
SIZE_RANGE = (1e-9, 1e4)
#: largest ratio of two positive dimensions (a 1e4 aspect ratio already needs ~1e5 elements)
MAX_ASPECT_RATIO = 1e4
#: plausible Young's moduli, Pa (from soft gels to diamond, with margin) and densities, kg/m^3
MODULUS_RANGE = (1e-3, 1e13)
MAX_DENSITY = 1e5


def require(condition: bool, parameter: str, message: str) -> None:
    """Raise ``GeometryError`` naming ``parameter`` unless ``condition`` holds."""
    if not condition:
        raise GeometryError(f"parameter {parameter!r}: {message}")


def check_material(p: dict) -> None:
    require(p["youngs_modulus"] > 0, "youngs_modulus", f"must be > 0, got {p['youngs_modulus']}")
    require(-1.0 < p["poisson_ratio"] < 0.5, "poisson_ratio",
            f"must satisfy -1 < poisson_ratio < 0.5, got {p['poisson_ratio']}")
    require(p["density"] >= 0, "density", f"must be >= 0, got {p['density']}")
    lo, hi = MODULUS_RANGE
    require(lo <= p["youngs_modulus"] <= hi, "youngs_modulus",
            f"{p['youngs_modulus']:g} Pa is outside the plausible range [{lo:g}, {hi:g}] Pa")
    require(p["density"] <= MAX_DENSITY, "density",
            f"{p['density']:g} kg/m^3 is above any material ({MAX_DENSITY:g} kg/m^3)")


def check_plausible(family: "Family", p: dict) -> None:
    """Physical plausibility of the dimensions (``unit == "m"``), before any meshing: each positive
    dimension within ``SIZE_RANGE`` and no two further apart than ``MAX_ASPECT_RATIO`` (a radius
    of 1e300 m next to a length of 4 cm would make gmsh run for ever)."""
    sizes = {spec.name: p[spec.name] for spec in family.parameters if spec.unit == "m" and p[spec.name] > 0}
    lo, hi = SIZE_RANGE
    for name, value in sizes.items():
        require(lo <= value <= hi, name, f"{value:g} m is outside the plausible range [{lo:g}, {hi:g}] m")
    if sizes:
        big, small = max(sizes, key=sizes.get), min(sizes, key=sizes.get)
        ratio = sizes[big] / sizes[small]
        require(ratio <= MAX_ASPECT_RATIO, big,
                f"{big} / {small} = {ratio:.3g} > {MAX_ASPECT_RATIO:g}: no segment is that slender or flat "
                "(and its mesh would not end)")


class Family:
    """Base class of a geometry family (one per module, registered)."""

    name: str = ""
    description: str = ""
    parameters: tuple[Parameter, ...] = ()
    is_segment: bool = True

    # ---- parameters ----------------------------------------------------
    def canonical(self, parameters: dict) -> dict:
        """Validated parameters with defaults filled, floats/ints normalised."""
        if not isinstance(parameters, dict):
            raise GeometryError(f"family {self.name!r}: parameters must be a dict, got {type(parameters).__name__}")
        known = {p.name: p for p in self.parameters}
        unknown = sorted(set(parameters) - set(known))
        for name in unknown:
            if f"{name}_deg" in known:        # angles are given in degrees, as in scene files
                raise GeometryError(f"family {self.name!r}: parameter {name!r} is spelt {name + '_deg'!r}: "
                                    f"the angle in degrees (as the scenes' angle_deg)")
        if unknown:
            raise GeometryError(
                f"family {self.name!r}: unknown parameter {unknown[0]!r} (known: {', '.join(sorted(known))})")
        out = {}
        for spec in self.parameters:
            value = parameters.get(spec.name, spec.default)
            if value is None:
                raise GeometryError(f"family {self.name!r}: parameter {spec.name!r} is required ({spec.description})")
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                try:
                    value = float(value)
                except (TypeError, ValueError):
                    raise GeometryError(f"parameter {spec.name!r}: not a number: {value!r}") from None
            if spec.integer:
                if float(value) != int(value):
                    raise GeometryError(f"parameter {spec.name!r}: must be an integer, got {value!r}")
                value = int(value)
            else:
                value = float(value)
                if not math.isfinite(value):
                    raise GeometryError(f"parameter {spec.name!r}: must be finite, got {value!r}")
            out[spec.name] = value
        self.check(out)
        check_plausible(self, out)
        return out

    def check(self, p: dict) -> None:
        """Geometric and material conditions; raise GeometryError."""
        raise NotImplementedError

    # ---- geometry --------------------------------------------------------
    def length(self, p: dict) -> float:
        return p["length"]

    def n_cavities(self, p: dict) -> int:
        return 0

    def default_mesh_size(self, p: dict) -> float:
        raise NotImplementedError

    def build(self, occ, p: dict) -> list[tuple[int, int]]:
        """Create the solid with ``gmsh.model.occ``; return its volume dimTags."""
        raise NotImplementedError

    def outer_radius(self, p: dict) -> float:
        """Largest distance of the solid from the axis (bounds the fibre strain of bending)."""
        return p["outer_radius"]

    def symmetry(self, p: dict) -> SegmentSymmetry:
        """The isometries mapping the segment onto itself (none unless a family says so)."""
        return SegmentSymmetry()

    def classify(self, point, p: dict) -> str:
        """Name of the physical group of the boundary surface through ``point``
        (a point on a lateral surface): ``cavity_k`` or ``wall``. End faces are
        recognised by the caller (z = 0, z = length)."""
        raise NotImplementedError


def nearest(distances: dict[str, float]) -> str:
    return min(distances, key=distances.get)

