"""The rig's events into the record: kept in memory (in order, with their times) while they cannot be
written, written when they can, and the log kept bounded.

Why kept and not dropped: an event that cannot be written (a full disk, the data directory removed)
is the history of exactly the moment someone will ask about. While it cannot be written the fault
``record`` says so; the rig's watchdog calls ``flush`` periodically, so the fault clears by itself
once space is back, not at the next event. While the data directory is not the one opened (removed
or replaced), nothing is written at all: SQLite would go on writing into a deleted file.

Retention (``[daemon] events_max_age_days``, ``events_max_count``): every ``max_count // 100``
events (at least every event) the oldest beyond either bound are deleted, except the newest of
each kind (:meth:`LabHistory.compact`).
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from collections import deque
from typing import Any, Callable

from graytrack.service.daemon.history import LabHistory

log = logging.getLogger("graytrack.daemon")
KEPT_IN_MEMORY = 10_000  # events held while the record cannot be written (the oldest go first beyond it)
DAY_S = 86_400.0


class EventLog:
    def __init__(self, history: LabHistory, blocked: Callable[[], str | None], report: Callable[[str | None], None],
                 max_age_days: float, max_count: int) -> None:
        """``blocked()``: why nothing may be written now (None: go ahead); ``report``: the ``record`` fault."""
        self.history, self.blocked, self.report = history, blocked, report
        self.max_age_s, self.max_count = max_age_days * DAY_S, max_count
        self._every = max(1, max_count // 100)
        self._since_compact = 0
        self._queue: deque[tuple[float, str, str, dict[str, Any]]] = deque(maxlen=KEPT_IN_MEMORY)
        self._lost = 0
        self._lock = threading.Lock()

    def write(self, kind: str, message: str, **details: Any) -> None:
        with self._lock:
            if len(self._queue) == self._queue.maxlen:
                self._lost += 1
            self._queue.append((time.time(), kind, message, details))
        self.flush()

    @property
    def pending(self) -> int:
        return len(self._queue)

    def flush(self) -> bool:
        """Write what is kept, oldest first; True when nothing is left. The fault is reported outside the
        lock (its listener writes an event itself)."""
        reason = None
        with self._lock:
            if not self._queue:
                return True
            blocked = self.blocked()
            while self._queue and blocked is None:
                t_unix, kind, message, details = self._queue[0]
                try:
                    self.history.event(kind, message, t_unix=t_unix, **details)
                except sqlite3.Error as exc:
                    blocked = str(exc)
                    break
                self._queue.popleft()
                self._since_compact += 1
            if blocked is not None:
                lost = f"; {self._lost} older ones were dropped" if self._lost else ""
                reason = (f"the event log {self.history.path.name} cannot be written ({blocked}): {len(self._queue)} "
                          f"event(s) kept in memory until it can{lost}")
            elif self._since_compact >= self._every:
                self._compact()
        self.report(reason)
        return reason is None

    def abandon(self) -> int:
        """At shutdown, the events still kept in memory (the record could not take them) into the log, one line
        each with its time and details: the journal keeps them where the record cannot. Returns how many."""
        with self._lock:
            kept, lost = list(self._queue), self._lost
            self._queue.clear()
        for t_unix, kind, message, details in kept:
            log.error("event not written to %s before the shutdown: %s", self.history.path.name,
                      json.dumps({"t_unix": t_unix, "kind": kind, "message": message, **details}, default=str))
        if lost:
            log.error("%d older event(s) were dropped while the record could not be written", lost)
        return len(kept)

    def compact(self) -> None:
        with self._lock:
            self._compact()

    def _compact(self) -> None:
        self._since_compact = 0
        try:
            removed = self.history.compact(self.max_age_s, self.max_count)
        except sqlite3.Error as exc:  # a full disk: the log stays as it is, the next round tries again
            log.warning("event log not compacted: %s", exc)
            return
        if removed:
            log.info("event log compacted: %d old event(s) removed", removed)
