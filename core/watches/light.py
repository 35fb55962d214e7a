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


def make(tracker) -> LightWatch:
    return LightWatch()
