"""An exclusive lock on a file that is removed when the lock is released.

Deleting an ``flock``-ed lock file on release is unsafe done naively: a waiter blocked on the
old inode obtains it after the unlink, while a newcomer creates a new file under the same
name and locks that one — two holders. The protocol here closes the gap. After ``flock``
succeeds, the holder checks that the path still names the inode it locked (``os.fstat`` of
its descriptor against ``os.stat`` of the path); if not, it lets go and starts again on
whatever the path names now. Only a holder unlinks the path, and only while it holds it, so
at any moment at most one process holds the inode the path names, and a released lock
leaves nothing behind. With ``tidy_dir`` the lock file lives in a directory of its own
(a catalogue's ``.shards/``) that is created for the lock and removed on release when empty;
a process that finds the directory gone meanwhile creates it again.

Mechanisms (:func:`mechanism`):

* ``flock`` (POSIX: Linux, macOS, the BSDs; the default). The kernel releases it when its
  holder dies, however it dies; a dead holder's file is unlinked by the next holder's release.
* ``soft`` (``VERTEBRA_CATALOGUE_LOCK=soft``): the lock is the file's existence
  (``O_CREAT | O_EXCL``, atomic on NFSv3+), for mounts where ``flock`` is local to one
  machine. A holder killed with SIGKILL leaves the file; it must then be deleted by hand.
* ``filelock`` (platforms without ``fcntl``: Windows): ``filelock.FileLock`` on the same
  file. It deletes the file on release when no other process has it open (Windows refuses
  to delete an open file, so a waiter keeps it until the last one leaves).
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

try:
    import fcntl
except ImportError:                                 # Windows
    fcntl = None

POLL_S = 0.05
MECHANISMS = ("flock", "soft", "filelock")


def mechanism() -> str:
    """``soft`` if ``VERTEBRA_CATALOGUE_LOCK=soft``, else ``flock`` where ``fcntl`` exists, else
    ``filelock``."""
    if os.environ.get("VERTEBRA_CATALOGUE_LOCK", "").strip().lower() == "soft":
        return "soft"
    return "flock" if fcntl is not None else "filelock"


@dataclass
class Held:
    """A lock held by this process (see :func:`acquire`)."""

    lock_file: Path
    mechanism: str
    fd: int | None = None
    handle: object = None           # the filelock.FileLock of the ``filelock`` mechanism


def _stamp() -> bytes:
    return f"pid={os.getpid()}\nhost={socket.gethostname()}\n".encode()


def _same_inode(fd: int, lock_file: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(lock_file))
    except FileNotFoundError:
        return False


def _try_flock(lock_file: Path) -> int | None:
    """The descriptor of ``lock_file`` locked, or None while another process holds it."""
    while True:
        fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    os.close(fd)
                    return None
                raise
            if _same_inode(fd, lock_file):
                os.ftruncate(fd, 0)                 # who holds it, for the messages of waiters
                os.pwrite(fd, _stamp(), 0)
                return fd
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)            # the previous holder unlinked the file we locked: lock the new one


def _try_soft(lock_file: Path) -> int | None:
    try:
        fd = os.open(lock_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        return None
    try:
        os.write(fd, _stamp())
    finally:
        os.close(fd)
    return -1


def _try_filelock(lock_file: Path):
    import filelock

    handle = filelock.FileLock(str(lock_file))
    try:
        handle.acquire(timeout=0)
    except filelock.Timeout:
        return None
    return handle


def make_directory(directory: Path) -> None:
    """Create ``directory`` if missing. Unlike ``Path.mkdir(exist_ok=True)`` this does not fail
    when another process removes the directory between the attempt and the check; a file in the
    way shows up as NotADirectoryError at the next use of a path inside it."""
    with contextlib.suppress(FileExistsError):
        os.mkdir(directory)


def remove_directory_if_empty(directory: Path) -> None:
    """``rmdir``: safe at any time, since whoever creates files in ``directory`` recreates it
    when it is gone (:func:`make_directory`, then retry on FileNotFoundError)."""
    with contextlib.suppress(OSError):
        os.rmdir(directory)


def acquire(lock_file: Path, until: float, *, tidy_dir: bool = False, how: str | None = None) -> Held | None:
    """Try to take the lock until ``time.monotonic()`` reaches ``until``; None if it did not.

    With ``tidy_dir`` the lock file's directory is created when missing (and removed again by
    :func:`release` when empty). An OSError (read-only filesystem, a directory where the lock
    file should be, a file where the directory should be, …) is raised at once.
    """
    lock_file = Path(lock_file)
    how = how or mechanism()
    while True:
        try:
            if tidy_dir:
                make_directory(lock_file.parent)
            if how == "flock":
                fd = _try_flock(lock_file)
                held = None if fd is None else Held(lock_file, how, fd=fd)
            elif how == "soft":
                held = None if _try_soft(lock_file) is None else Held(lock_file, how)
            else:
                handle = _try_filelock(lock_file)
                held = None if handle is None else Held(lock_file, how, handle=handle)
        except FileNotFoundError:
            if not tidy_dir or not lock_file.parent.parent.is_dir():
                raise               # (no directory to make it in: the catalogue's own is missing)
            continue                # a releasing holder removed the empty directory just now: again
        if held is not None:
            return held
        if time.monotonic() >= until:
            return None
        time.sleep(POLL_S)


def release(held: Held, *, tidy_dir: bool = False) -> None:
    """Let go of the lock and leave nothing behind: the lock file is unlinked while still held
    (``flock``), by its existence's end (``soft``) or by filelock (``filelock``); with
    ``tidy_dir`` its directory is then removed if nothing else is in it."""
    try:
        if held.mechanism == "flock":
            try:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(held.lock_file)       # still holding it: waiters will find it gone
            finally:
                os.close(held.fd)                   # closing releases the flock
        elif held.mechanism == "soft":
            with contextlib.suppress(FileNotFoundError):
                os.unlink(held.lock_file)
        else:
            held.handle.release()
    finally:
        if tidy_dir:                                # unless a shard or a writer's temporary file is there
            remove_directory_if_empty(held.lock_file.parent)


def holder(lock_file: Path, how: str | None = None) -> str:
    """What is known about the holder of ``lock_file``, for messages."""
    how = how or mechanism()
    try:
        st = Path(lock_file).stat()
        with open(lock_file, "rb") as fh:
            text = fh.read(4096).decode("utf-8", "replace")
    except OSError:
        return "held by another process" if how != "soft" else "soft lock file present"
    fields = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
    who = ", ".join(f"{k} {fields[k]}" for k in ("pid", "host") if k in fields)
    if not who and text.strip().splitlines():
        who = "pid " + text.strip().splitlines()[0][:20]
    if how != "soft":
        return "held by another process" + (f" ({who})" if who else "")
    return f"soft lock file created {time.time() - st.st_mtime:.0f} s ago" + (f" by {who}" if who else "")


@contextlib.contextmanager
def locked(lock_file: Path, timeout: float, *, tidy_dir: bool = False):
    """Hold the lock for a ``with`` block; TimeoutError after ``timeout`` seconds."""
    held = acquire(lock_file, time.monotonic() + timeout, tidy_dir=tidy_dir)
    if held is None:
        raise TimeoutError(f"{lock_file}: lock not obtained within {timeout:.0f} s ({holder(lock_file)})")
    try:
        yield held
    finally:
        release(held, tidy_dir=tidy_dir)
