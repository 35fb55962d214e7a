"""The ``scale`` watch: the camera against the grating, when frames come with a grating reading.

The model can fit every image perfectly while the target itself has grown or the camera has moved
along the axis: only an outside ruler sees that. This watch feeds each frame's position, grating
reading and bound to a :class:`~graytrack.core.reference_monitor.ReferenceMonitor` and blames
``scale`` while the monitor finds the line camera − grating drifted beyond its uncertainty.

With an online trim (the daemon's ``[daemon] trim``) the trim's owner drives its own monitor and
hands the tracker a watch reading it (``tracker.scale_watch``): a frame is counted once, and drift
is then measured against the trim in force.
"""

from __future__ import annotations

import math

from graytrack.core.compression import stream_bound_factor
from graytrack.core.reference_monitor import ReferenceMonitor, scale_tells
from graytrack.core.validity import FrameSign


class ScaleWatch:
    """``observe(sign) -> "scale" | None`` from ``sign.x_mm``, ``sign.reference_mm``, ``sign.information``."""

    family = "scale"
    reads = ("chi2_suspect", "placed", "x_mm", "reference_mm", "information")

    def __init__(self, monitor: ReferenceMonitor, feeds: bool = True, bound_scale: float = 1.0) -> None:
        self.monitor = monitor
        self.feeds = feeds
        self.bound_scale = bound_scale  # the frames' bound over the sensor's (a JPEG stream's quantisation)

    @classmethod
    def for_model(cls, model, reference_resolution_mm: float = 0.0, **options) -> "ScaleWatch":
        """A watch centred on the model's calibrated stroke (its scale is measured about the centre,
        its floor over the whole stroke); ``reference_resolution_mm``: the grating's step, if known."""
        return cls(ReferenceMonitor.for_model(model, reference_resolution_mm, **options),
                   bound_scale=stream_bound_factor(model.info))

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.chi2_suspect, sign.placed, sign.x_mm, sign.reference_mm, sign.information)

    def step(self, chi2_suspect: bool, placed: bool, x_mm: float, reference_mm: float,
             information: float) -> str | None:
        # While χ² says the images changed, a disagreement with the grating is its consequence, not a
        # scale: those frames are not fed. But a disagreement already found stays a flag: the camera
        # is off the grating and the images are not the calibration's, so the model does not describe
        # the rig (geometry), even while χ² has not yet crossed its own stale limit.
        if chi2_suspect:
            return "geometry" if self.monitor.stale else None
        if self.feeds and placed:
            bound = self.bound_scale / math.sqrt(information) if information > 0 else float("nan")
            self.monitor.observe(x_mm, reference_mm, bound)
        return self.family if self.monitor.stale else None

    def step_many(self, columns, n: int) -> list[str | None]:
        """:meth:`step` of ``n`` frames at once (the monitor's :meth:`~ReferenceMonitor.observe_many`)."""
        import numpy as np

        suspect = columns.array("chi2_suspect", bool)
        information = columns.array("information", np.float64)
        feed = columns.array("placed", bool) & ~suspect if self.feeds else np.zeros(n, dtype=bool)
        positive = information > 0
        bound = np.where(positive, self.bound_scale / np.sqrt(np.where(positive, information, 1.0)), np.nan)
        stale = self.monitor.observe_many(columns.array("x_mm", np.float64), columns.array("reference_mm", np.float64),
                                          bound, feed)
        if not stale.any():
            return [None] * n
        families = np.full(n, None, dtype=object)
        families[stale & ~suspect] = self.family
        families[stale & suspect] = "geometry"
        return families.tolist()


def make(tracker) -> "ScaleWatch | object | None":
    """The tracker's scale watch: the one its owner handed it (``scale_watch``), else one of its own;
    none for a model already off its bound on its own calibration (the adequacy watch has it)."""
    if not scale_tells(tracker.model):
        return None
    shared = getattr(tracker, "scale_watch", None)
    return shared if shared is not None else ScaleWatch.for_model(tracker.model)
