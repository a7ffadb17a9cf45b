"""HDF5 layout of a catalogue file (schema version 2; described in docs/catalogue.md).

Layout::

    /                     attrs: format = "vertebra-catalogue", schema_version = 1
    /index                1-D chunked, resizable vlen UTF-8 strings: one canonical JSON row
                          per entry {key, name, family, parameters, n_cavities, mass,
                          checksum, content}; read once on open (names, prefixes, listing)
    /entries/<key>        one group per entry, named by its content key
        compliance        float64 (6+n, 6+n)
        cavity_volumes    float64 (n,)
        center_of_mass    float64 (3,)
        rest_translation  float64 (3,)
        rest_quaternion   float64 (4,)
        attrs: name, family (fixed-length UTF-8 strings), mass (float64) and
               mass_units ("kg"), parameters, mesh, accuracy, timings, provenance
               (canonical JSON, fixed-length UTF-8 strings), checksum, content
               ("sha256:<hex>")
        energy/           optional (schema v2): ψ(s, p) of a nonlinear segment
                          (:mod:`vertebra.core.energy`), see :func:`write_energy`;
                          covered by the checksum

A version-1 file is a version-2 file without energy groups: it reads unchanged. A file
is stamped 2 once it holds an entry with an energy group.

This module only knows how to write one entry into an open group, read it back
(checked), and compute digests. File-level concerns (locking, shards, atomic
replacement) live in ``store.shards``.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import unicodedata
from typing import Any

import numpy as np

from vertebra.core.energy import GROUPS, MAX_TERMS, EnergyFit, EnergyRange, rest_strain
from vertebra.store.entry import SegmentEntry, canonical_json
from vertebra.store import h5read
from vertebra.store.soundness import stored_problems
from vertebra.core.errors import CatalogueError

FORMAT = "vertebra-catalogue"
SCHEMA_VERSION = 2
#: the schema version a file needs: 1 unless it holds an entry with an energy group
ENERGY_SCHEMA_VERSION = 2

ARRAY_FIELDS = ("compliance", "cavity_volumes", "center_of_mass", "rest_translation", "rest_quaternion")
DICT_FIELDS = ("parameters", "mesh", "accuracy", "timings", "provenance")
# Fields that record *how/when* an entry was computed, not *what* it is. Two entries
# with the same key that differ only here are "identical content" (idempotent add,
# merge skips them); every other field difference is a conflict.
CIRCUMSTANTIAL_FIELDS = ("timings", "provenance")
#: wall-clock times recorded inside a content field (``accuracy``): circumstantial too
CIRCUMSTANTIAL_KEYS = {"accuracy": ("estimate_s",)}
#: relative tolerance within which two entries' stored numbers count as the same design: a
#: nonlinear fit repeated on the same mesh differs in the last bits (~1e-10 of the largest
#: coefficient) from summation order; any real change of design moves them by far more
SAME_DESIGN_TOLERANCE = 1e-7

# HDF5 attributes ``units`` and ``description`` of every dataset vertebra writes (readers do not
# need them: files without them read and verify as before). The compliance maps
# [f (N); m (N m); p (Pa)] at frame b to [Δx (m); Δθ (rad); ΔV (m³)], in frame a's axes.
DATASET_ATTRIBUTES = {
    "compliance": ("[[m/N, 1/N, m/Pa], [rad/N, rad/(N m), rad/Pa], [m^3/N, m^2/N, m^3/Pa]]",
                   "symmetric (6+n)x(6+n) compliance [[C, G], [G^T, V]]: rows [dx; dtheta; dV] (displacement "
                   "and rotation vector of frame b relative to frame a, in a's axes; cavity volume growths), "
                   "columns [f; m; p] (force and moment applied at b's origin, in a's axes; cavity pressures); "
                   "units by block (rows dx, dtheta, dV; columns f, m, p)"),
    "cavity_volumes": ("m^3", "rest volume of each cavity"),
    "center_of_mass": ("m", "centre of mass of the segment in frame a"),
    "rest_translation": ("m", "rest position d0 of frame b in frame a"),
    "rest_quaternion": ("1", "rest rotation R0 of frame b in frame a, unit quaternion [w, x, y, z]"),
    "index": ("none", "one canonical JSON row per entry: key, name, family, parameters, n_cavities, mass, "
                      "checksum, content"),
}

#: ``<name>_units`` attributes beside the attributes of an entry group that hold quantities (an
#: HDF5 attribute has no attributes of its own; for a JSON object, the rule its values follow);
#: readers do not need them
ENTRY_ATTRIBUTE_UNITS = {
    "mass": "kg",
    "parameters": "SI (m, Pa, kg/m^3); ratios and counts 1; a name ending in _deg is an angle in degrees",
    "mesh": "mesh_size m; counts and order 1",
    "accuracy": "relative errors and ratios 1; sizes m; compliances as the dataset compliance; names ending "
                "in _s: s",
    "timings": "s",
}

MAX_JSON_BYTES = 1 << 20       # one metadata attribute or one index row
MAX_TEXT_CHARS = 256           # names and families
MAX_ARRAY_SIDE = 6 + 256       # 6+n cavities; a larger compliance is not a segment
MAX_INDEX_ROWS = 10_000_000    # rows of /index

KEY_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")


# ---------------------------------------------------------------- sanitising

def check_key(key: Any, where: str = "") -> str:
    """A key becomes an HDF5 group name and part of a shard file name: no path tricks."""
    if not isinstance(key, str) or not KEY_PATTERN.match(key) or ".." in key:
        raise CatalogueError(
            f"{where}invalid entry key {key!r}: expected 1-128 characters from [A-Za-z0-9_.-], "
            "starting with a letter or digit, without '..'")
    return key


def check_text(value: Any, field: str, where: str = "", *, allow_empty: bool = False) -> str:
    """Names and families: printable text, no path separators or control characters."""
    if not isinstance(value, str):
        raise CatalogueError(f"{where}entry field {field!r}: expected a string, got {type(value).__name__}")
    if not value and not allow_empty:
        raise CatalogueError(f"{where}entry field {field!r}: must not be empty")
    if len(value) > MAX_TEXT_CHARS:
        raise CatalogueError(f"{where}entry field {field!r}: {len(value)} characters > {MAX_TEXT_CHARS}")
    bad = [c for c in value if unicodedata.category(c)[0] == "C" or c in "/\\"]
    if bad or value in (".", "..") or value != value.strip():
        raise CatalogueError(
            f"{where}entry field {field!r}: {value!r} contains path separators, control characters "
            "or surrounding whitespace")
    return value


def to_jsonable(value: Any, path: str) -> Any:
    """Plain JSON data from dict/list/tuple/number/str/bool/None and numpy scalars/arrays.

    Tuples and arrays become lists; dictionary keys must be strings. Anything else
    (sets, objects, NaN, infinity) is refused with the path of the offending value.
    """
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise CatalogueError(f"{path}: {value} is not finite (JSON has no NaN/infinity)")
        return float(value)
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist(), path)
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v, f"{path}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise CatalogueError(f"{path}: key {k!r} is not a string")
            out[k] = to_jsonable(v, f"{path}.{k}")
        return out
    raise CatalogueError(f"{path}: value of type {type(value).__name__} is not JSON data")


def parse_json(text: str | bytes, what: str, limit: int = MAX_JSON_BYTES) -> Any:
    """Parse JSON from the file with a size limit; no NaN/infinity, no pickle, no eval."""
    if isinstance(text, bytes):
        if len(text) > limit:
            raise CatalogueError(f"{what}: {len(text)} bytes > limit {limit}")
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as error:
            raise CatalogueError(f"{what}: not UTF-8 ({error})") from None
    if len(text) > limit:
        raise CatalogueError(f"{what}: {len(text)} characters > limit {limit}")
    try:
        return _DECODER.decode(text)
    except (ValueError, RecursionError) as error:
        raise CatalogueError(f"{what}: invalid JSON ({error})") from None


def _reject_constant(constant):
    raise ValueError(f"{constant} is not allowed")


_DECODER = json.JSONDecoder(parse_constant=_reject_constant)       # one decoder: rows are parsed one by one


# ---------------------------------------------------------------- digests

def _metadata(key, name, family, mass, dicts: dict, *, content_only: bool) -> dict:
    meta = {"key": key, "name": name, "family": family, "mass": float(mass)}
    for field in DICT_FIELDS:
        if content_only and field in CIRCUMSTANTIAL_FIELDS:
            continue
        meta[field] = _content_part(field, dicts[field]) if content_only else dicts[field]
    return meta


def _content_part(field: str, value):
    """``value`` without the circumstantial keys of ``field`` (wall-clock times)."""
    drop = CIRCUMSTANTIAL_KEYS.get(field, ())
    if not drop or not isinstance(value, dict):
        return value
    return {k: v for k, v in value.items() if k not in drop}


def _digest(arrays: dict, meta: dict, energy=None) -> str:
    """SHA-256 over, per array in ARRAY_FIELDS order, ``b"<name>:<shape,comma-joined>:"``
    followed by the little-endian float64 C-order bytes, then the canonical JSON of ``meta``,
    then (schema v2, only when the entry has one) ``energy.digest_bytes()``."""
    h = hashlib.sha256()
    for field in ARRAY_FIELDS:
        arr = np.ascontiguousarray(arrays[field], dtype="<f8")
        h.update(f"{field}:{','.join(str(s) for s in arr.shape)}:".encode())
        h.update(arr.tobytes())
    h.update(canonical_json(meta).encode())
    if energy is not None:
        h.update(energy.digest_bytes())
    return "sha256:" + h.hexdigest()


def digests(key, name, family, mass, arrays: dict, dicts: dict, energy=None) -> tuple[str, str]:
    """(checksum over every field, content digest without timings/provenance)."""
    checksum = _digest(arrays, _metadata(key, name, family, mass, dicts, content_only=False), energy)
    content = _digest(arrays, _metadata(key, name, family, mass, dicts, content_only=True), energy)
    return checksum, content


class EncodedEntry:
    """An entry checked and normalised for storage: JSON-exact dicts, digests computed."""

    __slots__ = ("entry", "key", "name", "family", "mass", "arrays", "dicts", "checksum", "content")

    def __init__(self, entry: SegmentEntry):
        if not isinstance(entry, SegmentEntry):
            raise CatalogueError(f"expected a SegmentEntry, got {type(entry).__name__}")
        self.entry = entry
        self.key = check_key(entry.key)
        where = f"entry {entry.key}: "
        self.name = check_text(entry.name, "name", where)
        self.family = check_text(entry.family, "family", where, allow_empty=True)
        self.mass = float(entry.mass)
        self.arrays = {f: np.ascontiguousarray(getattr(entry, f), dtype="<f8") for f in ARRAY_FIELDS}
        if self.arrays["compliance"].shape[0] > MAX_ARRAY_SIDE:
            raise CatalogueError(f"{where}compliance larger than {MAX_ARRAY_SIDE}")
        self.dicts = {}
        for field in DICT_FIELDS:
            value = getattr(entry, field)
            if not isinstance(value, dict):
                raise CatalogueError(f"{where}field {field!r} must be a dict, got {type(value).__name__}")
            plain = to_jsonable(value, f"{where}field {field!r}")
            if len(canonical_json(plain).encode()) > MAX_JSON_BYTES:
                raise CatalogueError(f"{where}field {field!r}: more than {MAX_JSON_BYTES} bytes of JSON")
            self.dicts[field] = plain
        self.checksum, self.content = digests(self.key, self.name, self.family, self.mass,
                                              self.arrays, self.dicts, entry.energy)

    def legacy_content(self) -> str:
        """The content digest as files written before ``CIRCUMSTANTIAL_KEYS`` existed store it
        (wall-clock times inside ``accuracy`` included): their index rows still verify."""
        dicts = {field: self.dicts[field] for field in DICT_FIELDS}
        meta = {"key": self.key, "name": self.name, "family": self.family, "mass": float(self.mass)}
        meta.update({f: dicts[f] for f in DICT_FIELDS if f not in CIRCUMSTANTIAL_FIELDS})
        return _digest(self.arrays, meta, self.entry.energy)

    def index_row(self) -> dict:
        return {"key": self.key, "name": self.name, "family": self.family,
                "parameters": self.dicts["parameters"], "n_cavities": int(self.arrays["cavity_volumes"].size),
                "mass": self.mass, "checksum": self.checksum, "content": self.content}


# ---------------------------------------------------------------- HDF5 encoding

def _fixed_string(text: str) -> np.ndarray:
    import h5py

    data = text.encode("utf-8")
    return np.array(data, dtype=h5py.string_dtype("utf-8", max(len(data), 1)))


def _entry_path(key: str) -> str:
    return f"/entries/{key}"


def entry_group(f, key: str, what: str, *, required: bool = True):
    """The group ``/entries/<key>`` of an open catalogue file, through hard links only
    (None if absent and not ``required``)."""
    check_key(key, f"{what}: ")
    entries = h5read.child(f, "entries", what, "/", "group")
    group = h5read.child(entries, key, what, "/entries", "group", required=False)
    if group is None and required:
        raise CatalogueError(f"{what}: the index lists {key} but its entry group is missing (corrupt file)")
    return group


def entry_keys(f, what: str) -> list[str]:
    """Names of the groups under ``/entries`` (no entry is opened)."""
    entries = h5read.child(f, "entries", what, "/", "group")
    return h5read.member_names(entries, what, "/entries")


def write_entry(entries_group, enc: EncodedEntry) -> None:
    """Create ``entries_group/<key>`` holding the encoded entry (contiguous float64 datasets)."""
    group = entries_group.create_group(enc.key)
    for field in ARRAY_FIELDS:
        _describe(group.create_dataset(field, data=enc.arrays[field]), field)
    group.attrs["name"] = _fixed_string(enc.name)
    group.attrs["family"] = _fixed_string(enc.family)
    group.attrs["mass"] = np.float64(enc.mass)
    _attribute_units(group, ENTRY_ATTRIBUTE_UNITS)
    for field in DICT_FIELDS:
        group.attrs[field] = _fixed_string(canonical_json(enc.dicts[field]))
    group.attrs["checksum"] = _fixed_string(enc.checksum)
    group.attrs["content"] = _fixed_string(enc.content)
    if enc.entry.energy is not None:
        write_energy(group, enc.entry.energy, enc.entry.rest_translation)
        stamp_version(group.file, ENERGY_SCHEMA_VERSION)


def read_stored_digests(group, what: str, path: str) -> tuple[str, str]:
    return (h5read.read_string_attribute(group, "checksum", what, path, 200),
            h5read.read_string_attribute(group, "content", what, path, 200))


def read_entry(group, key: str, what: str) -> SegmentEntry:
    """Read and check one entry group: links, sizes, shapes, dtypes, JSON, checksum, validity
    and physical soundness. Every problem is a CatalogueError naming ``what`` and the object."""
    check_key(key, f"{what}: ")
    path = _entry_path(key)
    problems = h5read.walk(group, what, path)      # links, foreign storage, attribute sizes
    if problems:
        raise CatalogueError(problems[0] + (f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""))
    arrays = {field: h5read.read_float_dataset(group, field, what, path, max_side=MAX_ARRAY_SIDE)
              for field in ARRAY_FIELDS}
    name = h5read.read_string_attribute(group, "name", what, path, 4 * MAX_TEXT_CHARS)
    family = h5read.read_string_attribute(group, "family", what, path, 4 * MAX_TEXT_CHARS)
    mass = h5read.read_number_attribute(group, "mass", what, path, "f")
    if not math.isfinite(mass):
        raise h5read.failure(what, path, f"attribute 'mass' is {mass}, not a finite number")
    dicts = {}
    for field in DICT_FIELDS:
        text = h5read.read_string_attribute(group, field, what, path, MAX_JSON_BYTES)
        value = parse_json(text, f"{what}: {path}: attribute {field!r}")
        if not isinstance(value, dict):
            raise h5read.failure(what, path, f"attribute {field!r} is not a JSON object")
        dicts[field] = value
    stored_checksum, _ = read_stored_digests(group, what, path)
    energy = None
    energy_group = h5read.child(group, ENERGY_GROUP, what, path, "group", required=False)
    if energy_group is not None:
        try:
            energy = read_energy(group, what, path, arrays["rest_translation"])
        except (OSError, KeyError, ValueError, TypeError, RuntimeError) as error:
            raise h5read.failure(what, f"{path}/{ENERGY_GROUP}", f"unreadable ({error})") from None
    try:
        checksum, _ = digests(key, name, family, mass, arrays, dicts, energy)
    except (ValueError, TypeError) as error:
        raise h5read.failure(what, path, f"metadata cannot be digested ({error})") from None
    if checksum != stored_checksum:
        raise CatalogueError(f"{what}: entry {key} ({name!r}): checksum mismatch — stored {stored_checksum}, "
                             f"data gives {checksum}; the entry is corrupt")
    try:
        entry = SegmentEntry(key=key, name=name, family=family, mass=mass, **arrays, **dicts, energy=energy)
    except CatalogueError as error:
        raise CatalogueError(f"{what}: entry {key}: {error}") from None
    problems = stored_problems(entry)
    if problems:
        raise CatalogueError(f"{what}: entry {key} ({name!r}) is not sound: " + "; ".join(problems))
    return entry


# ---------------------------------------------------------------- the energy group (schema v2)

ENERGY_GROUP = "energy"
_ENERGY_DATASETS = {"exponents": "<i8", "coefficients": "<f8", "scales": "<f8"}
_BOUND_UNITS = {"pose": "[m, m, rad, rad]", "load": "[N, N, N m, N m]", "pressure": "Pa"}
_BOUNDED = {"pose": "the strain s", "load": "the load d psi / d s (the wrench conjugate to s)",
            "pressure": "each cavity pressure"}
_GROUP_TEXT = "[" + ", ".join(f"{name} {coordinate}" for name, coordinate in
                              zip(GROUPS, ("|rho_xy|", "rho_z", "|phi_xy|", "phi_z"))) + "]"
#: ``units`` and ``description`` of the datasets of ``<entry>/energy`` (paths inside the group).
#: ``exponents``, ``coefficients`` and ``scales`` are the energy; the others restate, for readers
#: with HDF5 tools only, what the entry's checksummed fields fix: ``rest_strain`` and
#: ``strain_map`` follow from ``rest_translation``, ``range/*`` from the JSON attribute ``range``.
ENERGY_DATASET_ATTRIBUTES = {
    "exponents": ("1", "exponents of the monomials of psi_nl in u = [s; w(p)] / scales, one row per term"),
    "coefficients": ("J", "coefficient of each monomial of psi_nl"),
    "scales": ("[m, m, m, rad, rad, rad, Pa...]", "scales of the variables [s; w(p)] (u = [s; w(p)] / scales)"),
    "rest_strain": ("[m, m, m, rad, rad, rad]",
                    "rest strain xi0 = log_SE3(T0) = [rho0; phi0] of the rest pose T0 of frame b in frame a "
                    "(rest_translation, rest_quaternion); the energy's strain is s = xi - xi0"),
    "strain_map": ("[[1, m/rad], [rad/m, 1]]",
                   "A = d xi / d delta at rest: the strain change per displacement delta = [dx; dtheta] of "
                   "frame b (the rows of ../compliance); psi_lin has K = inv(A C A^T), S = A G; units by block "
                   "(rows rho, phi; columns dx, dtheta)"),
    **{f"range/{kind}_{side}": (_BOUND_UNITS[kind], f"{side} bounds of {_BOUNDED[kind]} where psi was sampled"
                                + ("" if kind == "pressure" else f", in the group coordinates {_GROUP_TEXT}"))
       for kind in ("pose", "load", "pressure") for side in ("lower", "upper")},
    "range/limit_pressure": ("Pa", "the inflation limit point met while sampling, above every sampled pressure "
                                   "(absent: none was met)"),
}
#: text attributes of ``<entry>/energy`` that say what it holds (readers do not need them)
ENERGY_TEXT = {
    "strain": "s = xi - xi0: xi = log_SE3(T_a^-1 T_b) = [rho; phi] the relative pose of the top frame b in the "
              "bottom frame a as a twist (translation rho in m, then rotation vector phi in rad, in a's axes), "
              "xi0 = rest_strain; p = the cavity pressures (Pa)",
    "definition": "psi(s, p) = 1/2 (s - S p)^T K (s - S p) - 1/2 p^T V p + sum_k coefficients[k] "
                  "prod_j u_j^exponents[k, j] (J), u = [s; w(p)] / scales; w(p) = p, or 2 P (1 - sqrt(1 - p/P)) "
                  "when fold_pressure = P is not null; K = inv(A C A^T), S = A G with A = strain_map and "
                  "[[C, G], [G^T, V]] = ../compliance; d psi / d s is the load on the strain, -d psi / d p the "
                  "cavity volume growth (m^3)",
}
#: ``<name>_units`` beside the energy group's attributes that hold quantities
ENERGY_ATTRIBUTE_UNITS = {
    "fold_pressure": "Pa",
    "range": "as the datasets range/*: pose [m, m, rad, rad], load [N, N, N m, N m], pressure Pa",
    "fit_error": "1 (fractions of the load bounds and of the largest volume growth; relative errors)",
    "material": "moduli and C10 Pa; poisson_ratio 1; D1 1/Pa",
    "sampling": "SI (m, rad, N, N m, Pa, s); shear and axial as fractions of the length; counts 1",
}
#: the JSON attributes of the energy group and the text one
_ENERGY_ATTRIBUTES = ("representation", "range", "fit_error", "material", "sampling", "fold_pressure")


def write_energy(entry_group, fit: EnergyFit, rest_translation: np.ndarray) -> None:
    """Create ``<entry>/energy``: datasets ``exponents`` (int64 (m, 6+n)), ``coefficients``
    (float64 (m,)), ``scales`` (float64 (6+n,)); attributes ``representation`` (text) and
    ``range``, ``fit_error``, ``material``, ``sampling``, ``fold_pressure`` (JSON; fixed-length
    UTF-8). Beside them, for readers with HDF5 tools only: the strain's definition and ψ's form
    (text attributes ``strain`` and ``definition``), ``rest_strain`` (6,) and ``strain_map``
    (6, 6), the range's bounds as datasets with units (``range/``), ``<name>_units`` beside the
    attributes that hold quantities."""
    group = entry_group.create_group(ENERGY_GROUP)
    for name, dtype in _ENERGY_DATASETS.items():
        dataset = group.create_dataset(name, data=np.ascontiguousarray(getattr(fit, name), dtype=dtype))
        _describe(dataset, name, ENERGY_DATASET_ATTRIBUTES)
    for name, value in fit.attributes().items():
        group.attrs[name] = _fixed_string(value if isinstance(value, str) else canonical_json(value))
    _attribute_units(group, ENERGY_ATTRIBUTE_UNITS)
    for name, text in ENERGY_TEXT.items():
        group.attrs[name] = _fixed_string(text)
    for name, data in _derived_energy_arrays(fit, rest_translation).items():
        _describe(group.create_dataset(name, data=data), name, ENERGY_DATASET_ATTRIBUTES)


def _derived_energy_arrays(fit: EnergyFit, rest_translation: np.ndarray) -> dict:
    """The datasets of the energy group that restate the entry's checksummed fields."""
    xi0, A = rest_strain(np.asarray(rest_translation, dtype=float))
    out = {"rest_strain": xi0, "strain_map": A}
    bounds = fit.range
    for kind in ("pose", "load", "pressure"):
        for side in ("lower", "upper"):
            out[f"range/{kind}_{side}"] = getattr(bounds, f"{kind}_{side}")
    if bounds.limit_pressure is not None:
        out["range/limit_pressure"] = np.float64(bounds.limit_pressure)
    return {name: np.array(value, dtype="<f8") for name, value in out.items()}     # a copy, 0-d kept 0-d


