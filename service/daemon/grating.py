"""The grating readout (``POS?``) polled on its own thread and paired with frames by host time.

Why a separate thread: a serial transaction can block for the link timeout when the controller
or its USB adapter misbehaves, and the camera loop must not stall (or drop frames) because of it.

Why pairing this way (docs/contracts.md: the reference must be read for the same instant as the
exposure): a reading is the midpoint of its request and reply on the host clock, a frame's time
is mid-exposure on the same clock. A frame gets a reference only when it can be *known*:

* **bracketed** — a reading before and one after the frame, at most ``window_s`` apart, and the
  motion between them straight: the change of velocity to the neighbouring readings, times the
  span, bounds the interpolation error (``|a| h² / 8``), which must stay below ``tolerance_mm``.
  A frame paired as it arrives often has no reading after the bracket yet, and the velocity change
  on one side cannot see an acceleration that begins or reverses inside the span (the start of a
  move, the turn into deceleration, where the two may even cancel): with one side seen, the stage's
  largest change of acceleration bounds the line too (``change · (t − ta)(tb − t) / 2``, the frame's
  place in the span counted), unless the three readings agree and no
  command came since (an axis at rest stays there until told). Without it, a busy host's late
  readings, 12-19 ms apart, left frames paired 1.5-4.5 um off during a move. And each reading's
  instant must be known well enough: a reading was taken somewhere between request and reply, so
  while moving at ``v`` its stamp may be off by ``|v| · latency / 2`` (a reply delayed by a busy
  machine makes that large), which must stay below ``tolerance_mm`` too;
* **at rest** — the last readings agree within ``tolerance_mm``, no move was commanded since the
  first of them, and the newest is at most ``rest_s`` old (a closed-loop axis at rest holds its
  position; the limit only guards against a poller that stopped). After a command, readings that
  still agree with the position before it prove nothing about the moments after them: the stage
  takes a few ms to start, and a poller starved then (a busy host) left three such readings stand
  for frames exposed while the stage was already under way (the daemon's virtual rig under two
  busy loops: frames paired with 8.000 mm placed 75-960 µm off it, a lock re-acquired a period
  away, 740 frames flagged ``scale``/``geometry``). So the rest after a command is the one the
  readings reach once they have seen the stage move, or, for a command that moved nothing (a stop
  at rest, a move to where it is), the one they hold for ``rest_s`` after it.

Otherwise no reference is sent: a wrong reference is worse than none (the stream's ``error_um``
would show the pairing, not the tracker). Pairing is called once per frame, so it scans the few
newest readings in place instead of copying the history.
"""

from __future__ import annotations

import logging
import math
import threading
import time

from graytrack.drivers.realtime import raise_thread_priority
from collections import deque
from typing import Callable

from graytrack.drivers.stage.base import Stage
from graytrack.drivers.stage.errors import StageError
from graytrack.service.daemon.worker import Worker

log = logging.getLogger("graytrack.daemon")
HISTORY = 64
REST_READINGS = 3
NAN = float("nan")
# the largest change of acceleration a stage makes between two readings: a reversal from its ACC to its DEC
# (a PI stage's default 100 mm/s^2 each way), the bound on what one side's readings cannot see
CHANGE_MM_S2 = 200.0


