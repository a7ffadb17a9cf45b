"""A sweep specification (TOML): family, fixed parameters, design options, one sampler.

The design options of a spec map one to one onto keyword arguments of
``designer.design_segment``; :data:`DESIGN_OPTIONS` declares each one (its default, its
check, and whether it is part of the content key, i.e. also an argument of
``designer.entry_key``). Adding a design setting to sweeps is one row of that table.

Every error is a :class:`SpecError` naming the file, the field and the reason; nothing is
designed before the spec is valid.
"""

from __future__ import annotations

import re
import string
from dataclasses import dataclass, field
from typing import Any, Callable

from vertebra.core.errors import OptionError, SpecError
from vertebra.core.inputs import check_depth, load_toml
from vertebra.designer.keys import check_material, sampling_settings
from vertebra.designer.sweep.samplers import SAMPLERS, check_value, is_number


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
        raise Invalid(f"{error.field.removeprefix('sampling.')}: {error.reason}") from None
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


MAX_NAME_TEMPLATE = 200     # characters of a name template, and of a name it makes
MAX_FIELD_WIDTH = 40        # width and precision of one field of a name template
_FORMAT_SPEC = re.compile(r"^(?:.?[<>=^])?[+ -]?z?#?0?(\d*)[_,]?(?:\.(\d+))?[a-zA-Z%]?$")


class NameFormatter(string.Formatter):
    """``str.format`` restricted to what an entry name needs: plain field names (no attribute
    or index access: ``{radius.__class__}`` is refused), no nested fields in a format spec,
    widths and precisions of at most :data:`MAX_FIELD_WIDTH` and names of at most
    :data:`MAX_NAME_TEMPLATE` characters. Each refusal is a ``ValueError`` saying why."""

    def check(self, template: str) -> None:
        """Raise ValueError when ``template`` is not a name template this formatter fills."""
        if len(template) > MAX_NAME_TEMPLATE:
            raise ValueError(f"at most {MAX_NAME_TEMPLATE} characters; got {len(template)}")
        for _, field_name, spec, conversion in self.parse(template):
            if field_name is None:
                continue
            self._check_name(field_name)
            if conversion not in (None, "r", "s", "a"):
                raise ValueError(f"unknown conversion !{conversion}")
            self._check_spec(field_name, spec)

    @staticmethod
    def _check_name(field_name: str) -> None:
        if not field_name.isidentifier():
            raise ValueError(f"field {{{field_name}}}: a name template takes plain names ({{index}}, "
                             "{family} or a parameter), not positions, attributes or indices")

    @staticmethod
    def _check_spec(field_name: str, spec: str) -> None:
        if "{" in spec or "}" in spec:
            raise ValueError(f"field {{{field_name}}}: nested fields in a format spec are not supported")
        match = _FORMAT_SPEC.match(spec)
        if match is None:
            raise ValueError(f"field {{{field_name}}}: bad format spec {spec!r}")
        for number in match.groups():
            if number and int(number) > MAX_FIELD_WIDTH:
                raise ValueError(f"field {{{field_name}}}: width or precision at most {MAX_FIELD_WIDTH}; "
                                 f"got {int(number):,}")

    def get_field(self, field_name, args, kwargs):
        self._check_name(field_name)
        return self.get_value(field_name, args, kwargs), field_name

    def format_field(self, value, format_spec):
        self._check_spec("?", format_spec)
        return super().format_field(value, format_spec)

    def fill(self, template: str, **values) -> str:
        name = self.format(template, **values)
        if len(name) > MAX_NAME_TEMPLATE:
            raise ValueError(f"the name has {len(name)} characters; at most {MAX_NAME_TEMPLATE}")
        return name


def _parse_name(name, source: str) -> str | None:
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise SpecError("expected a non-empty string template", file=source, field="name")
    try:
        NameFormatter().check(name)
    except ValueError as error:
        raise SpecError(f"bad template {name[:60]!r}: {error}", file=source, field="name") from None
    return name


def parse_spec(data: dict, source: str = "<dict>") -> SweepSpec:
    """Validate a sweep spec dictionary; SpecError names the file and the field."""
    if not isinstance(data, dict):
        raise SpecError("a sweep spec is a table", file=source)
    check_depth(data, SpecError, source=source)
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
    check_value(parameters, source, "parameters")
    sampler, design = _parse_sampler(data, parameters, source)
    options = _parse_options(data, source)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise SpecError("expected a string", file=source, field="description")
    return SweepSpec(family=family, parameters=dict(parameters), sampler=sampler, design=design, options=options,
                     name=_parse_name(data.get("name"), source), description=description, source=source)


def load_spec(path) -> SweepSpec:
    """Read and validate a sweep spec TOML file (bounded in size and nesting: core/inputs.py)."""
    return parse_spec(load_toml(path, SpecError), source=str(path))