def read_energy(entry_group, what: str, path: str, rest_translation: np.ndarray) -> EnergyFit:
    """Read and validate ``<entry>/energy`` (dtypes, shapes and sizes checked before reading).
    The datasets that restate other fields (``rest_strain``, ``strain_map``, ``range/``) are
    optional (files written before them read the same) and, when present, must agree with them.
    ``what`` names the file, ``path`` the entry group."""
    import h5py

    label = f"{what}: {path}"
    group = entry_group[ENERGY_GROUP]
    if not isinstance(group, h5py.Group):
        raise CatalogueError(f"{label}: '{ENERGY_GROUP}' is not a group")
    arrays = {}
    for name, dtype in _ENERGY_DATASETS.items():
        ds = group.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise CatalogueError(f"{label}: energy dataset {name!r} missing")
        kind = "iu" if dtype == "<i8" else "f"
        if ds.dtype.kind not in kind or ds.dtype.itemsize != 8 or ds.ndim > 2 \
                or any(n > MAX_TERMS for n in ds.shape):
            raise CatalogueError(f"{label}: energy dataset {name!r} has dtype {ds.dtype} and shape {ds.shape}")
        arrays[name] = np.asarray(ds[()], dtype=dtype)
    attrs = {}
    for name in _ENERGY_ATTRIBUTES:
        if name not in group.attrs:
            raise CatalogueError(f"{label}: energy attribute {name!r} missing")
        value = group.attrs[name]
        if isinstance(value, np.ndarray) and value.shape == ():
            value = value[()]
        if isinstance(value, bytes):
            if len(value) > MAX_JSON_BYTES:
                raise CatalogueError(f"{label}: energy attribute {name!r} larger than {MAX_JSON_BYTES} bytes")
            value = value.decode("utf-8", errors="strict")
        if not isinstance(value, str):
            raise CatalogueError(f"{label}: energy attribute {name!r} is not a string")
        if name == "representation":
            attrs[name] = value
            continue
        try:
            attrs[name] = json.loads(value, parse_constant=_reject_constant)
        except ValueError as error:
            raise CatalogueError(f"{label}: energy attribute {name!r}: invalid JSON ({error})") from None
    try:
        fit = EnergyFit(exponents=arrays["exponents"], coefficients=arrays["coefficients"],
                        scales=arrays["scales"], range=EnergyRange.from_dict(attrs["range"]),
                        fit_error=attrs["fit_error"], material=attrs["material"], sampling=attrs["sampling"],
                        fold_pressure=attrs["fold_pressure"], representation=attrs["representation"])
    except CatalogueError as error:
        raise CatalogueError(f"{label}: {error}") from None
    _check_derived_energy_arrays(group, fit, rest_translation, what, f"{path}/{ENERGY_GROUP}")
    return fit


