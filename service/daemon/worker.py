"""A supervised loop on its own daemon thread: what the camera reader and the grating poller are.

Supervision lives here, once: an exception escaping ``_run`` is reported as a fault with its
reason (``on_crash``), logged with its traceback, and the loop starts again after a pause
(``_recover`` first, e.g. to reopen a device). A worker therefore never ends silently while the
daemon keeps saying all is well; ``alive`` lets a watchdog check that from outside.
"""

from __future__ import annotations

import logging
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, TypeVar

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


class ThreadGroup:
    """The CPU seconds a set of threads has used, those that have ended included: what the rig's own threads
    (the frame loop, the grating poller, a calibration's sweep and fit) take of the process, so that the rest,
    what serving clients costs, can be told from the process's total (limits.py)."""

    def __init__(self) -> None:
        self._live: dict[int, int] = {}  # thread ident -> its CPU clock
        self._ended = 0.0
        self._lock = threading.Lock()

    @contextmanager
    def member(self) -> Iterator[None]:
        """The calling thread counts in the group while the block runs."""
        ident = threading.get_ident()
        clock = time.pthread_getcpuclockid(ident) if hasattr(time, "pthread_getcpuclockid") else None
        if clock is None:  # a platform without per-thread clocks: nothing is told apart
            yield
            return
        with self._lock:
            self._live[ident] = clock
        try:
            yield
        finally:
            with self._lock:
                self._ended += time.thread_time()
                del self._live[ident]

    def cpu_s(self) -> float:
        with self._lock:
            return self._ended + sum(time.clock_gettime(clock) for clock in self._live.values())


# the threads that run the rig in this process; everything else (the event loop, the request threads) serves
RIG_THREADS = ThreadGroup()


def rig_thread(target: Callable[..., None]) -> Callable[..., None]:
    """``target`` run as one of :data:`RIG_THREADS` (for a thread that is not a :class:`Worker`)."""
    def run(*args: object) -> None:
        with RIG_THREADS.member():
            target(*args)
    return run


def serving_cpu_s() -> float:
    """CPU seconds this process has spent outside the rig's threads: the event loop, the threads answering
    requests, the stream."""
    return time.process_time() - RIG_THREADS.cpu_s()


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
        with RIG_THREADS.member():
            self._loop()

    def _loop(self) -> None:
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
