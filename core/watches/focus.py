"""The focus watch: has the blur moved away from the one the model was calibrated at?

The tracker solves a change of focus δ (blur variance on the target, px²) when a frame's evidence
asks for it, and keeps x at its bound with δ profiled out; χ² then stays at the calibration's
level, so only δ itself can tell that the optics changed. One frame's δ is noisy (on a one-row
line its standard error is about the size of a half-pixel blur change), so the watch takes the
median of the last frames' estimates, each weighted by its precision, and blames ``focus`` while it is
both many of its standard errors away from zero (not noise) and larger than a change that
matters physically (not a statistically real but harmless drift on a long, precise run), and only
while the estimates hold still and the focus explains the frames: a light changing shape or a
print the model does not know also move the focus term a little, and are not a blur.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections import deque
from itertools import accumulate
from operator import itemgetter
from dataclasses import dataclass, field

import numpy as np

from graytrack.core.place_spread import WindowPlaces, model_share
from graytrack.core.validity import FrameSign

FOCUS_WINDOW = 50  # frames of focus estimates averaged
FOCUS_MIN_FRAMES = FOCUS_WINDOW  # estimates before the watch says anything: a sustained change
FOCUS_Z = 5.0  # standard errors of the window's mean beyond zero: a real change
# The window's location is its precision-weighted median (one wild frame, a glint or a lost lock,
# moves it by nothing); its standard error is the mean's times √(π/2), the median's efficiency.
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)
# A blur holds still from frame to frame: its estimates scatter about their median as their errors
# say (χ²/dof ≈ 1). Another change the focus term only mimics (a light changing shape, a print the
# model does not know) gives estimates that wander with x: beyond this the watch abstains.
FOCUS_SCATTER_LIMIT = 3.0
# ... and leaves the frames' χ² above the calibration's level even with the focus solved: beyond
# five spreads of one frame's χ², the focus does not explain the frames and the watch abstains.
FOCUS_FIT_SPREADS = 5.0
# Half a pixel of blur σ added to a sharp image is a variance of 0.25 px²: a change below that is
# within the smoothing the pixel's own footprint (variance 1/12 px²) and the print already do.
FOCUS_MIN_CHANGE_PX2 = 0.25


@dataclass
class FocusWatch:
    """``observe(sign) -> "focus" | None``: the window's precision-weighted median focus change is
    beyond ``z`` of its standard errors and beyond ``min_change_px2`` outside the range the model
    was calibrated over (``calibrated_px2``: a model calibrated with the focus effect saw the
    focus move by that much and is right over it). Frames with no estimate (the focus term was
    not needed) add nothing; after a whole window of them, the watch forgets."""

    window: int = FOCUS_WINDOW
    min_frames: int = FOCUS_MIN_FRAMES
    z: float = FOCUS_Z
    min_change_px2: float = FOCUS_MIN_CHANGE_PX2
    calibrated_px2: tuple[float, float] = (0.0, 0.0)
    chi2_limit: float = math.inf  # a frame's χ² (with the focus solved) beyond which it is not explained
    # of a frame's focus variance, the model's own at a place (core/place_spread.py): a window taken at one
    # place (a stage at rest) holds it whole, one spread over many places averages it
    place_share: float = 0.0
    family: str = "focus"
    _estimates: deque = field(default_factory=deque)  # (δ, 1/σ², χ², x)
    _places: WindowPlaces = field(default_factory=WindowPlaces, repr=False)  # the window's frames by place
    _missing: int = 0
    change_px2: float = float("nan")  # the window's median change, as last judged
    change_sigma_px2: float = float("nan")
    reads = ("focus", "focus_sigma", "chi2", "field", "x_mm")  # (a class attribute: not a field)

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.focus, sign.focus_sigma, sign.chi2, sign.field, sign.x_mm)

    def step(self, focus: float, sigma: float, chi2: float, field: bool, x_mm: float = math.nan) -> str | None:
        if math.isfinite(sigma) and sigma > 0.0 and math.isfinite(focus):
            self._estimates.append((focus, 1.0 / (sigma * sigma), chi2, x_mm))
            self._places.add(x_mm, 1.0 / (sigma * sigma))
            if len(self._estimates) > self.window:
                _, gone, _, at = self._estimates.popleft()
                self._places.remove(at, gone)
            self._missing = 0
        else:
            self._missing += 1
            # the tracker's evidence took a light field over the focus: the estimates were mimicry
            if self._missing >= self.window or field:
                self._estimates.clear()
                self._places.clear()
        if len(self._estimates) < self.min_frames:
            self.change_px2 = self.change_sigma_px2 = float("nan")
            return None
        ordered = sorted(self._estimates)
        cumulative = list(accumulate(map(itemgetter(1), ordered)))  # (C-level: this runs every focus frame)
        precision = cumulative[-1]
        self.change_px2 = ordered[bisect_left(cumulative, 0.5 * precision)][0]  # the precision-weighted median
        place_var = self.place_share * self._places.concentration(precision)  # the model's own focus at the places
        self.change_sigma_px2 = math.sqrt(MEDIAN_EFFICIENCY * MEDIAN_EFFICIENCY / precision + place_var)
        low, high = self.calibrated_px2
        beyond = max(low - self.change_px2, self.change_px2 - high)
        moved = abs(self.change_px2) > self.z * self.change_sigma_px2 and beyond > self.min_change_px2
        return self.family if moved and self._a_blur() else None

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once while the window cannot reach ``min_frames`` estimates
        within them (the common case: the focus solved on a few frames, or on none): nothing is
        judged, and the window's estimates, gaps and clearings follow as frame by frame. Else None:
        frame by frame."""
        sigma, focus = columns.array("focus_sigma", np.float64), columns.array("focus", np.float64)
        valid = np.isfinite(sigma) & (sigma > 0.0) & np.isfinite(focus)
        count = int(valid.sum())
        if len(self._estimates) + count >= self.min_frames or self.min_frames > self.window:
            return None
        frames = np.arange(n)
        last = np.maximum.accumulate(np.where(valid, frames, -1))  # the last frame with an estimate, so far
        missing = np.where(last >= 0, frames - last, self._missing + frames + 1)  # (on frames without one)
        cleared = ~valid & ((missing >= self.window) | columns.array("field", bool))
        if cleared.any():
            self._estimates.clear()
            self._places.clear()
            start = int(np.flatnonzero(cleared)[-1]) + 1
        else:
            start = 0
        if count:
            chi2, x = columns.array("chi2", np.float64), columns.array("x_mm", np.float64)
            kept = np.flatnonzero(valid[start:]) + start
            entering = list(zip(focus[kept].tolist(), (1.0 / (sigma[kept] * sigma[kept])).tolist(),
                                chi2[kept].tolist(), x[kept].tolist()))
            self._estimates.extend(entering)
            for _, weight, _, at in entering:
                self._places.add(at, weight)
        self._missing = int(missing[-1]) if not valid[-1] else 0
        self.change_px2 = self.change_sigma_px2 = float("nan")
        return [None] * n

    def _a_blur(self) -> bool:
        """The window's estimates hold still (scatter about their median as their errors say) and
        the focus explains the frames (their median χ² within the limit)."""
        n = len(self._estimates)
        scatter = sum(p * (d - self.change_px2) ** 2 for d, p, _, _ in self._estimates) / max(n - 1, 1)
        chi2 = sorted(c for _, _, c, _ in self._estimates)[n // 2]
        return scatter < FOCUS_SCATTER_LIMIT and not chi2 > self.chi2_limit

    @classmethod
    def for_model(cls, model, chi2_calibration: float = math.nan) -> "FocusWatch":
        """The watch for a calibrated model: the range of focus its calibration saw, if it fitted
        one, and the χ² its frames should come back to with the focus solved."""
        seen = model.info.get("calibration_focus_range_px2")
        limit = chi2_calibration * (1.0 + FOCUS_FIT_SPREADS * math.sqrt(2.0 / (model.n_rows * model.n_pixels)))
        return cls(calibrated_px2=(float(seen[0]), float(seen[1])) if seen else (0.0, 0.0),
                   chi2_limit=limit if math.isfinite(limit) else math.inf, place_share=model_share(model))


def make(tracker) -> FocusWatch | None:
    """The monitor's focus watch: only a tracker that solves a focus term has estimates to watch."""
    if not getattr(tracker, "focus_capable", False):
        return None
    return FocusWatch.for_model(tracker.model, tracker.chi2_calibration)