def _check_derived_energy_arrays(group, fit: EnergyFit, rest_translation: np.ndarray, what: str, path: str) -> None:
    """The restating datasets present in ``group`` hold what the entry's fields give: ``range/``
    bit for bit (all six bounds, and ``limit_pressure`` exactly when the range has one);
    ``rest_strain`` and ``strain_map`` to 1e-12 of their largest element (the log of a pure
    translation is exact up to its series' last digit)."""
    bounds = h5read.child(group, "range", what, path, "group", required=False)
    stored_limit = bounds is not None and h5read.link_kind(bounds, "limit_pressure", what, f"{path}/range") is not None
    if stored_limit and fit.range.limit_pressure is None:
        raise h5read.failure(what, f"{path}/range/limit_pressure", "stored, but the range has no limit pressure")
    for name, value in _derived_energy_arrays(fit, rest_translation).items():
        in_range = name.startswith("range/")
        parent, where, leaf = (bounds, f"{path}/range", name[len("range/"):]) if in_range else (group, path, name)
        if parent is None or (not in_range and h5read.link_kind(group, name, what, path) is None):
            continue                                  # written before the restating datasets existed
        stored = h5read.read_float_dataset(parent, leaf, what, where, max_side=MAX_ARRAY_SIDE)
        tolerance = 0.0 if in_range else 1e-12 * max(1.0, float(np.abs(value).max()))
        if stored.shape != value.shape or not np.all(np.abs(stored - value) <= tolerance):
            raise h5read.failure(what, f"{path}/{name}", "disagrees with the entry's fields it restates "
                                                          f"(stored {stored.tolist()}, expected {value.tolist()})")


