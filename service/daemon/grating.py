"""The grating readout (``POS?``) polled on its own thread and paired with frames by host time.

Why a separate thread: a serial transaction can block for the link timeout when the controller
or its USB adapter misbehaves, and the camera loop must not stall (or drop frames) because of it.
Why pairing by time rather than "the latest reading": DESIGN.md — the reference must be read for
the same instant as the exposure. Frames carry their mid-exposure host time and readings the
midpoint of request and reply on the same clock, so a frame's reference is the readings nearest
to it in time, linearly interpolated (or extrapolated over a few ms while moving).
"""

from __future__ import annotations

import bisect
import logging
import threading
import time
from collections import deque
from typing import Callable

from graytrack.drivers.stage.base import PositionReading, Stage
from graytrack.drivers.stage.errors import StageError
from graytrack.service.daemon.worker import Worker

log = logging.getLogger("graytrack.daemon")
HISTORY = 64


def pair_reading(readings: list[PositionReading], t: float, window_s: float) -> float:
    """The grating position at host time ``t`` from readings sorted by time; NaN if none is near.

    Uses the two readings closest to ``t`` (a bracketing pair when there is one) and draws the
    line through them; both must lie within ``window_s`` of ``t``. One reading alone is used as
    it is when it is that close (a stage at rest reads the same anyway).
    """
    if not readings:
        return float("nan")
    times = [r.t for r in readings]
    first = min(max(bisect.bisect_left(times, t) - 1, 0), max(len(readings) - 2, 0))
    candidates = readings[first: first + 2]  # the bracketing pair, else the two at the near end
    near = [r for r in candidates if abs(r.t - t) <= window_s]
    if not near:
        return float("nan")
    if len(near) == 1 or near[1].t == near[0].t:
        return near[0].position_mm
    a, b = near
    return a.position_mm + (b.position_mm - a.position_mm) * (t - a.t) / (b.t - a.t)


class GratingPoller(Worker):
    """Reads ``POS?`` every ``poll_s`` (wall time) and keeps the recent readings.

    Failures are reported through ``on_fault(reason or None)`` — None when a read succeeds again —
    so the rig can show a stage fault and clear it once the link recovers.
    """

    def __init__(self, stage: Stage, poll_s: float, window_s: float,
                 on_fault: Callable[[str | None], None]) -> None:
        super().__init__("grating-poller")
        self.stage = stage
        self.poll_s = poll_s
        self.window_s = window_s
        self.on_fault = on_fault
        self.reads = 0
        self.errors = 0
        self._readings: deque[PositionReading] = deque(maxlen=HISTORY)
        self._lock = threading.Lock()

    def latest(self) -> PositionReading | None:
        with self._lock:
            return self._readings[-1] if self._readings else None

    def at(self, t: float) -> float:
        """The grating position at host time ``t`` (NaN when no reading is close enough)."""
        with self._lock:
            readings = list(self._readings)
        return pair_reading(readings, t, self.window_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                reading = self.stage.position()
            except StageError as exc:
                self.errors += 1
                self.on_fault(f"grating readout failed: {exc}")
                self._stop.wait(max(self.poll_s, 0.2))  # do not hammer a failing link
                continue
            self.reads += 1
            with self._lock:
                self._readings.append(reading)
            self.on_fault(None)
            self._stop.wait(max(0.0, self.poll_s - (time.monotonic() - started)))
