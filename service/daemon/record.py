"""The record a lab lives with: calibrations and events in SQLite (``DATA/record.sqlite``).

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
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

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


def open_record(path: Path) -> tuple["Record", Path | None]:
    """The record at ``path``, or a new one when that file is damaged: ``(record, where the damaged
    file was moved)``."""
    path = Path(path)
    try:
        record = Record(path)
        record.check()
        return record, None
    except sqlite3.DatabaseError:
        pass
    if "record" in locals():
        record.close()
    aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%dT%H%M%S')}")
    for suffix in ("", "-wal", "-shm"):
        companion = path.with_name(path.name + suffix)
        if companion.exists():
            companion.replace(aside.with_name(aside.name + suffix))
    return Record(path), aside


class Record:
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
            raise sqlite3.DatabaseError(f"{self.path}: {verdict}")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- events ------------------------------------------------------------------------------
    def event(self, kind: str, message: str, **details: Any) -> int:
        with self._lock:
            cursor = self._db.execute("INSERT INTO events (t_unix, kind, message, details) VALUES (?, ?, ?, ?)",
                                      (time.time(), kind, message, json.dumps(details, default=str)))
            return int(cursor.lastrowid)

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