def differing_fields(a: SegmentEntry, b: SegmentEntry) -> list[str]:
    """Names of the content fields in which two entries differ (arrays compared bit for bit;
    timings, provenance and the wall-clock times of ``CIRCUMSTANTIAL_KEYS`` do not count)."""
    out = []
    for field in ("name", "family", "mass") + DICT_FIELDS:
        if field in CIRCUMSTANTIAL_FIELDS:
            continue
        if _content_part(field, getattr(a, field)) != _content_part(field, getattr(b, field)):
            out.append(field)
    for field in ARRAY_FIELDS:
        x, y = getattr(a, field), getattr(b, field)
        if x.shape != y.shape or x.tobytes() != y.tobytes():
            out.append(field)
    if a.energy != b.energy and not (a.energy is None and b.energy is None):
        out.append("energy")
    return out


def _close(x, y, tolerance: float) -> bool:
    """Plain data (JSON values, arrays) equal, numbers within ``tolerance`` relative to the
    largest magnitude of their array or of the pair."""
    if isinstance(x, dict) or isinstance(y, dict):
        return (isinstance(x, dict) and isinstance(y, dict) and x.keys() == y.keys()
                and all(_close(x[k], y[k], tolerance) for k in x))
    if isinstance(x, str) or isinstance(y, str) or x is None or y is None or isinstance(x, bool) \
            or isinstance(y, bool):
        return type(x) is type(y) and x == y
    try:
        a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    except (TypeError, ValueError):
        return x == y
    if a.shape != b.shape:
        return False
    if a.size == 0:
        return True
    if not (np.array_equal(np.isfinite(a), np.isfinite(b))
            and np.array_equal(a[~np.isfinite(a)], b[~np.isfinite(b)])):
        return False
    finite = np.isfinite(a)
    scale = max(float(np.max(np.abs(a[finite]), initial=0.0)), float(np.max(np.abs(b[finite]), initial=0.0)))
    return bool(np.all(np.abs(a[finite] - b[finite]) <= tolerance * scale))


