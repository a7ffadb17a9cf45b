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
from vertebra.store.errors import CatalogueError

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
MAX_ARRAY_SIDE = 4096          # 6+n cavities; a larger compliance is not a segment

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

    def reject(constant):
        raise ValueError(f"{constant} is not allowed")

    try:
        return json.loads(text, parse_constant=reject)
    except (ValueError, RecursionError) as error:
        raise CatalogueError(f"{what}: invalid JSON ({error})") from None


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


def _read_string_attr(group, name: str, what: str, limit: int) -> str:
    """Read a scalar string attribute, checking its stored size before reading it."""
    import h5py

    try:
        attr_id = h5py.h5a.open(group.id, name.encode())
    except (KeyError, OSError, ValueError):
        raise CatalogueError(f"{what}: attribute {name!r} missing") from None
    size = attr_id.get_storage_size()
    if size > limit:
        raise CatalogueError(f"{what}: attribute {name!r} is {size} bytes > limit {limit}")
    dtype = attr_id.dtype
    if attr_id.shape != ():
        raise CatalogueError(f"{what}: attribute {name!r} is not a scalar")
    if dtype.kind == "S":                       # fixed-length: what vertebra writes
        buf = np.empty((), dtype=dtype)
        attr_id.read(buf)
        value = buf[()]
    else:                                       # e.g. a variable-length string from another tool
        value = group.attrs[name]
        if isinstance(value, np.ndarray) and value.shape == ():
            value = value[()]
        if isinstance(value, (str, bytes)) and len(value) > limit:
            raise CatalogueError(f"{what}: attribute {name!r} longer than limit {limit}")
    if isinstance(value, bytes):
        try:
            return value.decode("utf-8")
        except UnicodeDecodeError:
            raise CatalogueError(f"{what}: attribute {name!r} is not UTF-8") from None
    if isinstance(value, str):
        return value
    raise CatalogueError(f"{what}: attribute {name!r} is not a string")


def _read_float_array(group, field: str, what: str) -> np.ndarray:
    import h5py

    try:
        did = h5py.h5d.open(group.id, field.encode())
    except (KeyError, OSError, ValueError):
        raise CatalogueError(f"{what}: dataset {field!r} missing") from None
    dtype, shape = did.dtype, did.shape
    if dtype not in (np.dtype("<f8"), np.dtype(">f8")):
        raise CatalogueError(f"{what}: dataset {field!r} has dtype {dtype}, expected float64")
    if len(shape) > 2 or any(s > MAX_ARRAY_SIDE for s in shape):
        raise CatalogueError(f"{what}: dataset {field!r} has shape {shape}")
    arr = np.empty(shape, dtype="<f8")
    if arr.size:
        did.read(h5py.h5s.ALL, h5py.h5s.ALL, arr)
    return arr


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


def read_stored_digests(group, what: str) -> tuple[str, str]:
    return (_read_string_attr(group, "checksum", what, 200), _read_string_attr(group, "content", what, 200))


def read_entry(group, key: str, what: str) -> SegmentEntry:
    """Read and check one entry group: shapes, dtypes, JSON, validation, checksum."""
    import h5py

    check_key(key, f"{what}: ")
    if not isinstance(group, h5py.Group):
        raise CatalogueError(f"{what}: entry {key} is not a group")
    try:
        arrays = {field: _read_float_array(group, field, f"{what}: entry {key}") for field in ARRAY_FIELDS}
        name = _read_string_attr(group, "name", f"{what}: entry {key}", 4 * MAX_TEXT_CHARS)
        family = _read_string_attr(group, "family", f"{what}: entry {key}", 4 * MAX_TEXT_CHARS)
        try:
            mass_id = h5py.h5a.open(group.id, b"mass")
        except (KeyError, OSError, ValueError):
            raise CatalogueError(f"{what}: entry {key}: attribute 'mass' missing") from None
        if mass_id.shape != () or mass_id.dtype.kind != "f":
            raise CatalogueError(f"{what}: entry {key}: attribute 'mass' is not a float scalar")
        mass_buf = np.empty((), dtype="<f8")
        mass_id.read(mass_buf)
        mass = float(mass_buf)
        dicts = {}
        for field in DICT_FIELDS:
            text = _read_string_attr(group, field, f"{what}: entry {key}", MAX_JSON_BYTES)
            value = parse_json(text, f"{what}: entry {key}: attribute {field!r}")
            if not isinstance(value, dict):
                raise CatalogueError(f"{what}: entry {key}: attribute {field!r} is not a JSON object")
            dicts[field] = value
        stored_checksum, _ = read_stored_digests(group, f"{what}: entry {key}")
        energy = energy_schema.read_group(group, f"{what}: entry {key}") if energy_schema.GROUP in group else None
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as error:
        raise CatalogueError(f"{what}: entry {key}: unreadable ({error})") from None
    checksum, _ = digests(key, name, family, mass, arrays, dicts, energy)
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
    """Refuse foreign files and schema versions this code does not know."""
    if "format" not in f.attrs:
        raise CatalogueError(f"{what}: an HDF5 file but not a vertebra catalogue (no 'format' attribute)")
    fmt = _read_string_attr(f, "format", what, 200)
    if fmt != FORMAT:
        raise CatalogueError(f"{what}: an HDF5 file but not a vertebra catalogue (format {fmt!r})")
    if "schema_version" not in f.attrs:
        raise CatalogueError(f"{what}: schema_version attribute missing")
    version = np.asarray(f.attrs["schema_version"])
    if version.shape != () or version.dtype.kind not in "iu":
        raise CatalogueError(f"{what}: schema_version is not an integer")
    version = int(version)
    if version > SCHEMA_VERSION:
        raise CatalogueError(f"{what}: catalogue schema version {version} is newer than this vertebra "
                             f"understands ({SCHEMA_VERSION}); upgrade vertebra")
    if version < 1:
        raise CatalogueError(f"{what}: invalid catalogue schema version {version}")
    if "entries" not in f or "index" not in f:
        raise CatalogueError(f"{what}: catalogue is missing its '/entries' group or '/index' dataset")


def read_index(f, what: str) -> dict:
    """key -> index row, from the ``/index`` dataset (no entry data is read)."""
    import h5py

    ds = f["index"]
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 1 or ds.dtype.kind != "O":
        raise CatalogueError(f"{what}: '/index' is not a 1-D string dataset")
    try:
        texts = ds.asstr()[()] if ds.shape[0] else []
    except (OSError, ValueError, UnicodeDecodeError) as error:
        raise CatalogueError(f"{what}: '/index' unreadable ({error})") from None
    parsed = None
    if all(len(t) <= MAX_JSON_BYTES for t in texts):
        try:        # one C-level parse of all rows; per-row parsing below only on trouble
            parsed = parse_json("[" + ",".join(texts) + "]", f"{what}: index", limit=1 << 62)
        except CatalogueError:
            parsed = None
        if not isinstance(parsed, list) or len(parsed) != len(texts):
            parsed = None
    rows = {}
    for i, text in enumerate(texts):
        row = parsed[i] if parsed is not None else parse_json(text, f"{what}: index row {i}")
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
