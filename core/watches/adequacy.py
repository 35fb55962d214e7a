"""A model that errs beyond its bound on its own calibration frames (core/adequacy.py) cannot
measure at its bound on any run: every position it gives is flagged from the first frame on, for
the family :func:`graytrack.core.adequacy.inadequacy` names (``geometry``, or ``pixels`` for a
JPEG stream whose quantisation accounts for the excess)."""

from __future__ import annotations

from graytrack.core.adequacy import inadequacy
from graytrack.core.validity import FrameSign


class AdequacyWatch:
    decisive = True

    def __init__(self, family: str) -> None:
        self.family = family

    def observe(self, sign: FrameSign) -> str | None:
        return self.family


def make(tracker) -> AdequacyWatch | None:
    family = inadequacy(tracker.model.info)
    return None if family is None else AdequacyWatch(family)
