"""Time for simulated hardware: the host's monotonic clock, or a faster-running copy of it.

The simulated controller, the simulated camera and the drivers talking to them must agree on
one clock, because pairing an exposure with a grating reading is what the rig is about. Tests
run that clock faster than wall time (``ScaledClock(10)``) so that a calibration sweep of real
moves, settles and frames takes a fraction of a second without changing any of the timing logic. What leaves a
simulated device is host time all the same (:meth:`ScaledClock.to_host`): physics runs on the simulated clock,
the frame and reading boundaries map to ``time.monotonic``, so the time contract holds whatever the scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass
class ScaledClock:
    """``now()`` advances ``scale`` seconds per wall second, from 0 at creation."""

    scale: float = 1.0
    _origin: float = field(default_factory=time.monotonic, repr=False)

    def now(self) -> float:
        return self.scale * (time.monotonic() - self._origin)

    def to_host(self, t: float) -> float:
        """The host ``time.monotonic`` instant at which this clock read ``t``."""
        return self._origin + t / self.scale

    def from_host(self, t_host: float) -> float:
        """This clock's reading at host ``time.monotonic`` instant ``t_host``."""
        return self.scale * (t_host - self._origin)

    def duration_to_host(self, seconds: float) -> float:
        """A span of this clock's seconds in host seconds."""
        return seconds / self.scale

    def sleep(self, seconds: float) -> None:
        """Sleep for ``seconds`` of this clock's time."""
        if seconds > 0:
            time.sleep(seconds / self.scale)


REAL_TIME = ScaledClock(1.0, 0.0)  # plain time.monotonic
