"""The ``[[segment]]`` tables of a scene: beam sections, catalogue entries and designs.

A segment is repeated ``count`` times; each repetition ends at a vertebra (``vertebra = {…}``).
Three types (a registry of parsers, :data:`SEGMENT_PARSERS`):

* ``beam`` — an analytic Timoshenko beam of ``elements`` links per repetition;
* ``entry`` — a catalogue entry named by key, unique key prefix or name;
* ``design`` — a segment the scene describes by its design (geometry family, parameters,
  mesh settings, material, and for a nonlinear material optionally the ``sampling`` settings of
  its fitted energy). The runtime keeps it as data (:class:`DesignSpec`): the
  precompute side (``vertebra prepare``, ``vertebra.designer.prepare``) checks the family's
  parameters, computes the content key and designs the missing entries, and returns the
  scene with each design segment resolved to its entry (``type = "entry"``, ``entry`` = the
  key, ``design`` kept). A model cannot be built while a design segment is unresolved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from vertebra.solver.timoshenko import Section
from vertebra.solver.tables import Table
from vertebra.core.errors import SceneError

#: materials a design segment may ask for: small-strain linear elasticity,
#: St Venant–Kirchhoff and the compressible neo-Hooke form of Abaqus and CalculiX
DESIGN_MATERIALS = ("linear", "svk", "neo_hookean")


@dataclass(frozen=True)
class VertebraSpec:
    mass: float = 0.0
    center_of_mass: tuple = (0.0, 0.0, 0.0)   # in the vertebra's frame
    disc_radius: float = 0.0                  # a contact disc in the frame's x–y plane (0: none; docs/contact.md)
    disc_thickness: float = 0.0


@dataclass(frozen=True)
class DesignSpec:
    """What a ``type = "design"`` segment asks the designer for. ``None`` fields take the
    designer's defaults (as ``vertebra design`` without the option); ``parameters`` are the
    family's parameters as ``(name, value)`` pairs sorted by name (the scene stays immutable)."""

    family: str
    parameters: tuple
    mesh_size: float | None = None
    order: int | None = None
    material: str | None = None
    sampling: tuple | None = None     # (name, value) pairs sorted by name: the nonlinear sampling settings given

    def parameter_dict(self) -> dict:
        return dict(self.parameters)

    def options(self) -> dict:
        """The design options the scene sets (absent ones are left to the designer's defaults)."""
        given = {"mesh_size": self.mesh_size, "order": self.order, "material": self.material,
                 "sampling": None if self.sampling is None else dict(self.sampling)}
        return {name: value for name, value in given.items() if value is not None}


@dataclass(frozen=True)
class SegmentSpec:
    type: str
    count: int
    vertebra: VertebraSpec
    elements: int = 1
    # beam
    length: float = 0.0
    youngs_modulus: float = 0.0
    shear_modulus: float = 0.0
    section: Section | None = None
    density: float = 0.0
    # entry (a design segment gets its entry's key when it is resolved)
    entry: str = ""
    # design: what the entry is (or will be) designed from
    design: DesignSpec | None = None
    # contact: the links' chords are capsules of this radius (None: the segment touches nothing)
    contact_radius: float | None = None

    @property
    def resolved(self) -> bool:
        """Whether the runtime can build the segment (a design segment needs its entry first)."""
        return self.type != "design"


def parse_vertebra(t: Table) -> VertebraSpec:
    disc = parse_disc(t)
    spec = VertebraSpec(mass=t.number("mass", 0.0, nonneg=True),
                        center_of_mass=t.vector("center_of_mass", 3, (0.0, 0.0, 0.0)), **disc)
    inertia = t.raw("inertia")  # accepted for completeness (statics does not need it)
    if inertia is not None and not (isinstance(inertia, list) and len(inertia) in (3, 9) and all(
            not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in inertia)):
        raise t.error("inertia", f"expected 3 principal moments or 9 matrix entries (finite numbers), got {inertia!r}")
    t.done()
    return spec


def parse_disc(t: Table) -> dict:
    """``disc_radius`` and ``disc_thickness`` of a vertebra (or the base): its contact disc."""
    radius = t.number("disc_radius", 0.0, nonneg=True)
    thickness = t.number("disc_thickness", 0.0, nonneg=True)
    if thickness > 0.0 and radius == 0.0:
        raise t.error("disc_thickness", "a disc needs its `disc_radius` too")
    if radius > 0.0 and not 0.0 < thickness <= 2.0 * radius:
        raise t.error("disc_thickness", f"a disc needs a thickness above 0 and at most twice its radius, got "
                      f"{thickness:g} m with disc_radius {radius:g} m (its rim is rounded by half its thickness: "
                      "docs/contact.md)")
    return {"disc_radius": radius, "disc_thickness": thickness}


