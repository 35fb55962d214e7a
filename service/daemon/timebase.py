"""One place that puts driver timestamps on the host's clock (``time.monotonic``).

The stream, the pairing and the sweep all work in host time, the clock a client on this machine
reads too. Hardware drivers stamp in host time; the virtual rig may run on a :class:`ScaledClock`
(``sim_clock_scale``) whose seconds are not the host's. :class:`HostTime` maps either onto the
host clock, deciding per stamp by which clock it is near: a stamp is always of the last moments,
and the two clocks differ by far more than that (different origin, different rate).
"""

from __future__ import annotations

import time

from graytrack.drivers.clock import ScaledClock


class HostTime:
    def __init__(self, clock: ScaledClock) -> None:
        self.clock = clock
        self.identity = clock.scale == 1.0 and clock._origin == 0.0

    def __call__(self, t: float) -> float:
        """``t`` (a driver's timestamp) in seconds of ``time.monotonic()``."""
        if self.identity:
            return t
        now = time.monotonic()
        if abs(t - now) <= abs(t - self.clock.now()):
            return t
        return self.clock._origin + t / self.clock.scale

    def seconds(self, duration: float) -> float:
        """A driver-clock duration in host seconds (exposures of the virtual camera)."""
        return duration / self.clock.scale


WALL_OFFSET_REFRESH_S = 1.0


class WallClock:
    """``time.monotonic()`` → ``time.time()``: the offset, re-read once a second (NTP slews it)."""

    def __init__(self) -> None:
        self._offset = time.time() - time.monotonic()
        self._read_at = time.monotonic()

    def unix(self, t_host: float, now: float) -> float:
        if now - self._read_at > WALL_OFFSET_REFRESH_S:
            self._offset, self._read_at = time.time() - time.monotonic(), now
        return t_host + self._offset
