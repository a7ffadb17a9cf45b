"""Safe concurrent writing of a catalogue: shards, one merger under a lock, atomic replace.

The catalogue file ``X.h5`` is never modified in place and never opened with mode
``'w'``. A writer puts its entries into a new shard file in ``X.h5.shards/``
(temporary name, fsync, atomic ``os.replace`` into place: from then on the entry is
*committed*). A merger holding the lock ``X.h5.shards/.lock`` (:mod:`.locking`) reads the current
catalogue into memory, appends the pending shards there (each entry checked — checksum,
links, soundness — before it is copied), writes the result into a temporary file next to
it, fsyncs, and ``os.replace``s it over ``X.h5``; only then are the merged shards deleted.
A process killed at any moment leaves either a temporary file (ignored, later cleaned) or
a committed shard (merged later) and the old or the new catalogue — both complete files.
When the lock is released the lock file goes, and the shards directory too if it is empty:
a catalogue with nothing pending is one file.

Files are built in memory (HDF5 core driver) and reach the disk through plain writes: a
full, read-only or forbidden disk fails one ``write`` with a clean OSError, mapped to a
one-line CatalogueError, and the temporary file is removed.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import logging
import os
import secrets
import socket
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vertebra.core.errors import CatalogueError
from vertebra.store import locking
from vertebra.store.h5read import H5_ERRORS
from vertebra.store.schema import (ENERGY_SCHEMA_VERSION, EncodedEntry, append_index, check_file, differing_fields, same_design,
                                   entry_group, init_file, read_entry, read_index, stamp_version, write_entry)

log = logging.getLogger("vertebra.store")

LOCK_TIMEOUT_S = 600.0
LOCK_FIRST_REPORT_S = 2.0       # a wait for the merger lock is reported after this long …
LOCK_REPORT_EVERY_S = 15.0      # … and again at this interval until it is obtained or given up
SHARD_SUFFIX = ".h5"
LOCK_NAME = ".lock"
CONFLICT_SUFFIX = ".conflict"
CORRUPT_SUFFIX = ".corrupt"
_HOST = socket.gethostname().replace("~", "-") or "host"
_ALLOWED_MODES = ("r", "r+", "x")


class LockTimeout(CatalogueError):
    """The merger lock of a catalogue was not obtained in time."""


def disk_error(path, action: str, error: BaseException) -> CatalogueError:
    """One-line CatalogueError for a failed file operation (full disk, read-only filesystem,
    permission denied, a directory where a file is expected, …)."""
    if isinstance(error, CatalogueError):
        return error
    if isinstance(error, OSError) and error.errno is not None:
        reason = f"{error.strerror or os.strerror(error.errno)} ({errno.errorcode.get(error.errno, error.errno)})"
    else:                           # h5py reports HDF5's message (it names the system error)
        reason = " ".join(str(error).split()) or type(error).__name__
    return CatalogueError(f"{path}: {action}: {reason}")


def guard_os_errors(fn):
    """Decorator for the public store API: an OSError that escapes (a directory that cannot be
    searched, a file vanishing, …) becomes a one-line CatalogueError naming the file."""
    @functools.wraps(fn)
    def guarded(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except OSError as error:
            raise disk_error(error.filename or "catalogue", "cannot access", error) from None
    return guarded


# ---------------------------------------------------------------- paths

def shards_dir(path) -> Path:
    return Path(str(path) + ".shards")


def lock_path(path) -> Path:
    """The merger lock's file, inside the shards directory (both removed when a merge ends)."""
    return shards_dir(path) / LOCK_NAME


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
    if not os.access(p, os.R_OK):
        raise CatalogueError(f"{what}: not readable (permission denied)")
    try:
        is_hdf5 = h5py.is_hdf5(str(p))
    except H5_ERRORS as error:
        raise CatalogueError(f"{what}: unreadable ({' '.join(str(error).split())})") from None
    if not is_hdf5:
        raise CatalogueError(f"{what}: not an HDF5 file (no HDF5 signature)")
    try:
        f = h5open(p, "r")
    except H5_ERRORS as error:
        raise CatalogueError(f"{what}: unreadable HDF5 file (truncated or corrupt): "
                             f"{' '.join(str(error).split())}") from None
    try:
        check_file(f, what)
    except BaseException as error:
        _close_quietly(f)
        if isinstance(error, H5_ERRORS):
            raise CatalogueError(f"{what}: corrupt catalogue structure ({' '.join(str(error).split())})") from None
        raise
    return f