def parse_section(t: Table, poisson_ratio: float) -> Section:
    shape = t.string("shape", None, choices=("circle", "tube"))
    try:
        if shape == "circle":
            section = Section.circle(t.number("radius", required=True, positive=True), poisson_ratio)
        elif shape == "tube":
            outer = t.number("outer_radius", required=True, positive=True)
            inner = t.number("inner_radius", required=True, nonneg=True)
            if inner >= outer:
                raise t.error("inner_radius", f"{inner} must be smaller than outer_radius {outer}")
            section = Section.tube(outer, inner, poisson_ratio)
        else:
            area = t.number("area", required=True, positive=True)
            shear = t.number("shear_area", math.inf, positive=True)
            section = Section(area=area, Ixx=t.number("Ixx", required=True, positive=True),
                              Iyy=t.number("Iyy", required=True, positive=True),
                              J=t.number("J", required=True, positive=True),
                              shear_area_x=t.number("shear_area_x", shear, positive=True),
                              shear_area_y=t.number("shear_area_y", shear, positive=True))
    except (ValueError, OverflowError) as error:
        raise SceneError(str(error), file=t.source, field=t.path)
    t.done()
    return section


def _one_link(t: Table, elements: int, what: str) -> None:
    if elements != 1:
        raise t.error("elements", f"{what} is condensed onto two frames: elements must be 1")


def _beam(t: Table, count: int, elements: int, vertebra: VertebraSpec) -> SegmentSpec:
    length = t.number("length", required=True, positive=True)
    E = t.number("youngs_modulus", required=True, positive=True)
    if t.has("poisson_ratio") and t.has("shear_modulus"):
        raise t.error("shear_modulus", "give poisson_ratio or shear_modulus, not both")
    if t.has("shear_modulus"):
        G = t.number("shear_modulus", positive=True)
        nu = E / (2 * G) - 1.0
        if not -1.0 < nu < 0.5:
            raise t.error("shear_modulus", f"implies a Poisson ratio E/(2G) − 1 = {nu:.4g} outside (-1, 0.5)")
    else:
        nu = t.number("poisson_ratio", 0.3)
        if not -1.0 < nu < 0.5:
            raise t.error("poisson_ratio", f"must lie in (-1, 0.5), got {nu}")
        G = E / (2 * (1 + nu))
    section = parse_section(t.table("section"), nu)
    if not t.has("section"):
        raise t.error("section", "required field is missing")
    density = t.number("density", 0.0, nonneg=True)
    return SegmentSpec(type="beam", count=count, vertebra=vertebra, elements=elements, length=length,
                       youngs_modulus=E, shear_modulus=G, section=section, density=density)


def _entry(t: Table, count: int, elements: int, vertebra: VertebraSpec) -> SegmentSpec:
    entry = t.string("entry", required=True)
    _one_link(t, elements, "a catalogue entry")
    return SegmentSpec(type="entry", count=count, vertebra=vertebra, entry=entry)


def _design(t: Table, count: int, elements: int, vertebra: VertebraSpec) -> SegmentSpec:
    """The family and its parameters are checked as data here (names are the designer's
    business: ``vertebra prepare`` checks them against the family and names the valid ones)."""
    family = t.string("family", required=True)
    if not t.has("parameters"):
        raise t.error("parameters", f"required field is missing: the parameters of family {family!r}")
    pt = t.table("parameters")
    if not pt.data:
        raise t.error("parameters", f"the parameters of family {family!r} are missing (an empty table)")
    parameters = tuple(sorted((name, pt.number(name)) for name in pt.data))
    pt.done()
    order = t.number("order", None, integer=True)
    if order is not None and order not in (1, 2):
        raise t.error("order", f"must be 1 or 2, got {order}")
    design = DesignSpec(family=family, parameters=parameters, mesh_size=t.number("mesh_size", None, positive=True),
                        order=order, material=t.string("material", None, choices=DESIGN_MATERIALS),
                        sampling=_sampling(t))
    _one_link(t, elements, "a designed entry")
    return SegmentSpec(type="design", count=count, vertebra=vertebra, design=design)


def _sampling(t: Table) -> tuple | None:
    """The ``sampling`` table (numbers and true/false; their names and ranges are the
    designer's to check), or None when absent."""
    if not t.has("sampling"):
        return None
    st = t.table("sampling")
    values = []
    for name in sorted(st.data):
        value = st.raw(name)
        if not isinstance(value, (bool, int, float)):
            raise st.error(name, f"expected a number or true/false, got {value!r}")
        values.append((name, st.number(name) if isinstance(value, float) else value))   # integers stay integers
    st.done()
    return tuple(values)


#: segment type -> parser of the rest of its table (count, elements and vertebra are read first)
SEGMENT_PARSERS = {"beam": _beam, "entry": _entry, "design": _design}
SEGMENT_TYPES = tuple(SEGMENT_PARSERS)


def parse_segment(t: Table) -> SegmentSpec:
    kind = t.string("type", required=True, choices=SEGMENT_TYPES)
    count = t.number("count", 1, integer=True, positive=True)
    elements = t.number("elements", 1, integer=True, positive=True)
    vertebra = parse_vertebra(t.table("vertebra"))
    segment = SEGMENT_PARSERS[kind](t, count, elements, vertebra)
    contact_radius = t.number("contact_radius", None, nonneg=True)
    t.done()
    return segment if contact_radius is None else replace(segment, contact_radius=contact_radius)

