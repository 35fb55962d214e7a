"""The frame rate the status page and ``/metrics`` show, over a window that never spans an outage.

A window of the last few hundred arrivals averages the rate smoothly, but after the camera was
silent for a while the same window straddles the silence: 200 frames at 50 Hz plus a 5 s gap read
as 21 Hz for the four seconds the window takes to refill. So an arrival after a gap much longer
than the window's own frame period (or after :meth:`FrameRate.restart`, which the frame loop calls
when it reopens the camera) starts a new window: the rate after a recovery is the rate since the
recovery. Times come from the caller, so tests need no sleeps: the daemon passes each frame's
mid-exposure on ``time.monotonic()`` (``Frame.t_host``), not the moment the loop got it, so a loop
stalled for a moment and then draining the camera's backlog neither restarts the window nor reads
the burst as a rate of thousands.
"""

from __future__ import annotations

from collections import deque

RATE_WINDOW = 200  # arrivals averaged over
OUTAGE_PERIODS = 10.0  # a gap this many mean frame periods long is an outage, not jitter or a dropped frame


class FrameRate:
    """Frames per second over the arrivals since the last outage (at most ``window`` of them)."""

    def __init__(self, window: int = RATE_WINDOW, outage_periods: float = OUTAGE_PERIODS) -> None:
        if window < 2:
            raise ValueError(f"a frame-rate window needs at least 2 arrivals, not {window}")
        self.outage_periods = outage_periods
        self._arrivals: deque[float] = deque(maxlen=window)

    def arrive(self, t: float) -> None:
        """One frame arrived at ``t``; a gap far beyond the window's frame period restarts the window."""
        arrivals = self._arrivals
        if arrivals and t <= arrivals[-1]:
            return  # a repeated frame (same exposure) adds no interval
        if len(arrivals) >= 2:
            period = (arrivals[-1] - arrivals[0]) / (len(arrivals) - 1)
            if period > 0 and t - arrivals[-1] > self.outage_periods * period:
                arrivals.clear()
        arrivals.append(t)

    def restart(self) -> None:
        """Forget the window (the camera was reopened): the next rate is the rate after it."""
        self._arrivals.clear()

    def hz(self, now: float, stale_after_s: float) -> float:
        """The rate over the window; 0 with fewer than two arrivals or when the newest is older than
        ``stale_after_s``."""
        arrivals = list(self._arrivals)  # a copy: the frame loop appends from its own thread
        if len(arrivals) < 2 or arrivals[-1] <= arrivals[0] or now - arrivals[-1] > stale_after_s:
            return 0.0
        return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
