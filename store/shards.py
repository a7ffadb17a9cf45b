"""Safe concurrent writing of a catalogue: shards, one merger under a lock, atomic replace.

The catalogue file ``X.h5`` is never modified in place and never opened with mode
``'w'``. A writer puts its entries into a new shard file in ``X.h5.shards/``
(temporary name, fsync, atomic ``os.replace`` into place: from then on the entry is
*committed*). A merger holding ``filelock.FileLock("X.h5.lock")`` copies the current
catalogue into a temporary file next to it, appends the pending shards (each entry
checked against its checksum), fsyncs, and ``os.replace``s it over ``X.h5``; only
then are the merged shards deleted. A process killed at any moment leaves either a
temporary file (ignored, later cleaned) or a committed shard (merged later) and the
old or the new catalogue — both complete files.
"""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import socket
import stat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vertebra.store.errors import CatalogueError
from vertebra.store.schema import (ENERGY_SCHEMA_VERSION, EncodedEntry, append_index, check_file, differing_fields,
                          init_file, read_entry, read_index, stamp_version, write_entry)

log = logging.getLogger("vertebra.store")

LOCK_TIMEOUT_S = 600.0
SHARD_SUFFIX = ".h5"
CONFLICT_SUFFIX = ".conflict"
CORRUPT_SUFFIX = ".corrupt"
_HOST = socket.gethostname().replace("~", "-") or "host"
_ALLOWED_MODES = ("r", "r+", "x")


# ---------------------------------------------------------------- paths

def shards_dir(path) -> Path:
    return Path(str(path) + ".shards")


def lock_path(path) -> Path:
    return Path(str(path) + ".lock")


def _temp_path(directory: Path, stem: str) -> Path:
    """Hidden temporary name carrying host and pid so that stale ones can be cleaned."""
    return directory / f".{stem}~{_HOST}~{os.getpid()}~{secrets.token_hex(4)}.tmp"


def _stale_temps(directory: Path):
    """Temporary files in ``directory`` left by dead processes of this host."""
    if not directory.is_dir():
        return
    for p in directory.glob(".*~*~*~*.tmp"):
        parts = p.name[:-len(".tmp")].rsplit("~", 3)
        if len(parts) != 4 or parts[1] != _HOST:
            continue
        try:
            os.kill(int(parts[2]), 0)
        except ProcessLookupError:
            yield p
        except (ValueError, PermissionError, OSError):
            continue


def list_shards(path) -> list[Path]:
    """Committed shards of catalogue ``path``, oldest first (the order they are merged in)."""
    d = shards_dir(path)
    if not d.is_dir():
        return []
    found = []
    for p in d.glob("*" + SHARD_SUFFIX):
        if p.name.startswith("."):
            continue
        try:
            found.append((p.stat().st_mtime_ns, p.name, p))
        except FileNotFoundError:       # merged meanwhile
            continue
    return [p for _, _, p in sorted(found)]


def problem_files(path) -> list[Path]:
    """Shards set aside by a merger (conflicting or corrupt): they need a human."""
    d = shards_dir(path)
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if p.name.endswith((CONFLICT_SUFFIX, CORRUPT_SUFFIX)))


# ---------------------------------------------------------------- HDF5 and file helpers

def hdf5_locking():
    """HDF5 file-locking setting for h5py (``VERTEBRA_HDF5_LOCKING`` = true|false|best-effort).

    Unset means h5py's default, which honours ``HDF5_USE_FILE_LOCKING``. Catalogue files
    are immutable once published, so ``false`` is safe on filesystems without locks.
    """
    value = os.environ.get("VERTEBRA_HDF5_LOCKING", "").strip().lower()
    return {"": None, "true": True, "1": True, "false": False, "0": False,
            "best-effort": "best-effort"}.get(value)


def h5open(path, mode: str):
    import h5py

    if mode not in _ALLOWED_MODES:     # never 'w': it truncates a file someone may be reading
        raise ValueError(f"catalogue files are opened with {_ALLOWED_MODES}, not {mode!r}")
    locking = hdf5_locking()
    if locking is None:
        return h5py.File(path, mode)
    return h5py.File(path, mode, locking=locking)


