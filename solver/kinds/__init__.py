"""Link kinds: which segments make which links, and the energy those links store.

Every link joins two frames and stores an energy ``ψ(ξ, p)`` of its strain
``ξ = log_SE3(T_a⁻¹ T_b)`` (:mod:`vertebra.solver.links`) and of the pressures ``p`` of the
chambers that act on its cavities. A *kind* says how a scene segment becomes links
(:class:`LinkKind`) and, through its :attr:`LinkKind.energy` class, how the energy of all its
links is evaluated batched (:class:`LinkEnergy`). The runtime never looks inside ψ: the link
kinematics and the assembly consume only

* ``ψ`` summed over the links (the total potential),
* ``w = ∂ψ/∂ξ`` (n, 6), the strain-space force,
* the material tangent ``∂²ψ/∂ξ²`` (n, 6, 6),
* the chamber forces ``−∂²ψ/∂ξ∂p`` (n, n_chambers, 6) — the strain-space force per unit
  pressure, giving the chambers' actuator Jacobian columns — and the volume growth
  ``−∂ψ/∂p`` (n_chambers,);
* the states outside the range an energy was fitted on (:class:`RangeExcess`), for the
  diagnostics of a result (an energy valid everywhere reports none).

Kinds register themselves: each module of this package calls :func:`register` when it is
imported, and every module here is imported the first time a kind is looked up, so adding a
kind is adding one module. :func:`kind_for` picks, among the kinds that claim a segment, the
one with the highest ``priority``. Links of kinds that share an energy class are evaluated as
one batch.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, Sequence

import numpy as np

from vertebra.core.errors import OptionError, SceneError


@dataclass(frozen=True)
class LinkSource:
    """One link of a segment repetition as its kind describes it, before it is repeated along
    the trunk: rest pose of ``b`` in ``a``, mass properties, cavity rest volumes and
    the kind's own ``parameters`` (for a quadratic link its compliance blocks)."""

    rest_quaternion: np.ndarray     # (4,)
    rest_translation: np.ndarray    # (3,) d0
    mass: float
    center_of_mass: np.ndarray      # (3,) in a's axes
    cavity_volumes: np.ndarray      # (k,) one per cavity of the link
    parameters: Any


@dataclass(frozen=True)
class CompiledLinks:
    """What compile hands an energy class: its links' sources and where they stand.

    ``sources[s]`` made the links with ``source_of_link == s``; ``rest[s]``/``strain_map[s]``
    are the source's rest strain ``ξ₀`` and ``A = ∂ξ/∂δ`` at rest (δ = [Δx; Δθ] of b in a's axes);
    ``cavity[l, j]`` is the cavity of link l that chamber j pressurises (−1: none);
    ``vertebra[l]`` the vertebra that ends link l's repetition (its proximal one is the previous);
    ``fields[s]`` names the scene field of the source (for errors), ``file`` the scene."""

    sources: Sequence[LinkSource]
    rest: np.ndarray            # (n_sources, 6)
    strain_map: np.ndarray      # (n_sources, 6, 6)
    source_of_link: np.ndarray  # (n,)
    cavity: np.ndarray          # (n, n_chambers) int
    vertebra: np.ndarray        # (n,) int
    fields: Sequence[str]
    file: str

    def error(self, source: int, reason: str) -> SceneError:
        return SceneError(reason, file=self.file, field=self.fields[source])


@dataclass(frozen=True)
class RangeExcess:
    """A quantity of a link's state outside the range its energy was fitted on: ``value`` lies
    ``excess`` widths of the fitted interval ``[lower, upper]`` beyond its nearer bound."""

    link: int                   # the link, in trunk order
    segment: int                # the scene segment that made it
    vertebrae: tuple            # (proximal, distal) vertebra of its repetition
    source: str                 # what the energy was fitted for (a catalogue entry's name)
    quantity: str               # e.g. "bending strain", "axial load", "cavity 0 pressure"
    value: float
    lower: float
    upper: float
    excess: float

    @property
    def unit(self) -> tuple[str, float]:
        """``(unit, factor)``: the physical unit the quantity reads in and the factor from its SI
        value (strain translations in mm, rotations in degrees of one link, loads in N and N·m,
        pressures in bar)."""
        return physical_unit(self.quantity)

    def to_dict(self) -> dict:
        unit, factor = self.unit
        return {"link": self.link, "segment": self.segment, "vertebrae": list(self.vertebrae), "entry": self.source,
                "quantity": self.quantity, "value": self.value, "lower": self.lower, "upper": self.upper,
                "excess": self.excess, "unit": unit, "value_in_unit": factor * self.value,
                "lower_in_unit": factor * self.lower, "upper_in_unit": factor * self.upper}

    def __str__(self) -> str:
        unit, factor = self.unit
        unit = unit if unit == "°" else f" {unit}"
        return (f"link {self.link} (segment {self.segment}, vertebrae {self.vertebrae[0]}–{self.vertebrae[1]}, "
                f"entry {self.source!r}): {self.quantity} {factor * self.value:.4g}{unit} outside the fitted range "
                f"[{factor * self.lower:.4g}, {factor * self.upper:.4g}]{unit} by {100.0 * self.excess:.3g} % "
                "of its width")