def same_design(a: SegmentEntry, b: SegmentEntry, tolerance: float = SAME_DESIGN_TOLERANCE) -> list[str]:
    """The content fields in which ``a`` and ``b`` differ beyond ``tolerance`` ([] = the same
    design): text and integer fields (and the energy's exponents) exactly, every stored number
    within ``tolerance`` relative to the largest magnitude of its array or JSON list."""
    out = []
    if a.name != b.name or a.family != b.family:
        out.append("name" if a.name != b.name else "family")
    if not _close(a.mass, b.mass, tolerance):
        out.append("mass")
    for field in DICT_FIELDS:
        if field not in CIRCUMSTANTIAL_FIELDS and not _close(_content_part(field, getattr(a, field)),
                                                             _content_part(field, getattr(b, field)), tolerance):
            out.append(field)
    for field in ARRAY_FIELDS:
        if not _close(getattr(a, field), getattr(b, field), tolerance):
            out.append(field)
    ea, eb = a.energy, b.energy
    if (ea is None) != (eb is None):
        out.append("energy")
    elif ea is not None:
        if not (np.array_equal(ea.exponents, eb.exponents) and _close(ea.coefficients, eb.coefficients, tolerance)
                and _close(ea.scales, eb.scales, tolerance)
                and _close(ea.attributes(), eb.attributes(), tolerance)):
            out.append("energy")
    return out


