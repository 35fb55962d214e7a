"""The history a lab lives with (:class:`LabHistory`): calibrations and events in SQLite (``DATA/record.sqlite``).

Why SQLite (the standard library's): one file in the data directory, transactions, and WAL mode,
so a reader never waits for the writer and a ``kill -9`` loses at most the transaction in flight,
never the history. Rows are small and few (a calibration a day, events on changes only), so every
write is its own transaction from whatever thread reports it.

A calibration gets its row when it is ``done`` (installed), never before: a job that fails, is
aborted or interrupted leaves events, not a calibration one could activate. At start-up the rows
are reconciled with the calibration folders, which are the truth: rows whose job did not end
``done`` on disk are removed (the window between the row and the status file), and folders that
ended ``done`` without a row get one (a record truncated, replaced or rebuilt).

The record is never a single point of failure: a file SQLite cannot read (a bad header, a
truncated or damaged page) is set aside under a name of its own, kept for inspection, and a new
one is started; the calibrations come back from their folders, and an event says what happened.
A full or read-only disk is not damage (:mod:`datadir`): nothing is set aside, the start is refused.
The event log is bounded (``compact``): by age and by count, keeping the newest event of each kind.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

from graytrack.service.daemon.datadir import START_ROOM_BYTES, corrupt, room_problem
from graytrack.service.daemon.errors import InsufficientStorage

SCHEMA = """
CREATE TABLE IF NOT EXISTS calibrations (
    id TEXT PRIMARY KEY,
    started TEXT NOT NULL,
    finished TEXT NOT NULL,
    model_kind TEXT NOT NULL,
    model TEXT,
    error_std_um REAL,
    bound_um REAL,
    frames INTEGER,
    effects TEXT NOT NULL DEFAULT '[]',
    files TEXT NOT NULL DEFAULT '[]',
    summary TEXT
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    t_unix REAL NOT NULL,
    kind TEXT NOT NULL,
    message TEXT NOT NULL,
    details TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS events_time ON events (t_unix);
"""
CALIBRATION_COLUMNS = ("id", "started", "finished", "model_kind", "model", "error_std_um", "bound_um", "frames",
                       "effects", "files", "summary")
MAX_PAGE = 500


def open_history(path: Path) -> tuple["LabHistory", str | None]:
    """The history at ``path``: ``(history, what was rebuilt and why)``, the second None when it opened as it was.

    Only damage sets a file aside: SQLite's "file is not a database" or "malformed", or a page that
    does not read back. A 0-byte file (its pages never written: a disk full before the first one) is said, not
    taken silently for an empty history. A full or read-only disk raises :class:`InsufficientStorage`
    with nothing renamed and nothing created: it is not the record's fault, and freeing space fixes it.
    """
    path = Path(path)
    existed = path.exists()
    empty = existed and path.stat().st_size == 0
    history = None
    try:
        history = LabHistory(path)
        history.check()
    except sqlite3.Error as exc:
        if history is not None:
            history.close()
        if not (isinstance(exc, Damaged) or corrupt(exc)):
            if not existed:
                for suffix in ("", "-wal", "-shm"):  # nothing left behind by the attempt
                    path.with_name(path.name + suffix).unlink(missing_ok=True)
            problem = room_problem(path.parent, START_ROOM_BYTES)
            raise InsufficientStorage(f"the record {path} cannot be opened ({exc}): "
                                      f"{problem or 'check its permissions and the free space of its disk'}") from None
        aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%dT%H%M%S')}")
        for suffix in ("", "-wal", "-shm"):
            companion = path.with_name(path.name + suffix)
            if companion.exists():
                companion.replace(aside.with_name(aside.name + suffix))
        return LabHistory(path), (f"the record could not be read ({exc}): the damaged file was kept as {aside.name} "
                                  f"and a new record started; the calibrations come back from their folders")
    if empty:
        return history, ("the record was an empty file (0 bytes: its history was lost before this start): a new "
                        "record started; the calibrations come back from their folders")
    return history, None


class Damaged(sqlite3.DatabaseError):
    """A page of the record does not read back (``PRAGMA quick_check``)."""


class LabHistory:
    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None, timeout=5.0)
        self._db.row_factory = sqlite3.Row
        mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if mode.lower() != "wal":
            raise sqlite3.OperationalError(f"{self.path}: cannot use WAL mode ({mode})")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(SCHEMA)

    def check(self) -> None:
        """Raise :class:`sqlite3.DatabaseError` unless every page of the file reads back."""
        with self._lock:
            verdict = self._db.execute("PRAGMA quick_check").fetchone()[0]
            self._db.execute("SELECT COUNT(*) FROM events").fetchone()
            self._db.execute("SELECT COUNT(*) FROM calibrations").fetchone()
        if verdict != "ok":
            raise Damaged(f"{self.path}: {verdict}")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- events ------------------------------------------------------------------------------
    def event(self, kind: str, message: str, t_unix: float | None = None, **details: Any) -> int:
        """One event (at ``t_unix``, default now: an event kept while the disk was full keeps its time)."""
        with self._lock:
            cursor = self._db.execute("INSERT INTO events (t_unix, kind, message, details) VALUES (?, ?, ?, ?)",
                                      (time.time() if t_unix is None else t_unix, kind, message,
                                       json.dumps(details, default=str)))
            return int(cursor.lastrowid)

    def compact(self, max_age_s: float, max_count: int, now: float | None = None) -> int:
        """Delete events older than ``max_age_s`` or beyond the newest ``max_count``, except the newest of
        each kind (the last fault, start, calibration... stay readable however old); how many went.
        The freed pages are reused by the next events, so the file stops growing."""
        cutoff = (time.time() if now is None else now) - max_age_s
        with self._lock:
            cursor = self._db.execute(
                "DELETE FROM events WHERE (t_unix < ? OR id <= COALESCE("
                "(SELECT id FROM events ORDER BY id DESC LIMIT 1 OFFSET ?), -1)) "
                "AND id NOT IN (SELECT MAX(id) FROM events GROUP BY kind)", (cutoff, max_count))
            return int(cursor.rowcount)

    def events(self, since_id: int = 0, since_unix: float | None = None, limit: int = 200) -> list[dict[str, Any]]:
        """Events after ``since_id`` (and at or after ``since_unix``), oldest first."""
        limit = max(1, min(int(limit), MAX_PAGE))
        with self._lock:
            rows = self._db.execute(
                "SELECT * FROM events WHERE id > ? AND t_unix >= ? ORDER BY id LIMIT ?",
                (since_id, since_unix if since_unix is not None else -1.0, limit)).fetchall()
        return [{**dict(row), "details": json.loads(row["details"])} for row in rows]

    # -- calibrations -------------------------------------------------------------------------
    def add_calibration(self, row: dict[str, Any]) -> None:
        values = [json.dumps(row.get(c, [])) if c in ("effects", "files") else row.get(c) for c in CALIBRATION_COLUMNS]
        with self._lock:
            self._db.execute(f"INSERT OR REPLACE INTO calibrations ({', '.join(CALIBRATION_COLUMNS)}) "
                             f"VALUES ({', '.join('?' * len(CALIBRATION_COLUMNS))})", values)

    def calibrations(self, limit: int = 20, offset: int = 0) -> tuple[list[dict[str, Any]], int]:
        """A page of calibrations, newest first, and how many there are."""
        limit, offset = max(1, min(int(limit), MAX_PAGE)), max(0, int(offset))
        with self._lock:
            total = self._db.execute("SELECT COUNT(*) FROM calibrations").fetchone()[0]
            rows = self._db.execute("SELECT * FROM calibrations ORDER BY id DESC LIMIT ? OFFSET ?",
                                    (limit, offset)).fetchall()
        return [self._calibration(row) for row in rows], int(total)

    def calibration(self, calibration_id: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM calibrations WHERE id = ?", (calibration_id,)).fetchone()
        return None if row is None else self._calibration(row)

    def remove_calibrations(self, ids: list[str]) -> None:
        with self._lock:
            self._db.executemany("DELETE FROM calibrations WHERE id = ?", [(i,) for i in ids])

    def calibration_ids(self) -> list[str]:
        with self._lock:
            return [row[0] for row in self._db.execute("SELECT id FROM calibrations")]

    @staticmethod
    def _calibration(row: sqlite3.Row) -> dict[str, Any]:
        document = dict(row)
        document["effects"] = json.loads(document["effects"])
        document["files"] = json.loads(document["files"])
        return document
