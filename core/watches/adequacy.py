"""A model that errs beyond its bound on its own calibration frames (core/adequacy.py) cannot
measure at its bound on any run: every position it gives is flagged, for ``geometry`` (the images
are not what the model describes), from the first frame on.

The same holds stretch by stretch along the stroke (``calibration_error_profile``): a model at its
bound over most of the stroke may err several bounds where the print has what it lacks (a
scratch, a flaw of the print the Fourier terms cannot follow). Its frames there are flagged on
every run, since the model will err there again: the global ratio would average them away.
"""

from __future__ import annotations

import bisect
import math

from graytrack.core.adequacy import INADEQUATE_RATIO, PROFILE_FRAMES, inadequacy
from graytrack.core.compression import judged_factor
from graytrack.core.period_rival import repeats
from graytrack.core.stroke_place import StrokePlace, folded, in_folded
from graytrack.core.validity import FrameSign

# a stretch is flagged beyond the global limit plus the ratio's own noise over its frames (an
# rms of ~PROFILE_FRAMES errors at the bound scatters by 1/√(2n)): a model at its bound is not
# flagged on the stretch its noise happened to lift
LOCAL_LIMIT = INADEQUATE_RATIO * (1.0 + 1.0 / math.sqrt(2.0 * PROFILE_FRAMES))


class AdequacyWatch:
    family = "geometry"
    decisive = True
    reads = ()

    def observe(self, sign: FrameSign) -> str | None:
        return "geometry"

    def step(self) -> str | None:
        return "geometry"


class LocalAdequacyWatch:
    """Flags the frames placed in a stretch of the stroke where the calibration erred beyond
    :data:`LOCAL_LIMIT` times its bound. With ``period_mm`` (a model that repeats once a period)
    and no grating reading yet, a frame's place is known only up to whole periods
    (core/stroke_place.py): it is flagged where a flagged stretch is at any of them."""

    family = "geometry"
    reads = ("placed", "x_mm", "reference_mm")

    def __init__(self, edges_mm: list[float], off: list[bool], period_mm: float | None = None) -> None:
        self.edges, self.off = edges_mm, off
        self.place = StrokePlace(period_mm)
        self._period_mm = period_mm or 0.0  # read only with the fold (a repeating model)
        self._folded = folded(edges_mm, off, period_mm) if period_mm else None

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.x_mm, sign.reference_mm)

    def step_many(self, columns, n: int) -> list[str | None]:
        """:meth:`step` of ``n`` frames at once (its one state, whether the place is known, carried)."""
        import numpy as np

        x = columns.array("x_mm", np.float64)
        placed = columns.array("placed", bool)
        known = self.place.see_many(columns.array("reference_mm", np.float64)) if "reference_mm" in columns \
            else np.full(n, self.place.known)
        edges = np.asarray(self.edges)
        inside = placed & (x >= edges[0]) & (x <= edges[-1])
        stretch = np.minimum(np.searchsorted(edges, np.where(inside, x, edges[0]), side="right") - 1, len(self.off) - 1)
        flagged = inside & np.asarray(self.off)[stretch]
        if self._folded is not None and not known.all():
            flagged |= placed & ~known & in_folded(x, edges[0], self._period_mm, *self._folded)
        return [self.family if f else None for f in flagged.tolist()]

    def step(self, placed: bool, x_mm: float, reference_mm: float = math.nan) -> str | None:
        known = self.place.see(reference_mm)
        if not placed or not math.isfinite(x_mm):
            return None
        if not known and self._folded is not None:
            return self.family if bool(in_folded(x_mm, self.edges[0], self._period_mm, *self._folded)) else None
        if not self.edges[0] <= x_mm <= self.edges[-1]:
            return None
        stretch = min(bisect.bisect_right(self.edges, x_mm) - 1, len(self.off) - 1)
        return self.family if self.off[stretch] else None


def make(tracker) -> AdequacyWatch | LocalAdequacyWatch | None:
    info = tracker.model.info
    if inadequacy(info):
        return AdequacyWatch()
    profile = info.get("calibration_error_profile")
    if not isinstance(profile, dict):
        return None
    limit = LOCAL_LIMIT * judged_factor(info)
    off = [ratio is not None and ratio > limit for ratio in profile.get("ratio", [])]
    edges = profile.get("edges_mm", [])
    if not any(off) or len(edges) != len(off) + 1:
        return None
    # without a grating a model that repeats is placed up to whole periods (core/stroke_place.py)
    period = float(tracker.model.period_mm) if repeats(tracker.model) else None
    return LocalAdequacyWatch([float(v) for v in edges], off, period)
