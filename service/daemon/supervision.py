"""Faults by source and the supervisor that brings the hardware up and watches the workers.

Sources: ``hardware`` (cannot open), ``startup`` (the bring-up itself failed), ``camera``,
``stage`` (the grating readout), ``tracking`` (frames or model the tracker cannot use),
``acquisition`` / ``grating-poller`` (a worker crashed or died), ``storage`` (the data directory
full, read-only, removed or replaced: :mod:`datadir`) and ``record`` (the event log cannot be
written). The rig's state is derived from this table, so it cannot say "tracking" while a part is
failing.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from graytrack.service.daemon.worker import describe

log = logging.getLogger("graytrack.daemon")
Reporter = Callable[[str, "str | None"], None]

# Faults during which a calibration still makes sense (it is how a bad model gets replaced).
CALIBRATABLE = frozenset({"tracking", "model"})


class Faults:
    """Current faults by source, thread-safe, logged on change.

    ``listeners(source, reason, previous, seconds)`` hear a fault when it is raised (``previous``
    None) and when it clears (``reason`` None, ``seconds`` how long it lasted): an event is a
    change of state. A fault whose text changes while it lasts (a camera's growing silence) is
    shown as it is now, but is not a new fault: an outage of an hour is two events, not thousands.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._faults: dict[str, str] = {}
        self._since: dict[str, float] = {}
        self._lock = threading.Lock()
        self._clock = clock
        self.raised = 0
        self.listeners: list[Callable[[str, str | None, str | None, float], None]] = []

    def reporter(self, source: str) -> Callable[[str | None], None]:
        """A callback setting (reason) or clearing (None) this source's fault."""
        return lambda reason: self.set(source, reason)

    def set(self, source: str, reason: str | None) -> None:
        if reason is None and source not in self._faults:  # the per-frame common case, without the lock
            return
        with self._lock:
            previous = self._faults.get(source)
            if reason == previous:
                return
            if reason is None:
                del self._faults[source]
                seconds = self._clock() - self._since.pop(source)
            else:
                self._faults[source] = reason
                self.raised += previous is None
                if previous is None:
                    self._since[source] = self._clock()
                seconds = 0.0
        if reason is None:
            log.info("%s fault cleared after %.1f s", source, seconds)
        elif previous is None:
            log.warning("%s fault: %s", source, reason)
        else:
            return  # the same fault, described anew
        for listener in self.listeners:
            listener(source, reason, previous, seconds)

    def snapshot(self) -> dict[str, str]:
        with self._lock:
            return dict(self._faults)

    def blocking_calibration(self) -> dict[str, str]:
        return {k: v for k, v in self.snapshot().items() if k not in CALIBRATABLE}


def sentence(faults: dict[str, str]) -> str | None:
    """Every part in fault, named, in one readable sentence (None when all is well)."""
    if not faults:
        return None
    parts = [f"{source}: {reason.rstrip('.')}" for source, reason in sorted(faults.items())]
    return "; ".join(parts) + "."


class Supervisor:
    """One thread: ``bring_up()`` until it succeeds (every ``retry_s``), then ``watch()`` every ``watch_s``.

    Any exception of either becomes the ``startup`` / ``watchdog`` fault with its reason and is
    retried, so a broken file in the data directory or a driver bug shows as a fault with a
    reason instead of a daemon that stays ``starting`` or ``idle`` for no visible reason.
    """

    def __init__(self, bring_up: Callable[[], None], watch: Callable[[], None], faults: Faults,
                 retry_s: float, watch_s: float = 0.1) -> None:
        self.bring_up, self.watch, self.faults = bring_up, watch, faults
        self.retry_s, self.watch_s = retry_s, watch_s
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, name="rig-supervisor", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self.stopping.set()
        if self.thread.is_alive():
            self.thread.join(timeout=10.0)

    def _run(self) -> None:
        while not self.stopping.is_set():
            try:
                self.bring_up()
                self.faults.set("startup", None)
                break
            except Exception as exc:  # noqa: BLE001 - report and retry; the daemon stays up
                log.exception("start-up failed")
                self.faults.set("startup", f"start-up failed: {describe(exc)}")
                self.stopping.wait(self.retry_s)
        while not self.stopping.wait(self.watch_s):
            try:
                self.watch()
                self.faults.set("watchdog", None)
            except Exception as exc:  # noqa: BLE001
                log.exception("watchdog failed")
                self.faults.set("watchdog", f"watchdog failed: {describe(exc)}")