def stamp_version(f, version: int) -> None:
    """Raise the file's ``schema_version`` to ``version`` (never lowers it)."""
    if int(np.asarray(f.attrs["schema_version"])) < version:
        f.attrs["schema_version"] = np.int64(version)


# ---------------------------------------------------------------- file level

def init_file(f) -> None:
    """Write the root attributes, an empty index and the entries group into a new file."""
    import h5py

    f.attrs["format"] = _fixed_string(FORMAT)
    f.attrs["schema_version"] = np.int64(1)      # stamped 2 by the first entry with an energy group
    _describe(f.create_dataset("index", shape=(0,), maxshape=(None,), chunks=(1024,),
                               dtype=h5py.string_dtype("utf-8")), "index")
    f.create_group("entries")


def _describe(dataset, field: str, attributes: dict = DATASET_ATTRIBUTES) -> None:
    """Attach the ``units`` and ``description`` attributes (fixed-length UTF-8) of ``field``."""
    units, description = attributes[field]
    dataset.attrs["units"] = _fixed_string(units)
    dataset.attrs["description"] = _fixed_string(description)


def _attribute_units(obj, units: dict) -> None:
    """Attach ``<name>_units`` (fixed-length UTF-8) beside each numeric attribute ``<name>``."""
    for name, unit in units.items():
        obj.attrs[f"{name}_units"] = _fixed_string(unit)


