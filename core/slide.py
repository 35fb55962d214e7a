"""The slide a magnification change may give the image while no grating vouches for the positions.

A lens whose magnification moves by m scales the image about its optical axis; with the axis a lever
L (on the target) off the ROI's centre the whole image slides by m·L, which no image can tell from a
move of the stage (core/stretch.py). Without a grating only the stretch that comes with it is seen,
and slowly: one 16-row frame knows m to ~490 ppm, the magnification watch's 50-frame mean to ~60
(core/watches/magnification.py), the model's own structure beside; with the axis 300 px off a
16-row frame is 4 bounds off at ~80 ppm, a one-row paper frame at ~330. Flagging alone cannot catch
the first frames of a drift: the watch's mean tells a ramp of 3 ppm a frame only 30-200 frames after
its frames are off, and no test on these stretches does much better (docs/robustness.md).

So while no grating vouches, each placed frame's bound carries what the stretch the frames allow
now could slide the image by: L × √(m̄² + σ_m²), the watch's mean and its σ in quadrature (the
expected square of a slide the positions do not take out), the largest of the last :data:`HOLD`
frames'. A steady run then carries the slide the frames cannot rule out; a drift's bound grows with
the stretch the mean has started to see, until the watch flags it. With a grating read the slide is
the grating's to see (core/watches/scale.py), and nothing is added.

The lever is the camera's geometry: the optical axis (the sensor's centre, for a lens centred on
it) from the ROI's centre along the line, in pixels (``track --axis-px``). Undeclared, it is taken
as :data:`AXIS_PRIOR_PX`: an ROI a quarter of a 1280-px sensor off its centre (the virtual rig's
default); an ROI on the axis declares 0 and carries nothing.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from graytrack.core.watches.magnification import MagnificationWatch
from graytrack.core.watches.scale import ScaleWatch

# pixels: the optical axis from the ROI's centre when the rig does not say (the estimator's ``lever_prior`` is the
# same prior: core/estimator/settings.py; importing it here would load the estimator's kernels with the watches)
AXIS_PRIOR_PX = 300.0
# frames the largest stretch the frames allowed is held for: the watch's mean can dip for some frames
# where its estimate errs with the print's phase (a one-row paper rig's temperature cycle read 150 ppm
# at its second rise, truth 1100: 7 frames 4+ bounds off unflagged), while a lens cannot cool that fast
HOLD = 20


class SlideWatch:
    """The magnification watch, stepped here, with each frame's slide σ kept (µm; 0 where a grating
    reading vouches for the frame): handed to a tracker that reads no grating in place of its own
    magnification and scale watches (``replaces``: core/validity.py ``monitor_for``; the scale watch
    has no camera − grating to judge and would carry a magnification watch of its own), its verdicts
    the magnification watch's. A frame shown to no watch (a repeated image) keeps the σ of the frame
    before it (:func:`carry`)."""

    family = "magnification"
    reads = ("frame", "placed", "x_mm", "stretch", "reference_mm")

    def __init__(self, watch: MagnificationWatch, lever_mm: float, declared: bool = True, keep: bool = True) -> None:
        """``keep``: every frame's σ kept (a recording's column); the daemon's stream keeps only the newest."""
        self.watch = watch
        self.lever_mm = abs(lever_mm)
        self.replaces = (type(watch).__module__, ScaleWatch.__module__)
        self.sigma_um: dict[int, float] = {}  # frame → the slide's σ, µm (with ``keep``)
        self.last_um = math.nan  # the newest frame's σ (a repeated image keeps it)
        self.keep = keep
        self.declared = declared  # the lever is the rig's (False: the prior's)
        self._recent: deque[float] = deque(maxlen=HOLD)  # ppm: the rms stretch of the last frames

    @classmethod
    def for_model(cls, model, axis_px: float | None = None, keep: bool = True) -> "SlideWatch":
        """The model's magnification watch with the lever ``axis_px`` pixel footprints (None: the prior)."""
        lever_px = AXIS_PRIOR_PX if axis_px is None else float(axis_px)
        return cls(MagnificationWatch.for_model(model, unplaced=True), lever_px * model.pixel_pitch_mm,
                   declared=axis_px is not None, keep=keep)

    def observe(self, sign) -> str | None:
        return self.step(sign.frame, sign.placed, sign.x_mm, sign.stretch, sign.reference_mm)

    def step(self, frame: int, placed: bool, x_mm: float, stretch, reference_mm: float) -> str | None:
        verdict = self.watch.step(placed, x_mm, stretch)
        self._recent.append(self.watch.rms_ppm)
        vouched = math.isfinite(reference_mm)
        self.last_um = 0.0 if vouched else self.lever_mm * 1e3 * max(self._recent) * 1e-6
        if self.keep:
            self.sigma_um[frame] = self.last_um
        return verdict


def carry(result, slide: SlideWatch | None) -> dict[str, np.ndarray]:
    """The slide's σ taken into ``result``'s bounds in place (in quadrature), and the column that says
    it (``slide_sigma_um``; NaN without a slide watch or a frame it saw). A frame it was not shown
    keeps the σ of the one before (the first frames, of the first it saw)."""
    n = result.x_mm.size
    shown = {k: v for k, v in (slide.sigma_um.items() if slide is not None else ()) if 0 <= k < n}
    if not shown:
        return {"slide_sigma_um": np.full(n, np.nan)}
    at = np.full(n, -1)
    at[list(shown)] = np.arange(len(shown))
    last = np.maximum.accumulate(at)  # each frame's own σ, else the last shown before it
    sigma_um = np.array(list(shown.values()))[np.where(last >= 0, last, at[at >= 0][0])]
    result.crlb_mm[:] = np.sqrt(result.crlb_mm ** 2 + (sigma_um * 1e-3) ** 2)
    return {"slide_sigma_um": sigma_um}


def describe(lever_mm: float, declared: bool, columns: dict[str, np.ndarray]) -> list[str]:
    """The line ``graytrack track`` prints about the slide its bounds carry, the optical axis ``lever_mm`` from the
    ROI's centre (``declared`` by the rig, else the prior's); none where no column says a slide."""
    sigma_um = columns.get("slide_sigma_um")
    if sigma_um is None or not np.isfinite(sigma_um).any():
        return []
    source = "declared" if declared else f"the prior {AXIS_PRIOR_PX:.0f} px; declare it with --axis-px"
    return [f"slide   no grating read: each bound carries what a magnification change could slide the image by, "
            f"the optical axis {lever_mm:.2f} mm from the ROI's centre ({source}): median "
            f"{np.nanmedian(sigma_um):.2f} um, max {np.nanmax(sigma_um):.2f} um (slide_sigma_um, in crlb_um)"]
