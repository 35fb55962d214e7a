"""The time the daemon's loops decide by: a seam, so tests can move it instead of waiting for it.

The frame loop (camera silence → fault, frame rate, reopen pauses), the calibration sweep
(frame and pass deadlines, on-target checks) and the job runner (a job's duration) decide by the
host's ``time.monotonic()`` and block by waiting on it. They take a :class:`Clock` (the host's by
default) and do all of that through it: reading the time, sleeping, waiting for an event or for a
queue's next item with a timeout. The tests give them a
:class:`~graytrack.service.daemon.manual_clock.ManualClock`, whose time moves only when a test
advances it, so "no frame for 1 s is a fault" is checked by advancing 1 s, not by sleeping
through it on a machine that may be too busy to keep the pace.

This is not the virtual rig's clock (:class:`graytrack.drivers.clock.ScaledClock`, the simulated
physics' time): instants stay host ``time.monotonic`` seconds here, as frames and grating
readings are stamped (the drivers' time contract).
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Protocol, TypeVar

T = TypeVar("T")


class Clock(Protocol):
    """What the loops need of time: host seconds, and blocking with a timeout measured in them."""

    def now(self) -> float:
        """Seconds on the host's monotonic clock."""
        ...

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds``."""
        ...

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Block until ``event`` is set (True) or ``timeout_s`` has passed (False)."""
        ...

    def get(self, items: "queue.Queue[T]", timeout_s: float) -> T:
        """The queue's next item, waiting at most ``timeout_s``; :class:`queue.Empty` when none came."""
        ...


class HostClock:
    """The host's ``time.monotonic``: what the daemon runs on."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return event.wait(max(0.0, timeout_s))

    def get(self, items: "queue.Queue[T]", timeout_s: float) -> T:
        return items.get(timeout=max(0.0, timeout_s))


HOST_CLOCK = HostClock()