def _close_quietly(f) -> None:
    try:
        f.close()
    except H5_ERRORS:
        pass


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def memory_file(image: bytes | None, label: str):
    """An HDF5 file held in memory (core driver, no backing store): new, or opened read-write
    from the bytes ``image`` of a file. Catalogue files are built this way and written with
    :func:`write_new`, so a full or read-only disk fails a plain ``write`` (a clean OSError,
    nothing half-flushed inside HDF5) and the temporary file is simply removed."""
    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_fapl_core(backing_store=False)
    name = f"memory:{label}:{secrets.token_hex(4)}".encode()
    if image is None:
        return h5py.File(h5py.h5f.create(name, h5py.h5f.ACC_EXCL, fapl=fapl))
    fapl.set_file_image(image)
    return h5py.File(h5py.h5f.open(name, h5py.h5f.ACC_RDWR, fapl))


def file_image(f) -> bytes:
    """The bytes of an in-memory HDF5 file (after a flush: a complete file)."""
    f.flush()
    return f.id.get_file_image()


def read_bytes(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as error:
        raise disk_error(path, "cannot read", error) from None


def write_new(path: Path, data: bytes) -> None:
    """Write ``data`` into a NEW file (O_EXCL: never truncates anything)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
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
    """Remove a file if it is there; a failure (read-only filesystem …) is logged, not raised:
    callers clean up after an error that matters more."""
    try:
        p.unlink()
    except FileNotFoundError:
        pass
    except OSError as error:
        log.warning("%s: could not remove (%s)", p, error.strerror or error)


@contextlib.contextmanager
def catalogue_lock(path, timeout: float = LOCK_TIMEOUT_S):
    """Hold the merger lock: ``<catalogue>.shards/.lock`` (:mod:`vertebra.store.locking`).

    The lock file and, when it is empty, the shards directory are removed on release, so a
    catalogue with nothing pending has nothing beside it. A wait is reported (logging,
    warning level: stderr by default) after ``LOCK_FIRST_REPORT_S`` and every
    ``LOCK_REPORT_EVERY_S``, naming the lock and what is known of its holder; after
    ``timeout`` seconds :class:`LockTimeout` says what to do. A lock file that cannot be
    created (read-only filesystem, permissions) is a CatalogueError at once.

    ``VERTEBRA_CATALOGUE_LOCK=soft`` switches to a lock by the file's existence for
    filesystems where ``flock`` does not work across machines; a merger killed while holding
    it leaves the lock file behind and it must be deleted by hand.
    """
    lock_file = lock_path(path)
    how = locking.mechanism()
    start = time.monotonic()
    report_at = start + LOCK_FIRST_REPORT_S
    while True:
        try:
            held = locking.acquire(lock_file, min(start + timeout, report_at), tidy_dir=True, how=how)
        except NotADirectoryError:
            raise _not_a_directory(path) from None
        except FileNotFoundError as error:
            if not Path(path).parent.is_dir():
                raise disk_error(path, f"its directory {Path(path).parent} does not exist", error) from None
            raise disk_error(lock_file, "cannot create the catalogue lock file", error) from None
        except OSError as error:
            raise disk_error(lock_file, "cannot create the catalogue lock file", error) from None
        if held is not None:
            break
        now = time.monotonic()
        waited = now - start
        if waited >= timeout:
            raise LockTimeout(
                f"{lock_file}: catalogue lock not obtained within {timeout:.0f} s "
                f"({locking.holder(lock_file, how)}); if no merger is running"
                + (", the soft lock file is stale: delete it" if how == "soft" else ", try again")) from None
        log.warning("%s: waiting %.0f s for the catalogue lock %s (%s); giving up after %.0f s",
                    path, waited, lock_file, locking.holder(lock_file, how), timeout)
        report_at = now + LOCK_REPORT_EVERY_S
    try:
        yield held
    finally:
        locking.release(held, tidy_dir=True)


# ---------------------------------------------------------------- writing shards

def _shard_name(encs: list[EncodedEntry]) -> str:
    if len(encs) == 1:
        return f"{encs[0].key}@{encs[0].content.split(':')[1][:16]}{SHARD_SUFFIX}"
    h = hashlib.sha256()
    for enc in sorted(encs, key=lambda e: e.key):
        h.update(f"{enc.key}={enc.content};".encode())
    return f"batch@{h.hexdigest()[:16]}{SHARD_SUFFIX}"


#: times a writer recreates the shards directory that a releasing merger removed meanwhile
_DIRECTORY_ATTEMPTS = 100


def _not_a_directory(path) -> CatalogueError:
    return CatalogueError(f"{shards_dir(path)}: exists but is not a directory (the shards and the merger "
                          f"lock of {path} go there)")


def _shards_directory(path: Path) -> Path:
    """Create ``<catalogue>.shards/`` (the merger lock's release removes it when empty)."""
    d = shards_dir(path)
    try:
        locking.make_directory(d)
    except OSError as error:
        raise disk_error(d, "cannot create the shards directory", error) from None
    return d


def write_shard(path, encs: list[EncodedEntry]) -> Path:
    """Commit ``encs`` as one shard file next to catalogue ``path``; returns its path.

    Same content gives the same shard name, so repeating a commit is harmless. A failed
    write (full disk, read-only filesystem, …) leaves no file behind and raises CatalogueError.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise CatalogueError(f"{path}: directory {path.parent} does not exist")
    d = shards_dir(path)
    final = d / _shard_name(encs)
    try:
        with memory_file(None, final.name) as f:
            init_file(f)
            for enc in encs:
                write_entry(f["entries"], enc)
            append_index(f, [enc.index_row() for enc in encs])
            image = file_image(f)
    except H5_ERRORS as error:
        raise disk_error(final, "cannot build the shard in memory", error) from None
    tmp = _temp_path(d, "shard")
    try:
        for attempt in range(_DIRECTORY_ATTEMPTS):
            _shards_directory(path)
            try:
                write_new(tmp, image)
                break
            except NotADirectoryError:
                raise _not_a_directory(path) from None
            except FileNotFoundError:       # a merger removed the empty directory meanwhile: again
                if attempt == _DIRECTORY_ATTEMPTS - 1:
                    raise
        _publish(tmp, final)
    except BaseException as error:
        _unlink_quietly(tmp)
        if isinstance(error, OSError):
            raise disk_error(final, "cannot write the shard", error) from None
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
        old = read_entry(entry_group(f, key, "catalogue"), key, "catalogue")
        new = read_entry(entry_group(src, key, what_new), key, what_new)
        return same_design(old, new) or differing_fields(old, new) or ["timings/provenance only"]
    except CatalogueError as error:
        return [f"unreadable: {error}"]


def _same_design_as(f, key, entry) -> bool:
    """Whether the catalogue's entry ``key`` is ``entry``'s design within the stored numbers'
    tolerance (``schema.same_design``): concurrent designs of one key, nonlinear fits differing
    in their last bits, are one entry, not a conflict."""
    try:
        return not same_design(read_entry(entry_group(f, key, "catalogue"), key, "catalogue"), entry)
    except CatalogueError:
        return False


def _copy_entry(f, src, key, what) -> None:
    try:
        f.copy(entry_group(src, key, what), f["entries"], name=key)
    except H5_ERRORS as error:
        raise CatalogueError(f"{what}: /entries/{key}: cannot be copied ({' '.join(str(error).split())})") from None


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
        entry = read_entry(entry_group(src, key, what), key, what)     # checked before copying
        row = EncodedEntry(entry).index_row()
        if key in rows:
            if rows[key]["content"] == row["content"] or _same_design_as(f, key, entry):
                report.skipped.append(key)
            else:
                report.conflicts.append(Conflict(key, str(src_path), _conflict_fields(f, src, key, what)))
                clean = False
            continue
        _copy_entry(f, src, key, what)
        if entry.energy is not None:
            stamp_version(f, ENERGY_SCHEMA_VERSION)
        rows[key] = row
        new_rows.append(row)
        report.added.append(key)
    return clean


@guard_os_errors
def rebuild(path, inputs=(), *, exclude: str | None = None, own_shard: Path | None = None,
            timeout: float = LOCK_TIMEOUT_S) -> MergeReport | None:
    """The merger: new catalogue = current catalogue + pending shards + ``inputs``.

    Runs under the catalogue lock, writes a new file, replaces the old one atomically,
    then deletes the merged shards (conflicting shards are renamed ``*.conflict``, corrupt
    ones ``*.corrupt``). ``exclude`` drops one key (the rebuild then copies entry by
    entry instead of copying the file, so the removed data really goes). With
    ``own_shard``, returns None at once if that shard was already merged by another
    process. Raises :class:`LockTimeout` if the lock is not obtained in ``timeout``, and a
    CatalogueError naming the file when the disk refuses the new file (full, read-only, no
    permission): the temporary file is removed and nothing committed is touched.
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
            image = _build(path, shards, inputs, exclude, report, merged, conflicted, corrupt)
        except H5_ERRORS as error:
            raise disk_error(path, "cannot build the merged catalogue in memory", error) from None
        try:
            write_new(tmp, image)
            _publish(tmp, path, mode_from=path if path.exists() else None)
        except BaseException as error:
            _unlink_quietly(tmp)
            if isinstance(error, OSError):
                raise disk_error(path, "cannot write the merged catalogue", error) from None
            raise
        _settle(path, shards, merged, conflicted, corrupt)
        return report


def _build(path, shards, inputs, exclude, report, merged, conflicted, corrupt) -> bytes:
    """The merged catalogue, built in memory (see :func:`rebuild`); returns its bytes."""
    if path.exists() and exclude is None:
        src = open_checked(path)          # refuse to build on a foreign/corrupt file
        src.close()
        f = memory_file(read_bytes(path), path.name)
    else:
        f = memory_file(None, path.name)
        init_file(f)
    with f:
        rows = read_index(f, str(path)) if exclude is None or not path.exists() else {}
        new_rows: list[dict] = []
        if exclude is not None and path.exists():
            with open_checked(path) as old:
                stamp_version(f, int(np.asarray(old.attrs["schema_version"])))
                for key, row in read_index(old, str(path)).items():
                    if key == exclude:
                        report.removed.append(key)
                        continue
                    _copy_entry(f, old, key, str(path))
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
                mark = (len(new_rows), len(report.added))
                try:
                    ok = _take(f, rows, new_rows, src, shard, f"shard {shard}", report, exclude=exclude)
                except CatalogueError as error:
                    # undo this shard's additions, set it aside
                    for key in report.added[mark[1]:]:
                        del f["entries"][key]
                        del rows[key]
                    del new_rows[mark[0]:]
                    del report.added[mark[1]:]
                    corrupt.append(shard)
                    report.rejected.append(str(error))
                    continue
            (merged if ok else conflicted).append(shard)
        for inp in inputs:
            with open_checked(inp) as src:
                _take(f, rows, new_rows, src, inp, str(inp), report, exclude=exclude)
        append_index(f, new_rows)
        return file_image(f)


def _settle(path, shards, merged, conflicted, corrupt) -> None:
    """After the new catalogue is published: delete merged shards, set problem shards aside.
    A failure here loses nothing (a merged shard left behind is skipped as identical by the
    next merge), so it is logged, not raised."""
    try:
        for shard in merged:
            _unlink_quietly(shard)
        for shard in conflicted:
            os.replace(shard, shard.with_name(shard.name + CONFLICT_SUFFIX))
        for shard in corrupt:
            os.replace(shard, shard.with_name(shard.name + CORRUPT_SUFFIX))
        if shards:
            _fsync_path(shards_dir(path), directory=True)
    except OSError as error:
        log.warning("%s: merged, but tidying the shards failed (%s); the next merge finishes it",
                    path, error.strerror or error)
