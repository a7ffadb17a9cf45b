"""A sweep specification (TOML): family, fixed parameters, design options, one sampler.

The design options of a spec map one to one onto keyword arguments of
``designer.design_segment``; :data:`DESIGN_OPTIONS` declares each one (its default, its
check, and whether it is part of the content key, i.e. also an argument of
``designer.entry_key``). Adding a design setting to sweeps is one row of that table.

Every error is a :class:`SpecError` naming the file, the field and the reason; nothing is
designed before the spec is valid.
"""

from __future__ import annotations

import string
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from vertebra.core.errors import OptionError, SpecError
from vertebra.designer.keys import check_material, sampling_settings
from vertebra.designer.sweep.samplers import SAMPLERS, is_number


class Invalid(ValueError):
    """Raised by a design option's check; the reason becomes a SpecError naming the field."""


def _positive_length(value):
    if value is None:
        return None
    if not (is_number(value) and value > 0):
        raise Invalid(f"expected a positive length in metres, got {value!r}")
    return float(value)


def _element_order(value):
    if value not in (1, 2) or isinstance(value, bool):
        raise Invalid(f"expected 1 or 2, got {value!r}")
    return int(value)


def _text(value):
    if not isinstance(value, str):
        raise Invalid(f"expected a string, got {value!r}")
    return value


def _flag(value):
    if not isinstance(value, bool):
        raise Invalid(f"expected true or false, got {value!r}")
    return value


def _material(value):
    try:
        return check_material(value) if isinstance(value, str) else _text(value)
    except OptionError as error:
        raise Invalid(error.reason) from None


def _sampling(value):
    """Nonlinear sampling and fit settings: a table of ``SamplingSettings`` fields (checked)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise Invalid(f"expected a table of sampling settings, got {value!r}")
    try:
        sampling_settings(value)
    except OptionError as error:
        raise Invalid(f"{error.field}: {error.reason}") from None
    return dict(value)


@dataclass(frozen=True)
class DesignOption:
    """A spec field passed to ``design_segment`` as the keyword argument of the same name."""

    name: str
    default: Any
    check: Callable[[Any], Any]       # value -> normalised value; raises Invalid(reason)
    keyed: bool = False               # changes the entry's numbers: also passed to ``entry_key``


DESIGN_OPTIONS: tuple[DesignOption, ...] = (
    DesignOption("mesh_size", None, _positive_length, keyed=True),     # None: the family's default
    DesignOption("order", 2, _element_order, keyed=True),
    DesignOption("linear_solver", "auto", _text),
    DesignOption("estimate_accuracy", True, _flag),
    DesignOption("material", "linear", _material, keyed=True),      # linear | svk | neo_hookean
    DesignOption("sampling", None, _sampling, keyed=True),          # nonlinear sampling and fit settings
)

#: top-level fields that are not design options or samplers
SPEC_FIELDS = ("family", "parameters", "name", "description")


def keyed_options(options: dict) -> dict:
    """The design options that are part of the content key (``entry_key``'s keyword arguments)."""
    return {option.name: options[option.name] for option in DESIGN_OPTIONS if option.keyed}


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep specification. ``sampler`` is a key of ``SAMPLERS``."""

    family: str
    parameters: dict
    sampler: str
    design: Any                       # the sampler's validated table
    options: dict = field(default_factory=lambda: {o.name: o.default for o in DESIGN_OPTIONS})
    name: str | None = None           # str.format template over the parameters, index, family
    description: str = ""
    source: str = "<dict>"

    def __post_init__(self):
        if self.sampler not in SAMPLERS:
            raise SpecError(f"unknown sampler {self.sampler!r}", file=self.source, field=self.sampler)


def _parse_sampler(data: dict, parameters: dict, source: str) -> tuple[str, Any]:
    samplers = [name for name in SAMPLERS if name in data]
    if len(samplers) != 1:
        raise SpecError(f"exactly one of {', '.join('[' + s + ']' for s in SAMPLERS)} is needed, "
                        f"found {len(samplers)}" + (f" ({', '.join(samplers)})" if samplers else ""),
                        file=source, field=samplers[1] if len(samplers) > 1 else "grid")
    sampler = samplers[0]
    design = SAMPLERS[sampler].parse(data[sampler], source)
    clash = sorted(SAMPLERS[sampler].varied(design) & set(parameters))
    if clash:
        raise SpecError(f"{clash[0]!r} is both fixed in [parameters] and varied by [{sampler}]",
                        file=source, field=f"{sampler}.{clash[0]}")
    return sampler, design


def design_options(given: dict, error: Callable[[str, str], Exception]) -> dict:
    """Every design option: the values ``given`` checked and normalised, the defaults for the
    rest. ``error(option name, reason)`` makes the exception raised for a value that fails its
    check or a name that is not a design option."""
    known = {option.name for option in DESIGN_OPTIONS}
    for name in given:
        if name not in known:
            raise error(name, f"not a design option (known: {', '.join(sorted(known))})")
    options = {}
    for option in DESIGN_OPTIONS:
        try:
            options[option.name] = option.check(given.get(option.name, option.default))
        except Invalid as reason:
            raise error(option.name, str(reason)) from None
    return options


def _parse_options(data: dict, source: str) -> dict:
    given = {option.name: data[option.name] for option in DESIGN_OPTIONS if option.name in data}
    return design_options(given, lambda name, reason: SpecError(reason, file=source, field=name))


def _parse_name(name, source: str) -> str | None:
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise SpecError("expected a non-empty string template", file=source, field="name")
    try:
        list(string.Formatter().parse(name))
    except ValueError as error:
        raise SpecError(f"bad template {name!r}: {error}", file=source, field="name") from None
    return name


def parse_spec(data: dict, source: str = "<dict>") -> SweepSpec:
    """Validate a sweep spec dictionary; SpecError names the file and the field."""
    if not isinstance(data, dict):
        raise SpecError("a sweep spec is a table", file=source)
    known = set(SPEC_FIELDS) | {o.name for o in DESIGN_OPTIONS} | set(SAMPLERS)
    for name in data:
        if name not in known:
            raise SpecError(f"unknown field (known: {', '.join(sorted(known))})", file=source, field=name)
    family = data.get("family")
    if not isinstance(family, str) or not family:
        raise SpecError("required: the geometry family name, e.g. \"rod\"", file=source, field="family")
    parameters = data.get("parameters", {})
    if not isinstance(parameters, dict):
        raise SpecError("expected a table of fixed parameters", file=source, field="parameters")
    sampler, design = _parse_sampler(data, parameters, source)
    options = _parse_options(data, source)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise SpecError("expected a string", file=source, field="description")
    return SweepSpec(family=family, parameters=dict(parameters), sampler=sampler, design=design, options=options,
                     name=_parse_name(data.get("name"), source), description=description, source=source)


def load_spec(path) -> SweepSpec:
    """Read and validate a sweep spec TOML file."""
    import tomllib

    path = Path(path)
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise SpecError("file not found", file=str(path)) from None
    except tomllib.TOMLDecodeError as error:
        raise SpecError(f"not valid TOML: {error}", file=str(path)) from None
    return parse_spec(data, source=str(path))
