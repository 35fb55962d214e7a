"""A frame answered with a moving light feature followed (core/moving_light.py) is flagged ``light``.

Its position is measured, at 1.3–2× the clean print's bound on the paper rig, but the learned
shape's own error is larger than its noise says: over the shadow's frames the errors scatter at
1.8–2.0 of the joint bound (the shape is built frame by frame, smoothed, from a few frames at its
edges), and unflagged 0.2–1.4 % of the placed frames were 4+ bounds off. Until the shape's error is
measured from the frames themselves, the frame says what its answer rests on: the light is not the
calibration's, and a learned shape stands in for it.
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
