"""The data directory's health: full, read-only, removed or replaced is the fault ``storage``, never corruption.

Why a watch of its own: a write that fails for want of space says nothing about the files already
there, and treating it as damage (setting the record aside, truncating it) loses what a full disk
had kept. So every failure is sorted here first: a full disk (``ENOSPC``, SQLite's "database or
disk is full") and a read-only one (``EROFS``) are a fault naming the directory, its free space and
what was needed, the request that would write answers 507, and the fault clears by itself once the
space is back (``probe``, called periodically by the rig's watchdog, not by the next write).

A directory removed or replaced (another inode at its path) while the daemon runs is the same
fault: the daemon's open record would otherwise go on writing into a file nobody can see, and a
new empty directory at the path is not the one whose model is tracked. Both are detected by the
directory's identity (``st_dev``, ``st_ino``) taken at start; a directory moved away and back (the
same inode) is safe and clears the fault, a replaced one keeps it until a restart.

Writes that could not be made (a job's final status) are kept in memory in order (``defer``) and
made when the fault clears. A shutdown before then hands each one's content to the log (``abandon``):
the journal is the one place left that takes it, so the end of a calibration is still on record.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import sqlite3
import threading
from collections import deque
from pathlib import Path
from typing import Any, Callable

from graytrack.service.daemon.errors import InsufficientStorage

log = logging.getLogger("graytrack.daemon")
MIN_FREE_BYTES = 64 * 1024  # below this an event, a status file or the pointer may not fit: the disk is full
START_ROOM_BYTES = 512 * 1024  # the record's header, its WAL and shared memory, the status files of a start
FULL, READ_ONLY = "disk full", "read-only"
Identity = tuple[int, int]


def kind_of(exc: BaseException) -> str | None:
    """``FULL`` or ``READ_ONLY`` when ``exc`` is the file system refusing a write, else None (a real error)."""
    if isinstance(exc, OSError):
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return FULL
        return READ_ONLY if exc.errno == errno.EROFS else None
    if isinstance(exc, sqlite3.Error):
        text = str(exc).lower()
        if "disk is full" in text:
            return FULL
        if "readonly" in text or "read-only" in text:
            return READ_ONLY
    return None


def corrupt(exc: sqlite3.Error) -> bool:
    """SQLite's own words for a file whose content is damaged (the only case the record is set aside for)."""
    text = str(exc).lower()
    return "not a database" in text or "malformed" in text


def identity(path: Path) -> Identity:
    info = os.stat(path)
    return info.st_dev, info.st_ino


def free_bytes(path: Path) -> int:
    vfs = os.statvfs(path)
    return vfs.f_bavail * vfs.f_frsize


