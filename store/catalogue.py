"""Public catalogue API: add, look up, load, verify, merge, remove, query, export.

Readers see the published catalogue file plus the committed shards not merged yet,
so an entry is visible as soon as ``add_entry`` returns. See docs/catalogue.md for
the file layout and the concurrency design (``store.shards``).
"""

from __future__ import annotations

import io
import json
import logging
import operator
import re
from pathlib import Path

import numpy as np

from vertebra.core.energy import EnergyFit
from vertebra.store.entry import SegmentEntry, canonical_json
from vertebra.core.errors import CatalogueError
from vertebra.store import locking
from vertebra.store.h5read import walk
from vertebra.store.schema import (ARRAY_FIELDS, DICT_FIELDS, SCHEMA_VERSION, EncodedEntry, check_key, same_design,
                                   entry_group, entry_keys, parse_json, read_entry, read_index,
                                   read_stored_digests)
from vertebra.store.shards import (CONFLICT_SUFFIX, LOCK_TIMEOUT_S, Conflict, LockTimeout, MergeReport,
                                   _publish, _temp_path, _unlink_quietly, disk_error, guard_os_errors, list_shards,
                                   open_checked,
                                   problem_files, rebuild, shards_dir, write_shard)

__all__ = ["add_entry", "add_entries", "StoredKey", "has_entry", "open_catalogue", "Catalogue", "verify",
           "merge", "consolidate", "remove", "query", "export", "entry_to_dict", "entry_from_dict",
           "MergeReport", "Conflict", "LockTimeout", "LIST_FIELDS"]

log = logging.getLogger("vertebra.store")

LIST_FIELDS = ("key", "name", "family", "parameters", "n_cavities", "mass")
MIN_PREFIX = 4


# ---------------------------------------------------------------- reading

class Catalogue:
    """Read-only, lazy view of a catalogue: the index is read on open, entry data on load.

    Holds the published file open (a consistent snapshot even if a merger replaces it)
    plus the rows of committed shards that were not merged yet. Use as a context manager
    or call ``close()``.
    """

    @guard_os_errors
    def __init__(self, path):
        self.path = Path(path)
        self._file = None
        self._rows: dict[str, dict] = {}
        self._shard_of: dict[str, Path] = {}
        self.shard_problems: list[str] = []
        # Shards first, then the main file: a shard merged in between is then in the file.
        shard_rows = []
        for shard in list_shards(self.path):
            try:
                with open_checked(shard, f"shard {shard}") as f:
                    shard_rows.append((shard, read_index(f, f"shard {shard}")))
            except CatalogueError as error:
                if shard.exists():
                    self.shard_problems.append(str(error))
        if self.path.exists() or not shard_rows:
            self._file = open_checked(self.path)
            try:
                self._rows = read_index(self._file, str(self.path))
            except BaseException:
                self._file.close()
                raise
        for shard, rows in shard_rows:
            for key, row in rows.items():
                if key not in self._rows:
                    self._rows[key] = row
                    self._shard_of[key] = shard

    # context manager / lifetime
    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __len__(self):
        return len(self._rows)

    def __contains__(self, key):
        return key in self._rows

    def keys(self) -> list[str]:
        return list(self._rows)

    @property
    def pending(self) -> list[str]:
        """Keys visible only through committed shards (not merged into the file yet)."""
        return list(self._shard_of)

    def list(self) -> list[dict]:
        """One dict per entry: key, name, family, parameters, n_cavities, mass (no array read)."""
        return [{f: row.get(f) for f in LIST_FIELDS} for row in self._rows.values()]

    def row(self, key_or_name: str) -> dict:
        return dict(self._rows[self.resolve(key_or_name)])

    def resolve(self, key_or_name: str) -> str:
        """Exact key, else unique exact name, else unique key prefix (≥ 4 characters)."""
        if not isinstance(key_or_name, str) or not key_or_name:
            raise CatalogueError(f"{self.path}: entry reference must be a non-empty string")
        if key_or_name in self._rows:
            return key_or_name
        by_name = [k for k, r in self._rows.items() if r["name"] == key_or_name]
        if len(by_name) == 1:
            return by_name[0]
        if len(by_name) > 1:
            raise CatalogueError(f"{self.path}: name {key_or_name!r} is ambiguous: "
                                 f"{len(by_name)} entries ({', '.join(sorted(by_name))}); use a key")
        by_prefix = [k for k in self._rows if k.startswith(key_or_name)] \
            if len(key_or_name) >= MIN_PREFIX else []
        if len(by_prefix) == 1:
            return by_prefix[0]
        if len(by_prefix) > 1:
            raise CatalogueError(f"{self.path}: key prefix {key_or_name!r} is ambiguous: "
                                 f"{', '.join(sorted(by_prefix)[:10])}")
        raise CatalogueError(f"{self.path}: no entry with key, name or key prefix {key_or_name!r} "
                             f"({len(self._rows)} entries)")

    @guard_os_errors
    def load(self, key_or_name: str) -> SegmentEntry:
        """Read, check (checksum) and return one entry; nothing else is read."""
        key = self.resolve(key_or_name)
        shard = self._shard_of.get(key)
        if shard is not None:
            try:
                with open_checked(shard, f"shard {shard}") as f:
                    return _load_from(f, key, f"shard {shard}")
            except CatalogueError:
                if shard.exists():
                    raise
            # merged and deleted since we opened: it is in the current published file
            with open_checked(self.path) as f:
                return _load_from(f, key, str(self.path))
        return _load_from(self._file, key, str(self.path))