class Readings:
    """Recent (host time, position) pairs, oldest first; safe to append and pair from two threads."""

    def __init__(self, window_s: float, tolerance_mm: float, rest_s: float = 0.25, history: int = HISTORY,
                 change_mm_s2: float = CHANGE_MM_S2) -> None:
        self.window_s = window_s
        self.change_mm_s2 = change_mm_s2
        self.rest_s = rest_s
        self.tolerance_mm = tolerance_mm
        self._t: deque[float] = deque(maxlen=history)
        self._x: deque[float] = deque(maxlen=history)
        self._latency: deque[float] = deque(maxlen=history)
        self._lock = threading.Lock()
        self.command_t = -math.inf  # host time of the last commanded move or stop
        self._before_command: float | None = None  # the position read last before it (None: none read)
        self._moved = True  # a reading since the command left that position (or there was none to leave)

    def append(self, t: float, x_mm: float, latency_s: float = 0.0) -> None:
        """A reading stamped ``t`` (host s), taken at most ``latency_s / 2`` from that stamp."""
        with self._lock:
            if self._t and t <= self._t[-1]:
                return
            self._t.append(t)
            self._x.append(x_mm)
            self._latency.append(latency_s)
            if not self._moved and t > self.command_t and self._before_command is not None \
                    and abs(x_mm - self._before_command) > self.tolerance_mm:
                self._moved = True

    def latest(self) -> tuple[float, float] | None:
        with self._lock:
            return (self._t[-1], self._x[-1]) if self._t else None

    def newer(self, t: float, most: int = 2) -> int:
        """How many readings are newer than host time ``t`` (counted up to ``most``): a frame with two
        after it is paired with the motion seen on both sides of its bracket."""
        with self._lock:
            count, k = 0, len(self._t) - 1
            while k >= 0 and count < most and self._t[k] > t:
                count, k = count + 1, k - 1
        return count

    def typical_latency_s(self) -> float:
        """The median round trip of the recent readings (0 before any): how well their instants are known."""
        with self._lock:
            latencies = sorted(self._latency)
        return latencies[len(latencies) // 2] if latencies else 0.0

    def moving(self) -> bool | None:
        """Whether the last readings disagree (None before there are enough of them)."""
        with self._lock:
            if len(self._x) < REST_READINGS:
                return None
            recent = list(self._x)[-REST_READINGS:]
        return max(recent) - min(recent) > self.tolerance_mm

    def note_command(self, t: float) -> None:
        """A move or stop was sent at host time ``t``: rest seen before it proves nothing after it, nor
        does a reading after it of the position before it (the stage may not have started yet)."""
        with self._lock:
            self.command_t = t
            self._before_command = self._x[-1] if self._x else None
            self._moved = self._before_command is None

    def rest_after_command(self) -> float | None:
        """The host time from which the readings show the stage at rest after the last command (the first of
        ``REST_READINGS`` or more readings since it that agree with the newest), or None while they do not: moving,
        not yet seen to start (a command that moved nothing shows its rest only ``rest_s`` after it), or too few
        readings. A later instant than the stage's arrival, never an earlier one: the reading before it differed."""
        with self._lock:
            ts, xs = self._t, self._x
            n = len(ts)
            if n < REST_READINGS or ts[-1] <= self.command_t:
                return None
            if not self._moved and ts[-1] - self.command_t < self.rest_s:
                return None
            newest, first = xs[-1], n
            while first > 0 and ts[first - 1] > self.command_t and abs(xs[first - 1] - newest) <= self.tolerance_mm:
                first -= 1
            return ts[first] if n - first >= REST_READINGS else None

    def at(self, t: float, skew_s: float = 0.0) -> float:
        """The grating position at host time ``t``, or NaN when it cannot be known (see module doc).
        ``skew_s``: the readout's latch against the exposure, as the closed loop measured it
        (``reference_skew_s`` of the model: a reading stamped t describes the stage at t + skew),
        taken back out while moving: the reading minus skew · v, as `graytrack track` compares."""
        with self._lock:
            n = len(self._t)
            if n == 0:
                return NAN
            ts = self._t
            i = n - 1
            while i >= 0 and ts[i] > t:  # the frame is recent: few steps from the end
                i -= 1
            if i < 0:
                return NAN
            if i < n - 1:
                return self._bracketed(i, t, skew_s)
            return self._at_rest(t)

    def _bracketed(self, i: int, t: float, skew_s: float = 0.0) -> float:
        ts, xs = self._t, self._x
        ta, tb, xa, xb = ts[i], ts[i + 1], xs[i], xs[i + 1]
        span = tb - ta
        if span > self.window_s or span <= 0:
            return NAN
        v = (xb - xa) / span
        dv = []
        if i > 0 and ta - ts[i - 1] <= self.window_s:
            dv.append(abs(v - (xa - xs[i - 1]) / (ta - ts[i - 1])))
        if i + 2 < len(ts) and ts[i + 2] - tb <= self.window_s:
            dv.append(abs((xs[i + 2] - xb) / (ts[i + 2] - tb) - v))
        if not dv or max(dv) * span / 8.0 > self.tolerance_mm:
            return NAN  # accelerating (or nothing to tell): the straight line may be wrong
        if len(dv) == 1 and self.change_mm_s2 * (t - ta) * (tb - t) / 2.0 > self.tolerance_mm \
                and not self._held(i - 1 if i > 0 else i + 2, i, i + 1):
            return NAN  # one side seen: a change of motion beginning in the span is not (module doc)
        if abs(v) * 0.5 * max(self._latency[i], self._latency[i + 1]) > self.tolerance_mm:
            return NAN  # moving, and the readings' instants are too loosely known
        value = xa + (xb - xa) * (t - ta) / span
        return value - skew_s * v if skew_s else value

    def _held(self, *readings: int) -> bool:
        """Whether these readings agree and no command came after the first: a closed-loop axis at rest
        stays there until commanded, so no change of motion hides between them."""
        xs = [self._x[k] for k in readings]
        return max(xs) - min(xs) <= self.tolerance_mm and self._t[min(readings)] > self.command_t

    def _at_rest(self, t: float) -> float:
        ts, xs = self._t, self._x
        n = len(ts)
        if n < REST_READINGS or t - ts[-1] > self.rest_s:
            return NAN
        first = n - REST_READINGS
        if ts[first] <= self.command_t or ts[-1] - ts[first] > REST_READINGS * self.rest_s:
            return NAN
        if not self._moved and ts[-1] - self.command_t < self.rest_s:
            return NAN  # the position before the command, read since: the stage may be starting (module doc)
        newest = xs[-1]
        for k in range(first, n - 1):
            if abs(xs[k] - newest) > self.tolerance_mm:
                return NAN
        return newest


class GratingPoller(Worker):
    """Reads ``POS?`` every ``poll_s`` (wall time) into :class:`Readings` (host time).

    Failures are reported through ``on_fault(reason or None)`` — None when a read succeeds again —
    so the rig can show a stage fault and clear it once the link recovers.
    """

    def __init__(self, stage: Stage, poll_s: float, readings: Readings,
                 on_fault: Callable[[str | None], None], priority: int = 0) -> None:
        super().__init__("grating-poller", on_fault)
        self.priority = priority  # SCHED_FIFO level (realtime.py), 0 = normal
        self.stage = stage
        self.poll_s = poll_s
        self.readings = readings
        self.on_fault = on_fault
        self.reads = 0
        self.errors = 0

    def latest_mm(self) -> float | None:
        latest = self.readings.latest()
        return None if latest is None else latest[1]

    def silent_s(self, now: float | None = None) -> float | None:
        """Seconds since the newest reading (host time; None before the first)."""
        latest = self.latest_t()
        return None if latest is None else (time.monotonic() if now is None else now) - latest

    def fresh_mm(self, max_age_s: float) -> float | None:
        """The newest reading while it is younger than ``max_age_s``: a figure older than that is
        withdrawn, never shown frozen while the stage may be elsewhere."""
        latest = self.readings.latest()
        return None if latest is None or time.monotonic() - latest[0] > max_age_s else latest[1]

    def latest_t(self) -> float | None:
        latest = self.readings.latest()
        return None if latest is None else latest[0]

    def _run(self) -> None:
        # the frame loop's level: a poller preempted by other work while it holds the interpreter lock
        # held the realtime frame loop and event loop waiting behind it (a priority inversion; bench/stream_latency.py
        # at priority 10 under load: encoding p99 9.7 -> 5.4 ms, receipt p99 14.6 -> 9.0 ms); it sleeps between polls
        raise_thread_priority(self.priority, "grating poller")
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
            self.readings.append(reading.t, reading.position_mm, reading.latency_s)  # host time (stage contract)
            self.on_fault(None)
            self._stop.wait(max(0.0, self.poll_s - (time.monotonic() - started)))
