"""A frame answered with a shadow's band followed (core/moving_band.py) is flagged ``light``.

Its position is measured, its bound the joint one (the band's shape and motion profiled out), but
the answer rests on a model of the light the calibration never saw: a band of shadow of learned
depth and softness whose edges move as a Kalman filter predicts. When the band is taken for
something it is not (a lamp's vignetting near the line's end, taken for a band that moved) the
answer can be off by more than its bound; the frame says what its answer rests on.
"""

from __future__ import annotations

from graytrack.core.validity import FrameSign


class MovingLightWatch:
    family = "light"
    reads = ("placed", "moving")

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.moving)

    def step(self, placed: bool, moving: bool) -> str | None:
        return self.family if placed and moving else None


def make(tracker) -> MovingLightWatch | None:
    return MovingLightWatch() if tracker.light == "auto" else None
