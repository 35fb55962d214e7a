"""A frame whose period is a guess is flagged ``period`` (core/period_rival.py).

Acquired without a grating, a print whose model has layers along the stroke can fit as well one
period on, where the model places it elsewhere than a whole period away (65 µm short on the paper
rig with a pitch error and a gradient): until the frames tell the two apart, the position is one of
two, and the frame says so. Decisive: the light and focus watches that fire at the wrong period
only describe how the wrong place fails.
"""

from __future__ import annotations

from graytrack.core.validity import FrameSign


class PeriodWatch:
    family = "period"
    decisive = True
    reads = ("placed", "period_guess")

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.period_guess)

    def step(self, placed: bool, period_guess: bool) -> str | None:
        return self.family if placed and period_guess else None


def make(tracker) -> PeriodWatch:
    return PeriodWatch()
