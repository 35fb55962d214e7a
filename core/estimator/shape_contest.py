"""The light's shape at the first frames: as calibrated, or changed since, decided by the frames' evidence.

Over less than a period of the print a tilt or a bow of the light across the line looks like a shift of the image,
so how freely the shape may differ from calibration's at the first frame is the position's too. Held tight, a shape
that changed between calibration and the run (a lamp moved, an aperture knocked deeper, light uneven along a print
laid since) is taken as a shift: from the image alone 30-60 µm off under a 1-5 µm bound, unflagged. Held loose, the
first frames learn the shape from the model's own error at the places they see and carry it to the rest of the
stroke: a clean 16-row strip 5-12 % worse than the shape held as calibrated.

Both are followed side by side over the first frames, as two models of one multiple-model estimator: the estimator
holding the shape as calibrated (``field_prior``) and a rival allowing it changed (``field_changed_prior``). Each
frame's evidence for each is its update's marginal likelihood, the Gaussian's at the update: the cost at the
posterior (residual, prior and grating; the samples' misfit counted beside what calibration measured of the model's
own error there) and the Occam factor log det(P⁻·Λ⁺) that makes the looser prior pay for its room. The rival takes
over where the log-likelihood ratio passes half of χ²(2)'s quantile at the false-alarm rate (Wilks: two terms of the
shape freed) while its updates explain every frame; it is dropped where the ratio falls below minus that, or after
``shape_contest_frames`` frames without a verdict (the shape as calibrated stands: nothing said it changed). Only
from the image alone: read or fused, the grating places the carriage whatever the shape, and a lab strip's light
uneven along the stroke read as a shape changed at its first frame and carried on (1.16 → 1.52 of its floor).
"""

from __future__ import annotations

from typing import Any


class ShapeContest:
    """The rival estimator (the shape allowed to have changed) and the log-likelihood ratio of it over the
    estimator holding it as calibrated, frame by frame."""

    def __init__(self, rival: Any, threshold: float, frames: int) -> None:
        self.rival = rival
        self.threshold = threshold  # nats: half of χ²(2)'s quantile at the false-alarm rate
        self.left = frames
        self.ratio = 0.0  # nats: Σ log p(frame | rival) − log p(frame | as calibrated)
        self.unexplained = 0  # frames of the contest the rival's update did not explain

    def weigh(self, held: float, rival: float, explained: bool) -> str:
        """One frame's evidence (log-likelihoods) for each, and whether the rival's update explains the frame (its
        innovation within its test): "rival" where it takes over, "held" where the shape as calibrated stands and the
        contest ends, "" while it goes on. The rival takes over only while it has explained every frame: a shape that
        changed before the run is in every frame from the first, while a shape freed explains more of any misfit (a
        print mirrored, its tone curve changed, a model of another print), and a rival that fails a frame has found
        a misfit, not a shape."""
        if held == held and rival == rival:  # (a frame either could not weigh, acquired or not placed, says nothing)
            self.ratio += rival - held
        self.left -= 1
        self.unexplained += not explained
        if self.ratio > self.threshold and not self.unexplained:
            return "rival"
        if self.ratio < -self.threshold or self.left <= 0:
            return "held"
        return ""