def check_file(f, what: str) -> None:
    """Refuse foreign files and schema versions this code does not know; ``/index`` and
    ``/entries`` must be a dataset and a group stored in the file itself."""
    import h5py

    try:
        has_format = h5py.h5a.exists(f.id, b"format")
    except h5read.H5_ERRORS as error:
        raise h5read.failure(what, "/", f"unreadable root attributes ({error})") from None
    if not has_format:
        raise CatalogueError(f"{what}: an HDF5 file but not a vertebra catalogue (no 'format' attribute)")
    fmt = h5read.read_string_attribute(f, "format", what, "/", 200)
    if fmt != FORMAT:
        raise CatalogueError(f"{what}: an HDF5 file but not a vertebra catalogue (format {fmt!r})")
    version = h5read.read_number_attribute(f, "schema_version", what, "/", "iu")
    if version > SCHEMA_VERSION:
        raise CatalogueError(f"{what}: catalogue schema version {version} is newer than this vertebra "
                             f"understands ({SCHEMA_VERSION}); upgrade vertebra")
    if version < 1:
        raise CatalogueError(f"{what}: invalid catalogue schema version {version}")
    for name, kind in (("entries", "group"), ("index", "dataset")):
        if h5read.link_kind(f, name, what, "/") is None:
            raise CatalogueError(f"{what}: catalogue is missing its '/entries' group or '/index' dataset")
        h5read.child(f, name, what, "/", kind)