def open_checked(path, what: str | None = None):
    """Open a catalogue-format file read-only; every failure becomes a clear CatalogueError."""
    import h5py

    p = Path(path)
    what = what or str(p)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise CatalogueError(f"{what}: no such catalogue file") from None
    if not stat.S_ISREG(st.st_mode):
        raise CatalogueError(f"{what}: not a regular file")
    if st.st_size == 0:
        raise CatalogueError(f"{what}: empty file (0 bytes) — not a catalogue (an interrupted or "
                             "truncating write?)")
    try:
        is_hdf5 = h5py.is_hdf5(str(p))
    except OSError as error:
        raise CatalogueError(f"{what}: unreadable ({error})") from None
    if not is_hdf5:
        raise CatalogueError(f"{what}: not an HDF5 file (no HDF5 signature)")
    try:
        f = h5open(p, "r")
    except OSError as error:
        raise CatalogueError(f"{what}: unreadable HDF5 file (truncated or corrupt): {error}") from None
    try:
        check_file(f, what)
    except CatalogueError:
        f.close()
        raise
    except (OSError, KeyError, ValueError) as error:
        f.close()
        raise CatalogueError(f"{what}: corrupt catalogue structure ({error})") from None
    return f


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _copy_exclusive(src: Path, dst: Path) -> None:
    """Byte copy into a new file (O_EXCL: never truncates anything)."""
    with open(src, "rb") as fin:
        fd = os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            size = os.fstat(fin.fileno()).st_size
            offset = 0
            while offset < size:
                sent = os.sendfile(fd, fin.fileno(), offset, size - offset)
                if sent == 0:
                    raise CatalogueError(f"{src}: file shrank while being copied")
                offset += sent
        finally:
            os.close(fd)


def _publish(tmp: Path, final: Path, mode_from: Path | None = None) -> None:
    """fsync ``tmp``, atomically rename it to ``final``, fsync the directory."""
    if mode_from is not None:
        try:
            os.chmod(tmp, stat.S_IMODE(mode_from.stat().st_mode))
        except OSError:
            pass
    _fsync_path(tmp)
    os.replace(tmp, final)
    _fsync_path(final.parent, directory=True)


def _unlink_quietly(p: Path) -> None:
    try:
        p.unlink()
    except FileNotFoundError:
        pass


def catalogue_lock(path, timeout: float = LOCK_TIMEOUT_S):
    """The merger lock, a separate file ``<catalogue>.lock`` (``filelock``).

    ``VERTEBRA_CATALOGUE_LOCK=soft`` switches to ``SoftFileLock`` (existence of the lock
    file) for filesystems where ``fcntl`` locks do not work; a crashed merger then leaves
    the lock file behind and it must be deleted by hand.
    """
    import filelock

    kind = os.environ.get("VERTEBRA_CATALOGUE_LOCK", "").strip().lower()
    cls = filelock.SoftFileLock if kind == "soft" else filelock.FileLock
    return cls(str(lock_path(path)), timeout=timeout)


# ---------------------------------------------------------------- writing shards

def _shard_name(encs: list[EncodedEntry]) -> str:
    if len(encs) == 1:
        return f"{encs[0].key}@{encs[0].content.split(':')[1][:16]}{SHARD_SUFFIX}"
    h = hashlib.sha256()
    for enc in sorted(encs, key=lambda e: e.key):
        h.update(f"{enc.key}={enc.content};".encode())
    return f"batch@{h.hexdigest()[:16]}{SHARD_SUFFIX}"


