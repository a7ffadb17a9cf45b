"""TOML tables read field by field: every error names the file, the dotted field and the reason.

:class:`Table` consumes the fields it is asked for and rejects, when done, the ones it never
read (unknown fields are errors, not silently ignored). A field name that is close to one the
parser asked for is reported as a misspelling of it ("unknown field `youngs_modulous`, did you
mean `youngs_modulus`?"), before a required field is reported missing.
"""

from __future__ import annotations

import difflib
import math

from vertebra.core.errors import SceneError

MAX_MAGNITUDE = 1e100        # larger inputs are mistakes (and overflow in l³, r⁴)
MIN_MAGNITUDE = 1e-100       # smaller positive sizes and moduli underflow (in l², r⁴) to zero
# How alike (difflib ratio) a field must be to one the parser asked for to be called its
# misspelling: "youngs_modulous" 0.97, "lenght" 0.83, "radus" 0.91, while distinct fields of one
# table stay below it ("outer_radius"/"inner_radius" 0.75, "youngs_modulus"/"shear_modulus" 0.67).
MISSPELLING_RATIO = 0.8


class Table:
    """Reads typed fields from one TOML table and rejects the ones it never read."""

    def __init__(self, data, path: str, source: str):
        if not isinstance(data, dict):
            raise SceneError(f"expected a table, got {type(data).__name__}", file=source, field=path or None)
        self.data, self.path, self.source, self.used = data, path, source, set()
        self.asked = set()      # every field the parser looked for, given or not

    def _given(self, key) -> bool:
        self.asked.add(key)
        return key in self.data

    def _name(self, key):
        return f"{self.path}.{key}" if self.path else key

    def error(self, key, reason):
        return SceneError(reason, file=self.source, field=self._name(key))

    def has(self, key):
        return self._given(key)

    def raw(self, key, default=None):
        self.asked.add(key)
        self.used.add(key)
        return self.data.get(key, default)

    def _misspelling(self, candidates, fields):
        """The first field of ``candidates`` (not asked for) that is close to one of ``fields``:
        ``(candidate, field)`` or None."""
        for candidate in sorted(str(c) for c in candidates):
            match = difflib.get_close_matches(candidate, list(fields), n=1, cutoff=MISSPELLING_RATIO)
            if match:
                return candidate, match[0]
        return None

    def missing(self, key):
        """The error for a required ``key`` that is absent. A field not asked for that looks
        like a misspelling (of ``key`` first, else of another field asked for) is reported
        instead: unknown fields are checked before required ones."""
        self.asked.add(key)
        unread = set(self.data) - self.asked
        found = self._misspelling(unread, [key]) or self._misspelling(unread, self.asked)
        if found:
            return self.error(found[0], f"unknown field `{found[0]}`, did you mean `{found[1]}`?")
        return self.error(key, "required field is missing")

    def number(self, key, default=None, *, positive=False, nonneg=False, required=False, integer=False,
               unbounded=False):
        """A number. Infinite values are accepted only where ``unbounded`` (actuator bounds:
        ``max_tension = inf``); magnitudes beyond 1e100 are refused as input mistakes."""
        if not self._given(key):
            if required:
                raise self.missing(key)
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"expected a number, got {type(value).__name__} {value!r}")
        if integer and not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {value!r}")
        if math.isnan(value) or (math.isinf(value) and not unbounded):
            raise self.error(key, f"expected a finite number, got {value!r}")
        if math.isfinite(value) and abs(value) > MAX_MAGNITUDE:
            raise self.error(key, f"magnitude {value!r} is beyond {MAX_MAGNITUDE:g}: not a physical input")
        if positive and not value > 0:
            raise self.error(key, f"must be > 0, got {value!r}")
        if positive and value < MIN_MAGNITUDE:
            raise self.error(key, f"magnitude {value!r} is below {MIN_MAGNITUDE:g}: not a physical input")
        if nonneg and not value >= 0:
            raise self.error(key, f"must be >= 0, got {value!r}")
        return int(value) if integer else float(value)

    def vector(self, key, n, default=None, *, required=False):
        if not self._given(key):
            if required:
                raise self.missing(key)
            return default
        value = self.raw(key)
        if (not isinstance(value, list) or len(value) != n
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.error(key, f"expected a list of {n} numbers, got {value!r}")
        if not all(math.isfinite(v) for v in value):
            raise self.error(key, f"expected finite numbers, got {value!r}")
        if any(abs(v) > MAX_MAGNITUDE for v in value):
            raise self.error(key, f"a magnitude beyond {MAX_MAGNITUDE:g} is not a physical input")
        return tuple(float(v) for v in value)

    def string(self, key, default=None, *, required=False, choices=None):
        if not self._given(key):
            if required:
                raise self.missing(key)
            return default
        value = self.raw(key)
        if not isinstance(value, str) or not value:
            raise self.error(key, f"expected a non-empty string, got {value!r}"[:200])
        if "\x00" in value:
            raise self.error(key, "a string cannot contain a NUL character")
        if choices and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def table(self, key):
        """The sub-table ``key`` (empty when absent, unless a field not asked for looks like its
        misspelling: that is reported as unknown)."""
        if not self._given(key):
            found = self._misspelling(set(self.data) - self.asked, [key])
            if found:
                raise self.error(found[0], f"unknown field `{found[0]}`, did you mean `{found[1]}`?")
        return Table(self.raw(key, {}), self._name(key), self.source)

    def tables(self, key):
        value = self.raw(key, [])
        if not isinstance(value, list):
            raise self.error(key, f"expected an array of tables ([[{key}]]), got {type(value).__name__}")
        return [Table(item, f"{self._name(key)}[{i}]", self.source) for i, item in enumerate(value)]

    def done(self):
        unknown = sorted(str(key) for key in set(self.data) - self.used)
        if unknown:
            found = self._misspelling(unknown, self.asked - set(self.data))
            if found:
                raise self.error(found[0], f"unknown field `{found[0]}`, did you mean `{found[1]}`?")
            raise self.error(unknown[0], "unknown field")
