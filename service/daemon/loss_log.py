"""The event log's account of camera frames lost on their way to the tracker (the stream's ``dropped``).

The page and the stream show a running count of frames missing from the camera's frame counter. A
count that rises with nothing in the event log reads as a fault nobody explains: on a fresh start
the first calibration's fit shares two cores with the frame loop and ~40 frames go missing. Each gap
is logged as ``frames_lost``: how many, between which frames, and the total since start (the figure
the page shows), so the count always has its events. Gaps within ``quiet_s`` of the last event
(``[daemon] frames_lost_quiet_s``, 10 s) are summed into the next one: a reader that keeps falling
behind writes a few events a minute, not one per frame (the event log keeps every kind's newest, and
a flood would push the rest out).
"""

from __future__ import annotations

import math
from typing import Callable

QUIET_S = 10.0  # at most one frames_lost event per this many seconds: [daemon] frames_lost_quiet_s's default


class LossLog:
    """``observe(missing, frame_id, now)`` for every frame read, in order (``missing``: frames the
    counter skipped before ``frame_id``, usually 0)."""

    def __init__(self, on_event: Callable[[str, str], None], quiet_s: float = QUIET_S) -> None:
        self.on_event = on_event
        self.quiet_s = quiet_s
        self.total = 0  # since start: the stream's and the status's ``dropped``
        self._pending = 0  # lost since the last event, not yet logged
        self._gaps = 0
        self._first: int | None = None  # the frame after the first gap not yet logged
        self._last = 0
        self._logged_at = -math.inf

    def observe(self, missing: int, frame_id: int, now: float) -> None:
        if missing > 0:
            self.total += missing
            self._pending += missing
            self._gaps += 1
            self._first = frame_id if self._first is None else self._first
            self._last = frame_id
        if self._pending and now - self._logged_at >= self.quiet_s:
            self._log(now)

    def _log(self, now: float) -> None:
        n, gaps = self._pending, self._gaps
        where = (f"before frame {self._last}" if gaps == 1
                 else f"in {gaps} gaps between frames {self._first} and {self._last}")
        self.on_event("frames_lost", f"{n} camera frame{'s' if n != 1 else ''} lost {where} of the camera's frame "
                                     f"counter (the frame loop fell behind the camera, or the link lost them): "
                                     f"{self.total} since start")
        self._pending, self._gaps, self._first, self._logged_at = 0, 0, None, now