def _load_from(f, key: str, what: str) -> SegmentEntry:
    return read_entry(entry_group(f, key, what), key, what)


def open_catalogue(path) -> Catalogue:
    """Read-only lazy handle (also a context manager). CatalogueError if missing/foreign/corrupt."""
    return Catalogue(path)


@guard_os_errors
def has_entry(path, key: str) -> bool:
    """Whether ``key`` is in the catalogue or a committed shard. Reads no entry data."""
    check_key(key)
    path = Path(path)
    if path.exists():
        with open_checked(path) as f:
            if entry_group(f, key, str(path), required=False) is not None:
                return True
    d = shards_dir(path)
    if d.is_dir() and any(d.glob(f"{key}@*.h5")):
        return True
    for shard in list_shards(path):
        if shard.name.startswith("batch@"):
            try:
                with open_checked(shard) as f:
                    if entry_group(f, key, f"shard {shard}", required=False) is not None:
                        return True
            except CatalogueError:
                continue
    return False


# ---------------------------------------------------------------- writing

def _lookup(path: Path, keys: list[str]) -> dict:
    """key -> (content digest or its 16-hex-digit prefix, file holding it) for the keys
    already in the catalogue file or in a committed shard. Reads no entry data and opens
    no single-entry shard (their names carry key and content digest)."""
    found = {}
    if path.exists():
        with open_checked(path) as f:
            for key in keys:
                group = entry_group(f, key, str(path), required=False)
                if group is not None:
                    found[key] = (read_stored_digests(group, str(path), f"/entries/{key}")[1], path)
    for shard in reversed(list_shards(path)):          # oldest shard wins, as in the merger
        if shard.name.startswith("batch@"):
            try:
                with open_checked(shard, f"shard {shard}") as f:
                    rows = read_index(f, f"shard {shard}")
            except CatalogueError:
                continue
            hits = {k: (rows[k]["content"], shard) for k in keys if k in rows}
        else:
            key, _, digest = shard.name[: -len(".h5")].rpartition("@")
            hits = {key: ("sha256:" + digest, shard)} if key in keys else {}
        for key, hit in hits.items():
            if key not in found or found[key][1] != path:
                found[key] = hit
    return found


def _fields_against(source: Path, enc: EncodedEntry) -> list[str]:
    """The fields in which the entry stored in ``source`` is another design than ``enc``'s
    ([] = the same design within ``schema.SAME_DESIGN_TOLERANCE``)."""
    try:
        with open_checked(source) as f:
            return same_design(_load_from(f, enc.key, str(source)), enc.entry)
    except CatalogueError:
        return ["?"]


