"""The period a run without a grating started in, followed while the image alone cannot tell it.

A print repeats its image once a period: a run acquired on the image alone knows its origin up to
whole periods, which costs nothing where the model is periodic (a whole period off is the origin's
convention, not an error). A model with layers along the stroke (a pitch error, a gradient, a
target map: what the closed loop adds) is not: at the other period its image is the same but
shifted, and with the light solved its fit is as good. On the paper rig with a 500 ppm pitch and an
8 %/10 mm gradient the acquisition took the period 8.62 mm away, 65 µm short of a whole one (45
bounds): 121 of 436 placed frames 4+ bounds off the truth without a flag until the stroke layer at
the wrong place failed, the lock was lost and found again 8.6 mm away.

So when the acquisition's rival is not a whole period away (beyond ``RIVAL_BOUNDS`` of the frame's
bound), both are followed: each frame the rival is solved as the chosen one was (light solved or
held as the tracker held it, from the chosen position plus the rival's offset), and the χ² each
leaves is summed. Until one leads by the acquisition's own ambiguity margin, the frame says its
period is a guess (``period_guess``; core/watches/period.py flags it); then the loser is dropped, and
if it was the chosen one the tracker moves to the rival (logged). The light can tell them apart only
over frames: the wrong period's image needs another light (7 % dimmer there), which a light solved
per frame absorbs, and its layers drift apart from the frames' as the stage moves (on the run
above, ~90 frames for the χ² to lead by 25).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from graytrack.core.models.fourier import FourierModel
from graytrack.core.solvers import FrameSolution, GeneralBatch, SolverSettings, TrigPolyBatch, gauss_newton

RIVAL_BOUNDS = 4.0  # a rival this many of the frame's bounds off a whole period gives another position


def repeats(model: FourierModel) -> bool:
    """True when the prediction at x + τ equals that at x: a period shift changes nothing but x (no
    layer along the stroke, no target map)."""
    return not model.stroke_degree and model.target_map is None


@dataclass
class PeriodRival:
    """The acquisition's rival period: its offset from the chosen position (mm) and the evidence
    Σ (χ²_rival − χ²_chosen) over the frames followed (> 0: the chosen one fits better)."""

    offset_mm: float
    margin: float  # the evidence that settles it (the acquisition's ambiguity margin, χ²)
    evidence: float = 0.0
    frames: int = 0

    @classmethod
    def opened(cls, offset_mm: float, solution: FrameSolution, model: FourierModel,
               margin: float) -> "PeriodRival | None":
        """The rival to follow, or None when only the origin is a guess: a whole period away
        (within the frame's bound) on a model that repeats with the print, as any periodic print
        read without a grating. A model with layers along the stroke does not repeat: a whole
        period on, its layers are elsewhere, and the frames will tell (the seed rig's gain hunting
        with the closed loop's stroke layer: the wrong period held 147 frames, then its layers
        failed past the stroke's end and the lock was found again a period away)."""
        if not (math.isfinite(offset_mm) and solution.information > 0):
            return None
        beyond = offset_mm - model.period_mm * round(offset_mm / model.period_mm)
        if abs(beyond) * math.sqrt(solution.information) <= RIVAL_BOUNDS and repeats(model):
            return None
        return cls(offset_mm, margin)

    def weigh(self, batch: "GeneralBatch | TrigPolyBatch", k: int, solution: FrameSolution,
              settings: SolverSettings) -> str | None:
        """Batch frame ``k``, answered by ``solution``, as evidence: "chosen" or "rival" once one
        leads by the margin, None while it is still a guess. Both are solved the same way (plain
        Gauss–Newton, the light as the answer had it) so that their χ² compare."""
        free = solution.free_light
        chosen = gauss_newton(batch, k, solution.x_mm, free, settings)
        rival = gauss_newton(batch, k, solution.x_mm + self.offset_mm, free, settings)
        samples = batch.scalars(k)[3]
        if not math.isfinite(rival.chi2):
            return "chosen"
        if math.isfinite(chosen.chi2):
            self.evidence += (rival.chi2 - chosen.chi2) * samples
            self.offset_mm = rival.x_mm - chosen.x_mm
        self.frames += 1
        if self.evidence > self.margin:
            return "chosen"
        return "rival" if self.evidence < -self.margin else None

    def describe(self) -> str:
        return (f"the period told apart over {self.frames} frames: the rival {self.offset_mm:+.3f} mm away fits "
                f"{-self.evidence:.0f} χ² better")
