"""Map a camera's own timestamps onto the host's ``time.monotonic`` clock, online.

A GigE/USB3 camera stamps each frame on its own counter: exact spacing, but an unknown origin
and a rate a few ppm off the host's. The host knows when each frame *arrived*, which is the
device instant plus a delay that is never negative: a fixed part (readout, transfer) plus
scheduling jitter and, now and then, a frame delivered milliseconds late. So the pairs
(device time, host arrival) scatter *above* the line host = offset + rate · device, and that
line's lower envelope is the best estimate of the earliest arrival for any frame.

:class:`DeviceClockFit` keeps, for each slice of device time (a bin, 0.1 s by default), the
pair that arrived earliest relative to its stamp, over the last 64 bins (6.4 s). It fits offset
and rate by least squares on those minima, then keeps the minima at or below the median residual
and refits, down to 4 of them, so that a bin whose every frame came late (a stall; a slow camera
with one frame per bin) falls out. The result maps a frame's device timestamp to a host arrival
time free of the jitter and drift that stamping frames with their receive time would carry. A
device clock that jumps backwards (a camera reset) or far ahead (a stopped stream) restarts it.
"""

from __future__ import annotations

from collections import deque

import numpy as np

BIN_S = 0.1  # device time per bin: at 1 kHz the earliest of 100 arrivals, at 10 Hz one frame
N_BINS = 64  # bins kept: 6.4 s, long enough to see drift, short enough to follow it
MIN_KEPT = 4  # the envelope is never fitted on fewer bins than this
GAP_RESTART_S = 10.0  # a device-time gap this long (or any step backwards) restarts the fit


class DeviceClockFit:
    """Online offset-and-rate fit from device timestamps (integer ns) to host seconds."""

    def __init__(self, bin_s: float = BIN_S, n_bins: int = N_BINS) -> None:
        self._bin_ns = max(1, int(bin_s * 1e9))
        self._bins: deque[tuple[int, int, float]] = deque(maxlen=max(n_bins, 2))  # (bin, device ns, host s)
        self._origin_ns: int | None = None
        self._last_ns: int | None = None
        self._offset = 0.0  # host seconds at the device-time origin
        self._rate = 1.0  # host seconds per device second
        self._spread = 0.0  # rms residual of the kept minima about the line, seconds
        self._established = False
        self.restarts = 0

    @property
    def n_bins(self) -> int:
        return len(self._bins)

    @property
    def rate(self) -> float:
        """Host seconds per device second (1 + drift)."""
        return self._rate

    @property
    def established(self) -> bool:
        """Enough bins (``2 * MIN_KEPT``) for an envelope; before that, rate 1 and the earliest arrival."""
        return self._established

    @property
    def spread_s(self) -> float:
        """Scatter of the kept minima about the line (rms), or, before the fit is established, the
        range of lateness seen so far: the fit's own timing uncertainty."""
        return self._spread

    def add(self, device_ns: int, host_s: float) -> None:
        """One frame: its device timestamp and the host time it arrived."""
        if self._last_ns is not None and not 0 < device_ns - self._last_ns < GAP_RESTART_S * 1e9:
            self._bins.clear()
            self._established = False
            self.restarts += 1
        if not self._bins:
            self._origin_ns = device_ns
        self._last_ns = device_ns
        assert self._origin_ns is not None
        index = (device_ns - self._origin_ns) // self._bin_ns
        if self._bins and self._bins[-1][0] == index:
            _, d, h = self._bins[-1]
            if host_s - device_ns * 1e-9 >= h - d * 1e-9:
                return  # not earlier than this bin's minimum: the line does not move
            self._bins[-1] = (index, device_ns, host_s)
        else:
            self._bins.append((index, device_ns, host_s))
        self._fit()

    def host_time(self, device_ns: int) -> float:
        """The envelope's host time for a device timestamp (the earliest-arrival estimate)."""
        if self._origin_ns is None:
            raise ValueError("no (device, host) pair yet")
        return self._offset + self._rate * (device_ns - self._origin_ns) * 1e-9

    def _fit(self) -> None:
        assert self._origin_ns is not None
        # The newest bin is still filling: its minimum is not settled, so it joins the fit only
        # while there is nothing else to go by.
        settled = list(self._bins)[:-1] if len(self._bins) > 2 else self._bins
        device = np.array([d - self._origin_ns for _, d, _ in settled], dtype=np.float64) * 1e-9
        host = np.array([h for _, _, h in settled], dtype=np.float64)
        if device.size < 2 * MIN_KEPT:
            # Too few bins to tell drift from a late frame: nominal rate, earliest arrival seen.
            lateness = host - device
            self._offset, self._rate = float(lateness.min()), 1.0
            self._spread = float(np.ptp(lateness))
            self._established = False
            return
        offset, rate, residual = _line(device, host)
        keep = np.ones(device.size, dtype=bool)
        while keep.sum() >= 2 * MIN_KEPT:
            keep &= residual <= np.median(residual[keep])
            offset, rate, residual = _line(device[keep], host[keep], device, host)
        self._offset, self._rate = offset, rate
        self._spread = float(np.sqrt(np.mean(residual[keep] ** 2)))
        self._established = True


def _line(x: np.ndarray, y: np.ndarray, x_all: np.ndarray | None = None,
          y_all: np.ndarray | None = None) -> tuple[float, float, np.ndarray]:
    """Least-squares y = a + b x on (x, y); residuals on (x_all, y_all) (default the same)."""
    x_mean, y_mean = x.mean(), y.mean()
    dx = x - x_mean
    b = float(dx @ (y - y_mean) / (dx @ dx))
    a = float(y_mean - b * x_mean)
    if x_all is None or y_all is None:
        x_all, y_all = x, y
    return a, b, y_all - (a + b * x_all)
