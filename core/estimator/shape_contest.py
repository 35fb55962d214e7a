"""The rig at the first frames: as calibrated, or changed since in one of its families, decided by the frames'
evidence.

Over less than a period of the print a tilt or a bow of the light across the line looks like a shift of the image,
and a magnification other than calibration's stretches the image about a lens axis no frame sees: how freely such a
state may differ from calibration's at the first frame is the position's too. Held tight, a change between
calibration and the run (a lamp moved, an aperture knocked deeper, light uneven along a print laid since, a lens
refocused) is taken as a shift: from the image alone 30-60 µm off under a 1-5 µm bound, unflagged. Held loose, the
first frames learn the model's own error at the places they see and carry it along the stroke: a clean 16-row strip
5-12 % worse than held as calibrated.

So the estimator holding the rig as calibrated and a rival for each family that may have changed since (its states
at the priors of a changed rig: ``field_changed_prior``, ``stretch_changed_prior``) are followed side by side over
the first frames, as models of one multiple-model estimator. Each frame's evidence for each is its update's marginal
likelihood, the Gaussian's at the update: the cost at the posterior (residual, prior and grating; the samples'
misfit counted beside what calibration measured of the model's own error there) and the Occam factor
log det(P⁻·Λ⁺) that makes a looser prior pay for its room. A rival takes over where its log-likelihood ratio over
the held estimator passes half of χ²(k)'s quantile at the false-alarm rate (Wilks: its k states freed) while its
updates explain every frame; it drops out where its ratio falls below minus that, and the contest ends when none is
left or after ``shape_contest_frames`` frames (the rig as calibrated stands: nothing said it changed). Only from the
image alone: read or fused, the grating places the carriage whatever the shape, and a lab strip's light uneven along
the stroke read as a shape changed at its first frame and carried on (1.16 → 1.52 of its floor).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class Rival:
    """One family's rival: its estimator, the threshold it must pass (nats), what changed in it (said in the frame's
    message where it takes over), its log-likelihood ratio over the held estimator so far and the frames of the
    contest its updates did not explain."""

    estimator: Any
    threshold: float
    what: str = ""
    ratio: float = 0.0
    unexplained: int = 0


class ShapeContest:
    """The rivals still in the contest and the frames it has left."""

    def __init__(self, rivals: list[Rival], frames: int) -> None:
        self.rivals = rivals
        self.left = frames

    def weigh(self, held: float, evidence: list[float], explained: list[bool]) -> Rival | None | bool:
        """One frame's evidence (log-likelihoods) for the held estimator and for each rival in order, and whether each
        rival's update explains the frame (its innovation within its test). Returns the rival that takes over, True
        where the contest ends with the rig as calibrated, None while it goes on. A rival takes over only while it has
        explained every frame: a change before the run is in every frame from the first, while states freed explain
        more of any misfit (a print mirrored, its tone curve changed), and a rival that fails a frame has found a
        misfit, not a change. A frame either could not weigh (acquired, not placed: NaN) says nothing."""
        self.left -= 1
        for rival, own, ok in zip(self.rivals, evidence, explained):
            if held == held and own == own:
                rival.ratio += own - held
            rival.unexplained += not ok
        taking = [rival for rival in self.rivals if rival.ratio > rival.threshold and not rival.unexplained]
        if taking:
            return max(taking, key=lambda rival: rival.ratio - rival.threshold)
        self.rivals = [rival for rival in self.rivals if rival.ratio >= -rival.threshold]
        return True if not self.rivals or self.left <= 0 else None
