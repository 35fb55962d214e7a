"""Wall-clock time for the stream's ``t_unix``.

Every driver stamps frames and grating readings on the host's ``time.monotonic()`` (the drivers'
time contract), which is what the daemon pairs and streams as ``t``. A controller on another
machine needs the same instant on the wall clock (synchronised by PTP or NTP): ``t_unix``.
"""

from __future__ import annotations

import time

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
