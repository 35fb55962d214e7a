"""The light itself: a lamp dimmed to less than half, or twice as bright, is measured (the light
is solved) but is no longer the rig that was calibrated: its noise, its saturation and its stray
light are not the calibration's. Sustained, that is stale for ``light``."""

from __future__ import annotations

from graytrack.core.validity import FrameSign, running

WINDOW = 50  # frames
GAIN_RANGE = (0.5, 2.0)


class LightWatch:
    family = "light"
    reads = ("placed", "free_light", "gain")

    def __init__(self) -> None:
        self.gain: float | None = None

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.free_light, sign.gain)

    def step(self, placed: bool, free_light: bool, gain: float) -> str | None:
        if not (placed and free_light):
            self.gain = running(self.gain, 1.0, WINDOW) if self.gain is not None else None
            return None
        self.gain = running(self.gain, gain, WINDOW)
        return None if GAIN_RANGE[0] < self.gain < GAIN_RANGE[1] else "light"

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once (compiled: core/watches/_kernels.py)."""
        import numpy as np

        from graytrack.core.watches import _kernels

        placed, free = columns.array("placed", bool), columns.array("free_light", bool)
        if self.gain is None and not (placed & free).any():
            return [None] * n  # nothing solved the light, and nothing to forget
        if not _kernels.COMPILED:
            return None
        state = np.array([self.gain is not None, self.gain or 0.0], dtype=np.float64)
        out = np.zeros(n, dtype=bool)
        _kernels._light_run(state, placed, free, columns.array("gain", np.float64), WINDOW, GAIN_RANGE[0],
                            GAIN_RANGE[1], out)
        self.gain = float(state[1]) if state[0] else None
        if not out.any():
            return [None] * n
        return ["light" if flagged else None for flagged in out.tolist()]


def make(tracker) -> LightWatch:
    return LightWatch()
