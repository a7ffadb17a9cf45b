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
        attrs: name, family (fixed-length UTF-8 strings), mass (float64),
               parameters, mesh, accuracy, timings, provenance (canonical JSON,
               fixed-length UTF-8 strings), checksum, content ("sha256:<hex>")
        energy/           optional (schema v2): ψ(s, p) of a nonlinear segment, see
                          ``store.energy.write_group``; covered by the checksum

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

from vertebra.store import energy as energy_schema
from vertebra.store.entry import SegmentEntry, canonical_json
from vertebra.store import h5read
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
        meta[field] = dicts[field]
    return meta


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
    for field in DICT_FIELDS:
        group.attrs[field] = _fixed_string(canonical_json(enc.dicts[field]))
    group.attrs["checksum"] = _fixed_string(enc.checksum)
    group.attrs["content"] = _fixed_string(enc.content)
    if enc.entry.energy is not None:
        energy_schema.write_group(group, enc.entry.energy)
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
    energy_group = h5read.child(group, energy_schema.GROUP, what, path, "group", required=False)
    if energy_group is not None:
        try:
            energy = energy_schema.read_group(group, f"{what}: {path}")
        except (OSError, KeyError, ValueError, TypeError, RuntimeError) as error:
            raise h5read.failure(what, f"{path}/{energy_schema.GROUP}", f"unreadable ({error})") from None
    try:
        checksum, _ = digests(key, name, family, mass, arrays, dicts, energy)
    except (ValueError, TypeError) as error:
        raise h5read.failure(what, path, f"metadata cannot be digested ({error})") from None
    if checksum != stored_checksum:
        raise CatalogueError(f"{what}: entry {key} ({name!r}): checksum mismatch — stored {stored_checksum}, "
                             f"data gives {checksum}; the entry is corrupt")
    try:
        return SegmentEntry(key=key, name=name, family=family, mass=mass, **arrays, **dicts, energy=energy)
    except CatalogueError as error:
        raise CatalogueError(f"{what}: entry {key}: {error}") from None


def differing_fields(a: SegmentEntry, b: SegmentEntry) -> list[str]:
    """Names of the fields in which two entries differ (arrays compared bit for bit)."""
    out = []
    for field in ("name", "family", "mass") + DICT_FIELDS:
        if getattr(a, field) != getattr(b, field):
            out.append(field)
    for field in ARRAY_FIELDS:
        x, y = getattr(a, field), getattr(b, field)
        if x.shape != y.shape or x.tobytes() != y.tobytes():
            out.append(field)
    if a.energy != b.energy and not (a.energy is None and b.energy is None):
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


def _describe(dataset, field: str) -> None:
    """Attach the ``units`` and ``description`` attributes (fixed-length UTF-8) of ``field``."""
    units, description = DATASET_ATTRIBUTES[field]
    dataset.attrs["units"] = _fixed_string(units)
    dataset.attrs["description"] = _fixed_string(description)


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