def write_shard(path, encs: list[EncodedEntry]) -> Path:
    """Commit ``encs`` as one shard file next to catalogue ``path``; returns its path.

    Same content gives the same shard name, so repeating a commit is harmless.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise CatalogueError(f"{path}: directory {path.parent} does not exist")
    d = shards_dir(path)
    d.mkdir(exist_ok=True)
    final = d / _shard_name(encs)
    tmp = _temp_path(d, "shard")
    try:
        with h5open(tmp, "x") as f:
            init_file(f)
            for enc in encs:
                write_entry(f["entries"], enc)
            append_index(f, [enc.index_row() for enc in encs])
        _publish(tmp, final)
    except BaseException:
        _unlink_quietly(tmp)
        raise
    return final


# ---------------------------------------------------------------- merging

@dataclass
class Conflict:
    key: str
    source: str
    fields: list[str]

    def __str__(self):
        return f"{self.key} from {self.source}: differs in {', '.join(self.fields) or '?'}"


@dataclass
class MergeReport:
    """What a merge did: keys added, keys skipped as identical content, conflicts left out."""

    added: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    conflicts: list[Conflict] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)     # corrupt pending shards set aside
    removed: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"added": self.added, "skipped_identical": self.skipped,
                "conflicts": [{"key": c.key, "source": c.source, "fields": c.fields} for c in self.conflicts],
                "rejected": self.rejected, "removed": self.removed}


def _conflict_fields(f, src, key, what_new) -> list[str]:
    try:
        old = read_entry(f["entries"][key], key, "catalogue")
        new = read_entry(src["entries"][key], key, what_new)
        return differing_fields(old, new) or ["timings/provenance only"]
    except (CatalogueError, KeyError) as error:
        return [f"unreadable: {error}"]


def _take(f, rows, new_rows, src, src_path, what, report, *, exclude) -> bool:
    """Merge the entries of one open source into ``f``. Returns False if it conflicted."""
    clean = True
    for key, src_row in read_index(src, what).items():
        if key == exclude:
            report.removed.append(key)
            continue
        if key in rows and rows[key]["content"] == src_row["content"]:
            report.skipped.append(key)          # same content already here: nothing to read or write
            continue
        if key not in src["entries"]:
            raise CatalogueError(f"{what}: index lists {key} but the entry group is missing")
        entry = read_entry(src["entries"][key], key, what)       # checksum-checked before copying
        row = EncodedEntry(entry).index_row()
        if key in rows:
            if rows[key]["content"] == row["content"]:
                report.skipped.append(key)
            else:
                report.conflicts.append(Conflict(key, str(src_path), _conflict_fields(f, src, key, what)))
                clean = False
            continue
        f.copy(src["entries"][key], f["entries"], name=key)
        if entry.energy is not None:
            stamp_version(f, ENERGY_SCHEMA_VERSION)
        rows[key] = row
        new_rows.append(row)
        report.added.append(key)
    return clean


def rebuild(path, inputs=(), *, exclude: str | None = None, own_shard: Path | None = None,
            timeout: float = LOCK_TIMEOUT_S) -> MergeReport | None:
    """The merger: new catalogue = current catalogue + pending shards + ``inputs``.

    Runs under the catalogue lock, writes a new file, replaces the old one atomically,
    then deletes the merged shards (conflicting shards are renamed ``*.conflict``, corrupt
    ones ``*.corrupt``). ``exclude`` drops one key (the rebuild then copies entry by
    entry instead of copying the file, so the removed data really goes). With
    ``own_shard``, returns None at once if that shard was already merged by another
    process. Raises ``filelock.Timeout`` if the lock is not obtained in ``timeout``.
    """
    path = Path(path)
    with catalogue_lock(path, timeout):
        if own_shard is not None and not own_shard.exists():
            return None
        for stale in list(_stale_temps(path.parent)) + list(_stale_temps(shards_dir(path))):
            _unlink_quietly(stale)
        shards = list_shards(path)
        inputs = [Path(p) for p in inputs]
        if not shards and not inputs and exclude is None and path.exists():
            return MergeReport()
        report = MergeReport()
        tmp = _temp_path(path.parent, path.name)
        merged, conflicted, corrupt = [], [], []
        try:
            if path.exists() and exclude is None:
                src = open_checked(path)          # refuse to build on a foreign/corrupt file
                src.close()
                _copy_exclusive(path, tmp)
                f = h5open(tmp, "r+")
            else:
                f = h5open(tmp, "x")
                init_file(f)
            with f:
                rows = read_index(f, str(path)) if exclude is None or not path.exists() else {}
                new_rows: list[dict] = []
                if exclude is not None and path.exists():
                    with open_checked(path) as old:
                        stamp_version(f, int(np.asarray(old.attrs["schema_version"])))
                        old_rows = read_index(old, str(path))
                        for key, row in old_rows.items():
                            if key == exclude:
                                report.removed.append(key)
                                continue
                            f.copy(old["entries"][key], f["entries"], name=key)
                            rows[key] = row
                            new_rows.append(row)
                for shard in shards:
                    try:
                        src = open_checked(shard, f"shard {shard}")
                    except CatalogueError as error:
                        if not shard.exists():            # cannot happen under the lock; be safe
                            continue
                        corrupt.append(shard)
                        report.rejected.append(str(error))
                        continue
                    with src:
                        mark = (len(rows), len(new_rows), len(report.added))
                        try:
                            ok = _take(f, rows, new_rows, src, shard, f"shard {shard}", report,
                                       exclude=exclude)
                        except CatalogueError as error:
                            # undo this shard's additions, set it aside
                            for key in report.added[mark[2]:]:
                                del f["entries"][key]
                                del rows[key]
                            del new_rows[mark[1]:]
                            del report.added[mark[2]:]
                            corrupt.append(shard)
                            report.rejected.append(str(error))
                            continue
                    (merged if ok else conflicted).append(shard)
                for inp in inputs:
                    with open_checked(inp) as src:
                        _take(f, rows, new_rows, src, inp, str(inp), report, exclude=exclude)
                append_index(f, new_rows)
            _publish(tmp, path, mode_from=path if path.exists() else None)
        except BaseException:
            _unlink_quietly(tmp)
            raise
        for shard in merged:
            _unlink_quietly(shard)
        for shard in conflicted:
            os.replace(shard, shard.with_name(shard.name + CONFLICT_SUFFIX))
        for shard in corrupt:
            os.replace(shard, shard.with_name(shard.name + CORRUPT_SUFFIX))
        if shards:
            _fsync_path(shards_dir(path), directory=True)
        return report