class StoredKey(str):
    """The key of an entry that ``add_entry`` stored, with how the merge went.

    ``merge_deferred`` is None when nothing is left to do, else the reason the merge into the
    catalogue file did not happen (lock not obtained, full or read-only disk, …): the entry is
    nevertheless **stored** — its shard is committed, durable and visible to readers — and the
    next merge (any writer, or ``vertebra catalogue consolidate``) picks it up.
    """

    merge_deferred: str | None

    def __new__(cls, key: str, merge_deferred: str | None = None):
        obj = super().__new__(cls, key)
        obj.merge_deferred = merge_deferred
        return obj

    def __reduce__(self):
        return (StoredKey, (str(self), self.merge_deferred))

    @property
    def status(self) -> str:
        return "stored" if self.merge_deferred is None else "stored, merge deferred"


@guard_os_errors
def add_entries(path, entries, *, consolidate: bool = True,
                timeout: float = LOCK_TIMEOUT_S) -> list[StoredKey]:
    """Add several entries in one shard (one merge): the bulk path for sweeps.

    Same semantics as ``add_entry`` for each entry. Returns their keys (:class:`StoredKey`).
    """
    path = Path(path)
    encs = [EncodedEntry(e) for e in entries]
    seen: dict[str, EncodedEntry] = {}
    for enc in encs:
        fields = same_design(seen[enc.key].entry, enc.entry) \
            if enc.key in seen and seen[enc.key].content != enc.content else []
        if fields:
            raise CatalogueError(f"{path}: two entries with key {enc.key} but different content "
                                 f"({', '.join(fields)})")
        seen[enc.key] = enc
    encs = list(seen.values())
    todo, pending_only = [], False
    known = _lookup(path, [enc.key for enc in encs])
    for enc in encs:
        found = known.get(enc.key)
        if found is None:
            todo.append(enc)
            continue
        content, source = found
        if not enc.content.startswith(content):
            fields = _fields_against(source, enc)
            if fields:
                raise CatalogueError(f"{path}: entry {enc.key} already exists with different content "
                                     f"({', '.join(fields)}); nothing written")
        pending_only |= source != path
    deferred = None
    if not todo:
        if consolidate and pending_only:
            deferred = _consolidate_quietly(path, None, timeout)
        return [StoredKey(e.key, deferred) for e in encs]
    shard = write_shard(path, todo)
    if consolidate:
        deferred = _consolidate_quietly(path, shard, timeout)
        conflict = shard.with_name(shard.name + CONFLICT_SUFFIX)
        if conflict.exists():
            keys = _conflicting_keys(path, conflict)
            _unlink_quietly(conflict)
            locking.remove_directory_if_empty(shards_dir(path))      # it may have been the last file
            raise CatalogueError(f"{path}: another process added {', '.join(keys) or 'these keys'} with "
                                 "different content at the same time; your entries with those keys were "
                                 "not stored (the others were)")
    return [StoredKey(e.key, deferred) for e in encs]


def add_entry(path, entry: SegmentEntry, *, consolidate: bool = True,
              timeout: float = LOCK_TIMEOUT_S) -> StoredKey:
    """Add one entry; returns its key (a :class:`StoredKey`). Safe with many concurrent writers.

    Idempotent for identical content (timings and provenance do not count); a key
    already present with different content raises CatalogueError and writes nothing.
    The entry is committed (durable, visible to readers) once its shard is in place; a
    failure before that (full or read-only disk, …) raises CatalogueError and leaves no file.
    With ``consolidate`` the shard is then merged into the catalogue file under the lock.
    If that merge cannot happen (lock not obtained within ``timeout``, the disk refuses the
    new file), the entry stays committed as a shard: the result says "stored, merge
    deferred" (``StoredKey.merge_deferred``), a warning is logged, and the next merge picks
    it up.
    """
    return add_entries(path, [entry], consolidate=consolidate, timeout=timeout)[0]


def _consolidate_quietly(path, shard, timeout) -> str | None:
    """Merge; on failure return why (the committed shard stays for the next merge)."""
    try:
        rebuild(path, own_shard=shard, timeout=timeout)
    except CatalogueError as error:
        log.warning("%s: entry stored, merge deferred: %s; it stays committed as a shard until the next "
                    "merge (`vertebra catalogue consolidate %s`)", path, error, path)
        return str(error)
    return None


