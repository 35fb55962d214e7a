"""One frame that says itself the model does not describe it, before the running χ² says so.

The running χ² (over about a hundred frames) takes a few frames to rise beyond the stale limit
when a change comes into view, and those first frames are the ones a change bends most: a cable's
shadow entering the field placed frames 8 bounds off at a χ² 1.8 times the calibration's, and a
light field taken for it (its shape mimicking the shadow's edge) 6 bounds off at χ² 0.7, neither
flagged without a grating. A frame is flagged on its own evidence when

- its own χ² is beyond five of its spreads above the calibration's level, and beyond five of the
  spreads the last frames' χ² actually show above their mean (a rig whose frames scatter more than
  the noise model says, a strip with row banding, is not flagged frame after frame for it; at four,
  the steady 16-row strip with row banding had 3 of 500 frames flagged);
- or, while the running χ² is beyond its own spread (suspect), its own χ² is beyond three spreads
  (one frame in 700 by chance, and only while the average already says something changed);
- or, while suspect, its answer is a light field's: a field taken while χ² is still rising is one
  whose shape has not been seen to hold still, and it trades that shape against x.

It blames ``geometry`` (the images are not what the model describes), the least specific family:
a watch that reads the cause over frames (the χ² watch's residual shapes, held to what stays still)
names it over this one. One frame's residual cannot: on a line shorter than a period the light's
shapes mimic a changed print too, which named ``light`` frame by frame.

A model whose χ² level varies along the stroke (core/chi2_curve.py) holds each frame against its
own level, which this watch does not know: there only the light-field rule applies.
"""

from __future__ import annotations

import math

from graytrack.core.validity import FrameSign

SUSPECT_SPREADS, ALONE_SPREADS = 3.0, 5.0
WINDOW = 100  # frames over which the frames' own χ² scatter is followed


class FrameFitWatch:
    family = "geometry"
    reads = ("placed", "chi2", "field", "chi2_suspect")

    def __init__(self, calibration: float = math.inf, spread: float = 0.0) -> None:
        self.suspect_limit = calibration * (1.0 + SUSPECT_SPREADS * spread)  # inf: no χ² rule (see above)
        self.alone_limit = calibration * (1.0 + ALONE_SPREADS * spread)
        self.mean, self.square = 1.0, 1.0  # the frames' χ² and its square, running
        if math.isfinite(calibration):
            self.mean, self.square = calibration, (calibration * spread) ** 2 + calibration**2

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.chi2, sign.field, sign.chi2_suspect)

    def step(self, placed: bool, chi2: float, field: bool, chi2_suspect: bool) -> str | None:
        if not placed:
            return None
        if chi2_suspect and field:
            return self.family
        if not (math.isfinite(chi2) and math.isfinite(self.alone_limit)):
            return None
        scatter = math.sqrt(max(self.square - self.mean * self.mean, 0.0))
        alone = chi2 > self.alone_limit and chi2 > self.mean + ALONE_SPREADS * scatter
        if alone or (chi2_suspect and chi2 > self.suspect_limit):
            return self.family
        self.mean += (chi2 - self.mean) / WINDOW  # the frames that fit feed the scatter
        self.square += (chi2 * chi2 - self.square) / WINDOW
        return None


def make(tracker) -> FrameFitWatch:
    if tracker.chi2_curve is not None:
        return FrameFitWatch()
    return FrameFitWatch(tracker.chi2_calibration, math.sqrt(2.0 / (tracker.model.n_rows * tracker.model.n_pixels)))
