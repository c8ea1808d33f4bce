"""One writer per folder: an advisory lock for datasets, run folders and bundles.

Two processes appending to the same dataset or run folder interleave their commits and lose
data without either noticing, so every writer of such a folder holds its lock for as long as it
writes. The lock is ``flock`` on a small file (``.gijax.lock`` inside the folder, or a sibling
file for folders that are replaced as a whole), and the file records the holder's PID, host,
command line and start time, so that a second writer's error says who holds it.

``flock`` belongs to the open file, so the kernel drops it when the holder exits in any way,
SIGKILL included: a lock file left behind by a killed process is stale, and the next writer
takes it over without help. Releasing removes the file; an acquirer that raced with that
removal and locked the old, unlinked file notices the changed inode and tries again.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import stat
import sys
import time
from pathlib import Path

LOCK_FILE = ".gijax.lock"


class FolderLockedError(RuntimeError):
    """Another live process holds the lock; ``holder`` is its record (pid, host, command)."""

    def __init__(self, message: str, holder: dict):
        super().__init__(message)
        self.holder = holder


def _open_lock_file(path: Path, flags: int) -> int:
    """``os.open`` of a lock file that never follows a link planted at its name (which would
    let the lock record overwrite the link's target) and accepts only a regular file."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
                     | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError(f"lock file {path} is a symbolic link; gijax never writes through "
                             f"one: remove the link and run again") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ValueError(f"lock file {path} is not a regular file; remove it and run again")
    return fd


def _read_record(fd: int) -> dict:
    try:
        data = os.pread(fd, 4096, 0)
        record = json.loads(data.decode("utf-8")) if data else {}
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def describe_holder(record: dict) -> str:
    """'PID 123 on host, gijax render ..., since 2024-01-01 12:00:00' from a lock record."""
    if not record.get("pid"):
        return "PID unknown (the lock file is being written)"
    parts = [f"PID {record['pid']}"]
    if record.get("host") and record["host"] != socket.gethostname():
        parts[0] += f" on {record['host']}"
    if record.get("command"):
        parts.append(str(record["command"])[:120])
    if record.get("since"):
        parts.append("since " + time.strftime("%Y-%m-%d %H:%M:%S",
                                              time.localtime(float(record["since"]))))
    return ", ".join(parts)


class FolderLock:
    """Exclusive write access to ``folder`` for this process.

    Args:
      folder: the folder written (must exist unless ``lock_file`` lies elsewhere).
      what: how errors name the folder ('dataset', 'run folder', 'bundle').
      lock_file: the lock file; default ``folder/.gijax.lock``. A folder that is replaced by a
        rename (a bundle) needs a lock file outside it.

    ``acquire()`` raises :class:`FolderLockedError` naming the holder when another process
    holds the lock; it never waits. After it returns, ``previous`` is the record a killed
    holder left behind (empty when the lock was free and clean). Use as a context manager or
    call ``release()``; the lock also goes when the process ends.
    """

    def __init__(self, folder, what: str = "folder", lock_file=None):
        self.folder = Path(folder)
        self.path = Path(lock_file) if lock_file is not None else self.folder / LOCK_FILE
        self.what = what
        self.previous: dict = {}
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "FolderLock":
        if self._fd is not None:
            return self
        while True:
            fd = _open_lock_file(self.path, os.O_RDWR | os.O_CREAT)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_record(fd)
                os.close(fd)
                raise FolderLockedError(
                    f"{self.what} {self.folder} is being written by another process "
                    f"({describe_holder(holder)}); wait for it to finish or use another "
                    f"folder", holder) from None
            try:
                st, now = os.fstat(fd), os.lstat(self.path)
                same = (st.st_ino, st.st_dev) == (now.st_ino, now.st_dev)
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)          # locked a file its holder had just removed: try the new one
        self.previous = _read_record(fd)
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv else "",
                  "since": time.time()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(record).encode("utf-8"), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            # Remove the file only while it is still ours, so a clean folder has no lock file.
            st, now = os.fstat(fd), os.lstat(self.path)
            if (st.st_ino, st.st_dev) == (now.st_ino, now.st_dev):
                os.unlink(self.path)
        except FileNotFoundError:
            pass
        finally:
            os.close(fd)

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self):
        if getattr(self, "_fd", None) is not None:
            try:
                self.release()
            except OSError:
                pass


def holder_of(folder, lock_file=None) -> dict | None:
    """The record of the live process holding ``folder``'s lock, or None when nobody does."""
    path = Path(lock_file) if lock_file is not None else Path(folder) / LOCK_FILE
    try:
        fd = _open_lock_file(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_record(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


__all__ = ["FolderLock", "FolderLockedError", "LOCK_FILE", "describe_holder", "holder_of"]