def _conflicting_keys(path, conflict: Path) -> list[str]:
    try:
        with open_checked(conflict) as f, open_checked(path) as main:
            rows = read_index(f, str(conflict))
            main_rows = read_index(main, str(path))
            return sorted(k for k, r in rows.items() if k in main_rows and main_rows[k]["content"] != r["content"])
    except CatalogueError:
        return []


@guard_os_errors
def consolidate(path, *, timeout: float = LOCK_TIMEOUT_S) -> MergeReport:
    """Merge every committed shard into the catalogue file now."""
    return rebuild(path, timeout=timeout)


@guard_os_errors
def merge(out_path, in_paths, *, timeout: float = LOCK_TIMEOUT_S) -> MergeReport:
    """Merge catalogues into ``out_path`` (created if missing).

    Same key and same content → kept once (``skipped``); same key and different content
    → a ``Conflict`` in the report and the existing entry is kept. Every input is opened
    and checked first; a corrupt input entry aborts the merge with nothing written.
    Inputs' pending shards are merged too.
    """
    out_path = Path(out_path)
    sources: list[Path] = []
    for p in in_paths:
        p = Path(p)
        if p.resolve() == out_path.resolve():
            continue
        with Catalogue(p):                     # fail early on foreign/corrupt inputs
            pass
        if p.exists():
            sources.append(p)
        sources.extend(list_shards(p))
    if not out_path.parent.is_dir():
        raise CatalogueError(f"{out_path}: directory {out_path.parent} does not exist")
    return rebuild(out_path, sources, timeout=timeout)


@guard_os_errors
def remove(path, key: str, *, timeout: float = LOCK_TIMEOUT_S) -> str:
    """Remove one entry (key, unique name or prefix); returns the removed key."""
    path = Path(path)
    with Catalogue(path) as cat:
        key = cat.resolve(key)
    report = rebuild(path, exclude=key, timeout=timeout)
    if key not in report.removed:
        raise CatalogueError(f"{path}: entry {key} vanished before it could be removed")
    return key


# ---------------------------------------------------------------- verification

@guard_os_errors
def verify(path) -> list[str]:
    """Check schema, every entry (checksum, shapes, validity), the index and pending shards.

    Returns the problems found ([] = all good). Raises CatalogueError when the file is
    not a readable vertebra catalogue at all (missing, empty, not HDF5, foreign, newer schema).
    """
    path = Path(path)
    problems: list[str] = []
    targets = []
    if path.exists() or not list_shards(path):
        targets.append((path, str(path)))
    for shard in list_shards(path):
        targets.append((shard, f"shard {shard}"))
    for p in problem_files(path):
        problems.append(f"{p}: set aside by a merger ({p.suffix[1:]}); inspect and delete it")
    for i, (p, what) in enumerate(targets):
        try:
            f = open_checked(p, what)
        except CatalogueError as error:
            if i == 0 and p == path:
                raise
            if p.exists():
                problems.append(str(error))
            continue
        with f:
            problems.extend(_verify_file(f, what))
    return problems


def _verify_file(f, what: str) -> list[str]:
    """Problems of one open catalogue-format file: every object (links, foreign storage,
    attribute sizes), the index row by row, every entry (checksum, validity, soundness), and
    the agreement of index and entries."""
    problems = walk(f, what, skip=frozenset({"/entries"}))      # each entry is walked when it is read
    try:
        rows = read_index(f, what)
    except CatalogueError as error:
        problems.append(str(error))
        rows = None
    try:
        keys = entry_keys(f, what)
    except CatalogueError as error:
        return problems + [str(error)]
    for key in keys:
        try:
            entry = _load_from(f, key, what)
        except CatalogueError as error:
            problems.append(str(error))
            continue
        if rows is None:
            continue
        row = rows.get(key)
        if row is None:
            problems.append(f"{what}: entry {key} is missing from the index")
            continue
        encoded = EncodedEntry(entry)
        expected = encoded.index_row()
        bad = [k for k in expected if row.get(k) != expected[k]
               and not (k == "content" and row.get(k) == encoded.legacy_content())]
        if bad:
            problems.append(f"{what}: index row of {key} disagrees with the entry in {', '.join(bad)}")
    if rows is not None:
        present = set(keys)
        for key in rows:
            if key not in present:
                problems.append(f"{what}: index lists {key} but there is no such entry group")
    return list(dict.fromkeys(problems))


