"""Time for simulated hardware: the host's monotonic clock, or a faster-running copy of it.

The simulated controller, the simulated camera and the drivers talking to them must agree on
one clock, because pairing an exposure with a grating reading is what the rig is about. Tests
run that clock faster than wall time (``ScaledClock(10)``) so that a calibration sweep of real
moves, settles and frames takes a fraction of a second without changing any of the timing logic.
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

    def sleep(self, seconds: float) -> None:
        """Sleep for ``seconds`` of this clock's time."""
        if seconds > 0:
            time.sleep(seconds / self.scale)


REAL_TIME = ScaledClock(1.0, 0.0)  # plain time.monotonic
