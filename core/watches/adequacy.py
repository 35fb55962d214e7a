"""A model that errs beyond its bound on its own calibration frames (core/adequacy.py) cannot
measure at its bound on any run: every position it gives is flagged, for ``geometry`` (the images
are not what the model describes), from the first frame on."""

from __future__ import annotations

from graytrack.core.adequacy import inadequacy
from graytrack.core.validity import FrameSign


class AdequacyWatch:
    family = "geometry"
    decisive = True
    reads = ()

    def observe(self, sign: FrameSign) -> str | None:
        return "geometry"

    def step(self) -> str | None:
        return "geometry"


def make(tracker) -> AdequacyWatch | None:
    return AdequacyWatch() if inadequacy(tracker.model.info) else None