# ---------------------------------------------------------------- query

_OPS = {"=": operator.eq, "==": operator.eq, "!=": operator.ne, "<": operator.lt,
        "<=": operator.le, ">": operator.gt, ">=": operator.ge}
_CONDITION = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_.]*)\s*(==|!=|<=|>=|=|<|>)\s*(.*?)\s*$")
_TOP_FIELDS = ("key", "name", "family", "n_cavities", "mass")


def _parse_condition(text: str):
    m = _CONDITION.match(text)
    if not m:
        raise CatalogueError(f"query: cannot parse condition {text!r}; expected FIELD OP VALUE with "
                             "OP one of = != < <= > >=")
    field, op, raw = m.groups()
    if len(raw) >= 2 and raw[0] == raw[-1] and raw[0] in "'\"":
        value = raw[1:-1]
    elif not raw or raw[0] in "<>=!":            # 'radius>>1', 'radius>=': a mistyped operator
        raise CatalogueError(f"query: condition {text!r}: after {field!r} {op!r} expected a value, got "
                             f"{raw!r}; OP is one of = != < <= > >= (quote a value that starts with one)")
    else:
        try:
            value = json.loads(raw)
        except ValueError:
            value = raw
    if field.startswith("parameters."):
        field = field[len("parameters."):]
        top = False
    else:
        top = field in _TOP_FIELDS
    return field, top, op, value


def _field_value(row: dict, field: str, top: bool):
    if top:
        return True, row.get(field)
    params = row.get("parameters", {})
    if field in params:
        return True, params[field]
    cur = params
    for part in field.split("."):                    # nested parameters: a.b.c
        if not isinstance(cur, dict) or part not in cur:
            return False, None
        cur = cur[part]
    return True, cur


def _compare(value, op, target) -> bool:
    numeric = (int, float)
    if isinstance(value, bool) or isinstance(target, bool):
        return op in ("=", "==", "!=") and _OPS[op](value, target)
    if isinstance(value, numeric) and isinstance(target, numeric):
        return _OPS[op](value, target)
    if isinstance(value, str) and isinstance(target, str):
        return _OPS[op](value, target)
    if op in ("=", "=="):
        return False
    if op == "!=":
        return True
    return False


def query(path, where: list[str]) -> list[dict]:
    """Entries whose every condition holds (AND). Conditions: ``FIELD OP VALUE`` with OP in
    ``= != < <= > >=`` on parameters (``radius``, ``parameters.radius``, dotted for nested)
    and on ``name``, ``family``, ``key``, ``n_cavities``, ``mass``. Numbers compare
    numerically, strings lexically; an entry without the field does not match."""
    if isinstance(where, str):
        where = [where]
    conditions = [_parse_condition(w) for w in where]
    with Catalogue(path) as cat:
        rows = cat.list()
    for field, top, _, _ in conditions:
        if rows and not any(_field_value(r, field, top)[0] for r in rows):
            raise CatalogueError(f"query: no entry of {path} has a field {field!r}")
    out = []
    for row in rows:
        ok = True
        for field, top, op, target in conditions:
            present, value = _field_value(row, field, top)
            if not present or not _compare(value, op, target):
                ok = False
                break
        if ok:
            out.append(row)
    return out


# ---------------------------------------------------------------- export

def entry_to_dict(entry: SegmentEntry) -> dict:
    """JSON-ready dict of every field (arrays as nested lists; floats round-trip exactly)."""
    enc = EncodedEntry(entry)
    out = {"format": "vertebra-entry", "schema_version": SCHEMA_VERSION, "key": enc.key,
           "name": enc.name, "family": enc.family, "mass": enc.mass}
    for field in ARRAY_FIELDS:
        out[field] = enc.arrays[field].tolist()
    out.update(enc.dicts)
    out["n_cavities"] = entry.n_cavities
    if entry.energy is not None:
        out["energy"] = entry.energy.to_dict()
    out["checksum"] = enc.checksum
    return out