#: physical units of the range's quantities by the word that names their group and their kind
_UNITS = {("lateral", "strain"): ("mm", 1e3), ("axial", "strain"): ("mm", 1e3),
          ("bending", "strain"): ("°", 180.0 / np.pi), ("twist", "strain"): ("°", 180.0 / np.pi),
          ("lateral", "load"): ("N", 1.0), ("axial", "load"): ("N", 1.0),
          ("bending", "load"): ("N·m", 1.0), ("twist", "load"): ("N·m", 1.0)}


def physical_unit(quantity: str) -> tuple[str, float]:
    """``(unit, factor from SI)`` of a range quantity's name (``"bending strain"``,
    ``"axial load"``, ``"cavity 0 pressure"``, …); SI with factor 1 for a name not known."""
    words = quantity.split()
    if words and words[-1] == "pressure":
        return "bar", 1e-5
    return _UNITS.get(tuple(words[-2:]), ("(SI)", 1.0))


class LinkEnergy(Protocol):
    """The energy of a batch of links of one kind, evaluated batched (no per-link Python).

    ``prepared`` is what :meth:`prepare` made of the chamber pressures (once per load stage);
    ``xi`` are the strains of the batch's links (n, 6); ``kept`` is what :meth:`response` kept
    of its evaluation for the derivatives at the same strains (None when they need nothing)."""

    links: np.ndarray           # (n,) which links of the trunk, in order
    rest: np.ndarray            # (n, 6) rest strains ξ₀
    fitted: ClassVar[bool]      # was the energy fitted on a range (may ``out_of_range`` report)?

    @classmethod
    def compile(cls, links: np.ndarray, compiled: CompiledLinks) -> "LinkEnergy": ...

    def scaled(self, scale: np.ndarray) -> "LinkEnergy":
        """The same links with each energy multiplied by ``scale`` (n,): a stiffness scale."""

    def prepare(self, pressures: np.ndarray) -> Any: ...

    def response(self, xi: np.ndarray, prepared: Any) -> tuple[float, np.ndarray, Any]:
        """``(Σ ψ, w = ∂ψ/∂ξ (n, 6), kept)``."""

    def material_tangent(self, xi: np.ndarray, prepared: Any, kept: Any) -> np.ndarray:
        """``∂²ψ/∂ξ²`` (n, 6, 6) (may be a constant array shared between calls)."""

    def chamber_forces(self, xi: np.ndarray, prepared: Any, kept: Any) -> np.ndarray:
        """``−∂²ψ/∂ξ∂p`` (n, n_chambers, 6)."""

    def volume_growth(self, xi: np.ndarray, prepared: Any, pressures: np.ndarray) -> np.ndarray:
        """``−∂ψ/∂p`` summed over the links (n_chambers,)."""

    def out_of_range(self, xi: np.ndarray, prepared: Any) -> tuple[RangeExcess, ...]:
        """Every quantity of the links' states outside the range their energy was fitted on."""


class LinkKind(Protocol):
    """How segments of a scene become links of one energy class."""

    name: ClassVar[str]
    priority: ClassVar[int]             # the highest-priority kind that claims a segment makes it
    energy: ClassVar[type]              # a LinkEnergy class

    def claims(self, segment, entry) -> bool:
        """Does this kind make the links of ``segment`` (``entry``: its catalogue entry or None)?"""

    def source(self, segment, entry) -> LinkSource:
        """One link of a repetition of ``segment`` (all its links are alike)."""


_KINDS: dict[str, LinkKind] = {}
_DISCOVERED = False


def refuse_scaled_cavities(scale: np.ndarray, has_cavity: np.ndarray) -> None:
    """A stiffness scale applies to links without cavities only: a scaled material changes a
    cavity's pressure response too, which a scale of ψ alone does not capture."""
    if np.any(has_cavity & (scale != 1.0)):
        raise OptionError("a stiffness scale applies to segments without cavities only (a chamber's pressure "
                          "response would need its own scale)", field="stiffness_scale")


def register(kind: LinkKind) -> LinkKind:
    """Register a link kind under its name (a module of this package does it at import)."""
    _KINDS[kind.name] = kind
    return kind


def kinds() -> dict[str, LinkKind]:
    """Every registered kind, by name (importing this package's modules first)."""
    global _DISCOVERED
    if not _DISCOVERED:
        for info in pkgutil.iter_modules(__path__):
            importlib.import_module(f"{__name__}.{info.name}")
        _DISCOVERED = True
    return _KINDS


def kind_for(segment, entry) -> LinkKind:
    """The kind that makes the links of ``segment``."""
    claiming = [kind for kind in kinds().values() if kind.claims(segment, entry)]
    if not claiming:
        raise SceneError(f"no link kind makes segments of type {segment.type!r} (kinds: {', '.join(sorted(_KINDS))})")
    return max(claiming, key=lambda kind: kind.priority)
