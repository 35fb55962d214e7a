"""A supervised loop on its own daemon thread: what the camera reader and the grating poller are.

Supervision lives here, once: an exception escaping ``_run`` is reported as a fault with its
reason (``on_crash``), logged with its traceback, and the loop starts again after a pause
(``_recover`` first, e.g. to reopen a device). A worker therefore never ends silently while the
daemon keeps saying all is well; ``alive`` lets a watchdog check that from outside.
"""

from __future__ import annotations

import logging
import threading
from typing import Callable, TypeVar

log = logging.getLogger("graytrack.daemon")
WorkerT = TypeVar("WorkerT", bound="Worker")
JOIN_TIMEOUT_S = 5.0
RESTART_PAUSE_S = 0.2


def describe(exc: BaseException) -> str:
    """One line: the message, and the type when the message alone would not say what happened
    (``ZeroDivisionError: division by zero``; an ``OSError`` or graytrack's own errors speak for themselves)."""
    if isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    else:
        text = str(exc).splitlines()[0][:300] if str(exc) else ""
    speaks = isinstance(exc, OSError) or type(exc).__module__.startswith("graytrack.")
    if not text:
        return type(exc).__name__
    return text if speaks else f"{type(exc).__name__}: {text}"


class Worker:
    """Subclasses implement ``_run`` and poll ``self._stop`` (or wait on it) to end promptly."""

    def __init__(self, name: str, on_crash: Callable[[str | None], None] | None = None) -> None:
        self.name = name
        self.on_crash = on_crash or (lambda reason: None)
        self.crashes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._supervised, name=name, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def _recover(self) -> None:
        """Called before the loop restarts after a crash."""

    def _supervised(self) -> None:
        while not self._stop.is_set():
            try:
                self._run()
                return
            except Exception as exc:  # noqa: BLE001 - any failure: report, log, restart
                log.exception("%s crashed; restarting", self.name)
                self.on_crash(f"{self.name} crashed: {describe(exc)}")
                self.crashes += 1  # counted once reported: whoever sees the count finds the fault
                if self._stop.wait(RESTART_PAUSE_S):
                    return
                try:
                    self._recover()
                except Exception as again:  # noqa: BLE001
                    self.on_crash(f"{self.name} cannot recover: {describe(again)}")

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def start(self: WorkerT) -> WorkerT:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=JOIN_TIMEOUT_S)