def read_index(f, what: str) -> dict:
    """key -> index row, from the ``/index`` dataset (no entry data is read). Rows are parsed
    and checked one by one: a row is valid JSON on its own or the index is refused."""
    ds = h5read.child(f, "index", what, "/", "dataset")
    raw = h5read.read_string_rows(ds, what, "/index", max_rows=MAX_INDEX_ROWS, max_row_bytes=MAX_JSON_BYTES)
    rows = {}
    for i, text in enumerate(raw):
        row = parse_json(text, f"{what}: index row {i}")
        if not isinstance(row, dict) or not isinstance(row.get("key"), str):
            raise CatalogueError(f"{what}: index row {i} is not an entry row")
        check_key(row["key"], f"{what}: index row {i}: ")
        for field, kind in (("name", str), ("family", str), ("parameters", dict), ("content", str),
                            ("checksum", str)):
            if not isinstance(row.get(field), kind):
                raise CatalogueError(f"{what}: index row {i}: field {field!r} missing or wrong type")
        if row["key"] in rows:
            raise CatalogueError(f"{what}: index lists key {row['key']} twice")
        rows[row["key"]] = row
    return rows


def append_index(f, rows: list[dict]) -> None:
    if not rows:
        return
    ds = f["index"]
    n = ds.shape[0]
    ds.resize((n + len(rows),))
    ds[n:] = np.array([canonical_json(r) for r in rows], dtype=object)