def entry_from_dict(data: dict) -> SegmentEntry:
    """Inverse of ``entry_to_dict`` (checks the checksum when present)."""
    try:
        kwargs = {f: data[f] for f in ("key", "name", "family", "mass") + ARRAY_FIELDS + DICT_FIELDS}
    except KeyError as error:
        raise CatalogueError(f"exported entry: field {error} missing") from None
    if data.get("energy") is not None:
        kwargs["energy"] = EnergyFit.from_dict(data["energy"])
    entry = SegmentEntry(**kwargs)
    if "checksum" in data and EncodedEntry(entry).checksum != data["checksum"]:
        raise CatalogueError(f"exported entry {entry.key}: checksum mismatch")
    return entry


def _npz_payload(entry: SegmentEntry) -> dict:
    enc = EncodedEntry(entry)
    payload = {f: enc.arrays[f] for f in ARRAY_FIELDS}
    payload["mass"] = np.float64(enc.mass)
    for name, text in (("key", enc.key), ("name", enc.name), ("family", enc.family),
                       ("checksum", enc.checksum), ("format", "vertebra-entry")):
        payload[name] = np.array(text)
    for field in DICT_FIELDS:
        payload[field + "_json"] = np.array(canonical_json(enc.dicts[field]))
    if entry.energy is not None:
        payload["energy_json"] = np.array(canonical_json(entry.energy.to_dict()))
    return payload


@guard_os_errors
def export(path, key: str, fmt: str, out=None) -> Path:
    """Write one entry as ``json`` or ``npz`` (no pickle: strings are unicode arrays) to
    ``out`` (default ``<key>.<fmt>`` in the current directory; an existing directory gets
    ``<key>.<fmt>`` inside it), atomically. Returns the path. A disk that refuses the file
    is a CatalogueError and leaves nothing behind."""
    if fmt not in ("json", "npz"):
        raise CatalogueError(f"export: format {fmt!r} unknown; use json or npz")
    with Catalogue(path) as cat:
        entry = cat.load(key)
    out = Path(out) if out is not None else Path(f"{entry.key}.{fmt}")
    if out.is_dir():
        out = out / f"{entry.key}.{fmt}"
        if out.is_dir():
            raise CatalogueError(f"export: {out} is a directory")
    if not out.parent.is_dir():
        raise CatalogueError(f"export: directory {out.parent} does not exist")
    tmp = _temp_path(out.parent, out.name)
    try:
        if fmt == "json":
            data = (json.dumps(entry_to_dict(entry), indent=1, allow_nan=False) + "\n").encode("utf-8")
        else:
            buf = io.BytesIO()
            np.savez(buf, **_npz_payload(entry))
            data = buf.getvalue()
        with open(tmp, "xb") as fh:
            fh.write(data)
        _publish(tmp, out)
    except BaseException as error:
        _unlink_quietly(tmp)
        if isinstance(error, OSError):
            raise disk_error(out, "cannot write the export", error) from None
        raise
    return out


def entry_from_npz(file) -> SegmentEntry:
    """Read an entry exported with ``export(..., "npz")`` (allow_pickle=False)."""
    with np.load(file, allow_pickle=False) as z:
        kwargs = {f: z[f] for f in ARRAY_FIELDS}
        kwargs.update(key=str(z["key"]), name=str(z["name"]), family=str(z["family"]), mass=float(z["mass"]))
        for field in DICT_FIELDS:
            kwargs[field] = parse_json(str(z[field + "_json"]), f"npz field {field}")
        if "energy_json" in z:
            kwargs["energy"] = EnergyFit.from_dict(parse_json(str(z["energy_json"]), "npz field energy"))
        checksum = str(z["checksum"])
    entry = SegmentEntry(**kwargs)
    if EncodedEntry(entry).checksum != checksum:
        raise CatalogueError(f"npz entry {entry.key}: checksum mismatch")
    return entry
