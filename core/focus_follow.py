"""The focus followed from frame to frame: what the last frames' blur estimates say about this one.

A focus drifts slowly (a lens mount warming up) or comes and goes (warming and cooling), and a
blur the model does not know moves the position before the frames' χ² shows it: on a 16-row strip
a blur variance 1.5 px² beyond calibration's placed frames 2-4 bounds off while each frame's χ²
was within a fifth of one frame's spread of the calibration's, and the running χ² average, which
alone asked for the focus term, only crossed its limit once the blur had grown to 2.4 px². One
frame's estimate of the blur δ has one degree of freedom where χ² has a hundred: averaged over
the last frames with its sign, it is the sensitive witness. So every frame of a tracker that can
solve the focus measures δ (core/focus_solve.py), and this record of those estimates

* says when the focus has moved (:meth:`FocusFollow.moved`: their precision-weighted mean beyond
  ``FOCUS_MOVED_Z`` of its standard error, the scatter of the estimates about their trend counted
  in it): the focus term is then the frame's answer whatever χ² says;
* gives the next frame's prior (:meth:`FocusFollow.prior`): a straight line through the
  estimates, weighted by precision and forgotten over ``FOLLOW_WINDOW`` frames, predicted at the
  frame, with the variance of that prediction (widened by the scatter beyond the estimates' own
  errors). A ramp is followed without the lag of a plain average (a rate times the average's age),
  and the prediction's variance enters the frame's normal equations, so the position's bound
  carries what the focus's uncertainty costs it.

A focus that comes back is forgotten as fast as it came: the mean follows the estimates back to
zero within the window, and the focus term is dropped once neither it nor the χ² it gains asks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from graytrack.core.compression import judged_factor
from graytrack.core.focus_solve import FocusPrior
from graytrack.core.watches.focus import FOCUS_WINDOW

# A model that places its own calibration frames beyond this many of their bounds (core/adequacy.py)
# leaves a residue that varies along the stroke, and part of it lies along the blur direction: its
# estimates move as the stage does, with no change of focus (the seed model under 2 gray of DSNU,
# 4.3x: the focus term taken on half the frames, 7.8x its bound). Its focus is followed only as
# before, when its frames' χ² asks. The models the closed loop grows are at 0.99-1.23.
FOLLOW_ADEQUACY = 1.5

FOLLOW_WINDOW = 20  # frames over which the estimates are forgotten (λ = 1 − 1/window a frame)
FOLLOW_PRIOR_FRAMES = 5  # estimates (discounted count) before they hold the next frame's focus
FOLLOW_TREND_FRAMES = 10  # ... before a trend is fitted through them (fewer: their mean)
# ... and before their mean is judged: a mean and a scatter of a few frames have heavy tails (a
# saturated crest set aside frame by frame moved the mean of 5 estimates "beyond 5 of its errors")
FOLLOW_MOVED_FRAMES = 0.8 * FOLLOW_WINDOW
# The mean's standard error over a window of ~2·window effectively independent frames: beyond five
# of them is no chance (two-sided 6e-7 a frame, ~1e-4 over a 500-frame steady run).
FOCUS_MOVED_Z = 5.0
# A try of the focus term opens the focus watch's window unless the estimates before it held the calibration's focus
# within this many of their errors: a blur coming back moves them first (a focus cycle), one frame's χ² spike does not
# (a clipped crest of the seed model under saturation opened it for 50 frames of a steady run). Only a try is gated,
# so a steady run's mean straying past 2σ now and then costs nothing; at 3 the paper rig's focus cycle under --trim
# was 1.11x its bound (its one-row estimates slower to stand out, the blur read as a stretch beside no focus), 0.97x so
HELD_Z = 2.0
# ... but a calibrated model's own error is no noise: fixed along the stroke and out of its calibration's
# sample, it reads as a steady blur of a few hundredths of a px² over stretches of the stroke (the closed
# loop's model on 3 scratches: +0.02 to +0.045 px² in 25-frame means over the last two thirds of a
# steady run, 2-7 of their errors, where its own calibration frames read 0.00 ± 0.01). So the mean
# is held against its error and this allowance together, as the magnification watch holds a stretch
# (core/watches/magnification.py STRUCTURE_PPM): a move is at least 5 × 0.02 = 0.1 px² (a 16-row
# strip's blur 1.5 px² beyond calibration's placed frames 2-4 bounds off: 0.1 px² is a tenth of a bound).
STRUCTURE_PX2 = 0.02


@dataclass
class FocusFollow:
    """Discounted weighted least squares of δ = a + b·t over the frames' estimates (t: frames, 0
    now, negative in the past), kept as sums that age by one frame per :meth:`add` or :meth:`wait`."""

    s0: float = 0.0  # Σ λ^age / σ²
    s1: float = 0.0  # Σ λ^age t / σ²
    s2: float = 0.0  # Σ λ^age t² / σ²
    y0: float = 0.0  # Σ λ^age δ / σ²
    y1: float = 0.0  # Σ λ^age t δ / σ²
    yy: float = 0.0  # Σ λ^age δ² / σ²
    count: float = 0.0  # Σ λ^age
    idle: int = 0  # frames since the last estimate
    reports: int = 0  # frames the estimates are still shown to the focus watch after the term was dropped

    def _age(self) -> None:
        """One frame later: every t down by one, every weight forgotten by λ."""
        keep = 1.0 - 1.0 / FOLLOW_WINDOW
        s0, s1 = self.s0, self.s1
        self.s2 = keep * (self.s2 - 2.0 * s1 + s0)
        self.s1 = keep * (s1 - s0)
        self.y1 = keep * (self.y1 - self.y0)
        self.s0, self.y0, self.yy, self.count = keep * s0, keep * self.y0, keep * self.yy, keep * self.count

    def add(self, delta: float, sigma: float) -> None:
        """This frame's estimate (δ and its standard error, in any one unit); a frame without a
        usable estimate only ages the record."""
        self._age()
        if not (math.isfinite(delta) and math.isfinite(sigma) and sigma > 0.0):
            self._idle()
            return
        weight = 1.0 / (sigma * sigma)
        self.s0 += weight
        self.y0 += weight * delta
        self.yy += weight * delta * delta
        self.count += 1.0
        self.idle = 0

    def wait(self) -> None:
        """A frame on which the focus was not measured."""
        self._age()
        self._idle()

    def _idle(self) -> None:
        self.idle += 1
        if self.idle > FOLLOW_WINDOW:  # a window without an estimate: what was known is gone
            self.s0 = self.s1 = self.s2 = self.y0 = self.y1 = self.yy = self.count = 0.0

    def _fit(self) -> tuple[float, float, float] | None:
        """(δ now, its variance, the scatter per degree of freedom of the estimates about the fit)."""
        if self.count < FOLLOW_PRIOR_FRAMES or self.s0 <= 0.0:
            return None
        determinant = self.s0 * self.s2 - self.s1 * self.s1
        if self.count >= FOLLOW_TREND_FRAMES and determinant > 1e-9 * self.s0 * self.s2:
            level = (self.s2 * self.y0 - self.s1 * self.y1) / determinant
            slope = (self.s0 * self.y1 - self.s1 * self.y0) / determinant
            residual = self.yy - level * self.y0 - slope * self.y1
            variance, dof = self.s2 / determinant, self.count - 2.0
        else:
            level = self.y0 / self.s0
            residual = self.yy - level * self.y0
            variance, dof = 1.0 / self.s0, self.count - 1.0
        scatter = max(1.0, residual / dof) if dof > 0.0 else 1.0
        return level, variance * scatter, scatter

    def prior(self) -> FocusPrior | None:
        """What the last frames say this frame's δ is (None: too few estimates yet)."""
        fit = self._fit()
        if fit is None or not fit[1] > 0.0:
            return None
        return FocusPrior(fit[0], fit[1])

    def moved(self, allowance: float = 0.0, z: float = FOCUS_MOVED_Z) -> bool:
        """The estimates' mean over the window is beyond ``z`` (:data:`FOCUS_MOVED_Z`) of its standard
        error from the calibration's focus (zero), ``allowance`` (the model's own error read as a focus,
        :data:`STRUCTURE_PX2` in the estimates' unit) counted in it: the focus has moved, whatever χ² says."""
        if self.count < FOLLOW_MOVED_FRAMES or self.s0 <= 0.0:
            return False
        mean = self.y0 / self.s0
        scatter = max(1.0, (self.yy - mean * self.y0) / max(self.count - 1.0, 1.0))
        return mean * mean > z * z * (scatter / self.s0 + allowance * allowance)

    def held(self, allowance: float = 0.0) -> bool:
        """The estimates say the focus is the calibration's: their mean within :data:`HELD_Z` of its
        error (with the scatter about it once they are as many as :meth:`moved` asks; before, against their
        stated errors: a run that starts blurred shows it on its first estimate, and a try on the first
        frame of a steady run opened the window on 50 frames). A try of the focus term on such a frame is
        its own χ²'s (a clipped crest, a telegraph pixel's flip), not a blur coming back."""
        if self.count >= FOLLOW_MOVED_FRAMES:
            return not self.moved(allowance, HELD_Z)
        if self.s0 <= 0.0:
            return False
        mean = self.y0 / self.s0  # too few for a scatter of their own: against their stated errors
        return mean * mean <= HELD_Z * HELD_Z * (1.0 / self.s0 + allowance * allowance)

    def shown(self, focus_on: bool) -> bool:
        """Whether this frame's estimate goes to the focus watch (core/watches/focus.py): while the
        focus term is on, and for a watch's window after it was dropped, so that the watch sees
        the focus come back rather than judge the last window it saw until it forgets it (a stale
        verdict for 50 frames). A steady focus is not shown: estimates taken on every frame of a
        model with a residue of its own (telegraph pixels) would be judged as a blur."""
        if focus_on:
            self.reports = FOCUS_WINDOW
            return True
        self.reports = max(self.reports - 1, 0)
        return self.reports > 0


def followable(info: dict) -> bool:
    """Whether a model's calibration leaves its focus estimates to be read as a blur: it places its
    own calibration frames within :data:`FOLLOW_ADEQUACY` of their bound, and it has no error of its
    own fixed along the stroke (``reference_structure_profile``, kept by core/calibration_line.py only
    where it stands out of its noise). A seed model under 1.5 gray of DSNU (1.18x, an error of 1.8 µm
    along the stroke) had its estimates "move" as the stage swept, and half of a steady run was
    flagged `focus`; telegraph pixels and a hunting gain leave such a profile too. A model with no
    adequacy figure is followed."""
    ratio = info.get("calibration_error_ratio")
    if ratio is not None and ratio / judged_factor(info) > FOLLOW_ADEQUACY:
        return False
    return not info.get("reference_structure_profile")
