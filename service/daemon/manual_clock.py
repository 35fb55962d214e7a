"""A :class:`~graytrack.service.daemon.clock.Clock` whose time moves only when a test advances it.

Why: the daemon's timing decisions (a camera silent for longer than ``camera_fault_after_s`` is a
fault, a pass that has not arrived within its allowance fails, a job lasted so long) are only
testable on the wall clock by sleeping through them, and a busy machine stretches every sleep.
On this clock a test advances the time it means and then looks: the outcome depends on the
figures, not on how fast the machine is.

How threads are released, deterministically: every blocking call (``sleep``, ``wait``, ``get``)
registers a deadline on this clock's time. :meth:`advance` moves the time and returns only once
every thread whose deadline it passed has left its wait. :meth:`put` hands an item to a queue a
thread may be waiting on and wakes it. :meth:`settle` returns once the given number of threads
are blocked again *having seen the latest change* (the time advanced, an item put): the loop
under test has done all that the change allows it to, and the test can assert. An event set from
outside (a worker's stop) or an item put on a queue directly is noticed within ``POLL_S`` of real
time; that only decides how soon, never what.
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from typing import Any, Callable, TypeVar

T = TypeVar("T")
POLL_S = 0.005  # real seconds between looks at an event or a queue that was not changed through this clock
SETTLE_TIMEOUT_S = 10.0  # real seconds a released thread may take to leave or block again (a loaded machine)


class ManualClock:
    """Host seconds that start at ``start`` and move only by :meth:`advance`."""

    def __init__(self, start: float = 1000.0) -> None:
        self._now = float(start)
        self._changes = 0  # counts advances and puts: what a blocked thread has seen
        self._cond = threading.Condition()
        self._blocked: dict[int, tuple[float, int]] = {}  # token → (deadline, changes seen)
        self._tokens = itertools.count()

    # -- the Clock protocol ---------------------------------------------------------------------
    def now(self) -> float:
        with self._cond:
            return self._now

    def sleep(self, seconds: float) -> None:
        self._block(seconds, lambda: False)

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return self._block(timeout_s, event.is_set)

    def get(self, items: "queue.Queue[T]", timeout_s: float) -> T:
        taken: list[T] = []

        def ready() -> bool:
            try:
                taken.append(items.get_nowait())
            except queue.Empty:
                return False
            return True

        if self._block(timeout_s, ready):
            return taken[0]
        raise queue.Empty

    # -- what the test does -----------------------------------------------------------------------
    def advance(self, seconds: float, timeout_s: float = SETTLE_TIMEOUT_S) -> None:
        """Move time on by ``seconds``; returns once every thread whose deadline passed has left its wait."""
        if seconds < 0:
            raise ValueError(f"time does not go back ({seconds} s)")
        with self._cond:
            self._now += seconds
            self._changes += 1
            self._cond.notify_all()
            self._wait_until(lambda: not any(deadline <= self._now for deadline, _ in self._blocked.values()),
                             timeout_s, "the threads whose deadline passed to wake")

    def put(self, items: "queue.Queue[Any]", item: Any) -> None:
        """Put ``item`` on ``items`` and wake whoever waits on it (time does not move)."""
        items.put_nowait(item)
        with self._cond:
            self._changes += 1
            self._cond.notify_all()

    def settle(self, threads: int = 1, timeout_s: float = SETTLE_TIMEOUT_S) -> None:
        """Return once ``threads`` threads are blocked on this clock having seen the latest advance or put."""
        with self._cond:
            self._wait_until(lambda: self._current() >= threads, timeout_s,
                             f"{threads} thread(s) to block again", threads)

    @property
    def blocked(self) -> int:
        """Threads blocked on this clock now."""
        with self._cond:
            return len(self._blocked)

    # -- inside -------------------------------------------------------------------------------------
    def _current(self) -> int:
        return sum(seen == self._changes for _, seen in self._blocked.values())

    def _wait_until(self, done: Callable[[], bool], timeout_s: float, what: str, threads: int | None = None) -> None:
        """Wait (real time, the condition held) until ``done()``; a thread that never gets there is a test failure."""
        end = time.monotonic() + timeout_s
        while not done():
            left = end - time.monotonic()
            if left <= 0:
                deadlines = sorted(deadline for deadline, _ in self._blocked.values())
                raise TimeoutError(f"manual clock at {self._now:g} s: waited {timeout_s:g} s (real) for {what}; "
                                   f"{len(self._blocked)} blocked (deadlines {deadlines}), "
                                   f"{self._current()} of them since the last change"
                                   + (f", {threads} wanted" if threads is not None else ""))
            self._cond.wait(min(left, 0.05))

    def _block(self, seconds: float, ready: Callable[[], bool]) -> bool:
        """Until ``ready()`` (True) or the deadline ``seconds`` from now (False); ready is looked at last,
        so an item put before the time advanced past the deadline is still taken."""
        with self._cond:
            deadline = self._now + max(0.0, seconds)
            token = next(self._tokens)
            self._blocked[token] = (deadline, -1)
            try:
                while True:
                    expired = self._now >= deadline
                    if ready():
                        return True
                    if expired:
                        return False
                    if self._blocked[token][1] != self._changes:
                        self._blocked[token] = (deadline, self._changes)
                        self._cond.notify_all()  # settle() may be waiting for this thread
                    self._cond.wait(POLL_S)
            finally:
                del self._blocked[token]
                self._cond.notify_all()  # advance() waits for released threads to leave