def size(n: float) -> str:
    """Bytes as a person reads them (4.0 KiB, 1.2 MiB)."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError


def full_message(root: Path, free: int, needed: int) -> str:
    return (f"disk full: the data directory {root} has {size(free)} free and needs {size(needed)}: "
            f"free some space on its file system or move [daemon] data_dir")


def unexplained_full(root: Path, exc: BaseException) -> str:
    """A write refused for space while the file system shows free space: its inodes, a quota."""
    return (f"disk full: a write to the data directory {root} failed ({exc}) with {size(free_bytes(root))} free: "
            f"out of inodes or over a quota? free some space on its file system or move [daemon] data_dir")


def read_only_message(root: Path) -> str:
    return (f"read-only: the data directory {root} cannot be written (a read-only file system or its permissions): "
            f"remount it read-write or make it writable by this user")


def room_problem(root: Path, needed: int) -> str | None:
    """Why nothing can be written to ``root`` now (read-only, fewer than ``needed`` bytes free), or None."""
    vfs = os.statvfs(root)
    if vfs.f_flag & os.ST_RDONLY or not os.access(root, os.W_OK):
        return read_only_message(root)
    free = vfs.f_bavail * vfs.f_frsize
    if free < needed:
        return full_message(root, free, needed)
    if vfs.f_files and not vfs.f_favail:  # every inode used: no new file, whatever the free bytes
        return (f"disk full: the data directory {root} has {size(free)} free but no free inode (a new file "
                f"cannot be made): remove files on its file system or move [daemon] data_dir")
    return None


def require_room(root: Path, needed: int = START_ROOM_BYTES) -> None:
    """Refuse a start on a full or read-only disk before anything is opened, renamed or truncated."""
    problem = room_problem(root, needed)
    if problem is not None:
        raise InsufficientStorage(f"cannot start: {problem}")


class DataDirHealth:
    """The ``storage`` fault of one data directory, raised on a failed write or by ``probe``, cleared by ``probe``."""

    def __init__(self, root: Path, home: Identity, report: Callable[[str | None], None],
                 min_free_bytes: int = MIN_FREE_BYTES) -> None:
        self.root, self.home, self.report = root, home, report
        self.min_free_bytes = min_free_bytes
        self._needed = min_free_bytes  # what the last write that failed for space asked for
        self._pending: deque[tuple[str, Callable[[], None], Any]] = deque()
        self._lock = threading.Lock()
        self.reason: str | None = None

    def moved(self) -> str | None:
        """Why the path no longer leads to the directory the daemon opened (removed, replaced), or None."""
        try:
            now = identity(self.root)
        except FileNotFoundError:
            return (f"the data directory {self.root} was removed while the daemon ran: nothing is written until it "
                    f"is back (move it back) or the daemon is restarted")
        if now != self.home:
            return (f"the data directory {self.root} was replaced by another directory while the daemon ran: nothing "
                    f"is written into it; restart the daemon to use the new one")
        return None

    def problem(self) -> str | None:
        return self.moved() or room_problem(self.root, self._needed)

    def probe(self) -> bool:
        """Look now: raise, update or clear the fault; on clearing, make the writes that were kept.
        True when healthy."""
        reason = self.problem()
        self.reason = reason
        self.report(reason)
        if reason is None:
            self._needed = self.min_free_bytes
            self._flush()
        return reason is None

    def refuse(self, needed: int = 0) -> None:
        """Raise the 507 of a request that would write while the directory cannot take ``needed`` bytes."""
        self._needed = max(self.min_free_bytes, needed)
        if not self.probe():
            raise InsufficientStorage(self.reason)

    def failed(self, exc: BaseException, needed: int = 0) -> InsufficientStorage | None:
        """The 507 for a write that failed because of the disk (the fault raised now), or None for any other error."""
        kind, moved = kind_of(exc), self.moved()
        if kind is None and moved is None:
            return None
        self._needed = max(self.min_free_bytes, needed)
        reason = moved or self.problem() or (read_only_message(self.root) if kind == READ_ONLY else
                                    unexplained_full(self.root, exc))
        self.reason = reason
        self.report(reason)
        return InsufficientStorage(reason)

    def defer(self, what: str, write: Callable[[], None], content: Any) -> None:
        """Make ``write`` once the fault clears (in order), kept in memory until then; ``content`` (JSON-able)
        is what it writes, logged in full should the daemon stop first (``abandon``)."""
        log.warning("%s: kept in memory until the data directory can be written", what)
        with self._lock:
            self._pending.append((what, write, content))

    @property
    def pending(self) -> int:
        return len(self._pending)

    def _flush(self) -> None:
        with self._lock:
            while self._pending:
                what, write, _ = self._pending[0]
                try:
                    write()
                except Exception as exc:  # noqa: BLE001 - still no room: kept, tried at the next probe
                    log.warning("%s: still cannot be written (%s)", what, exc)
                    return
                self._pending.popleft()
                log.info("%s: written", what)

    def abandon(self) -> int:
        """At shutdown with the fault still raised: log each kept write's content (the journal keeps it, the
        directory cannot) and forget them. Returns how many there were."""
        with self._lock:
            kept, self._pending = list(self._pending), deque()
        for what, _, content in kept:
            log.error("%s could not be written to %s before the shutdown (%s); its content: %s",
                      what, self.root, self.reason, json.dumps(content, sort_keys=True, default=str))
        return len(kept)
