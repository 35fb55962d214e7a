"""The daemon on a rig without a grating (``[daemon] grating = false``): each streamed bound carries the slide.

A lens whose magnification moves slides the image by m × the optical axis's distance from the ROI
(core/slide.py), which no image tells from a move of the stage; with a grating the daemon's scale
watch sees it (service/daemon/trim.py). Without one, ``graytrack track --no-reference`` carries in
each bound what the stretch the frames allow could slide the image by; the daemon does the same here:
a :class:`~graytrack.core.slide.SlideWatch` is made for each model (:meth:`watch_for`) and handed to
its :class:`~graytrack.core.tracking.LiveTracker` through its constructor in place of the scale
watch (fed there by the validity monitor, which also flags ``magnification`` on its verdicts), and
each fix's bound is widened by the newest σ on the frame loop (:meth:`apply`, O(1)). The stage's
``POS?`` is then no grating: the frames are tracked and streamed without it (no ``reference_mm``,
no ``error_um``), the calibration sweep still stops at it.

The lever is ``[daemon] axis_px`` (pixels from the ROI's centre to the optical axis along the line;
unset: core/slide.py's prior, 300 px; 0: the ROI on the axis, nothing carried).
"""

from __future__ import annotations

import math
import threading
from typing import Any

from graytrack.core.models.fourier import FourierModel
from graytrack.core.slide import AXIS_PRIOR_PX, SlideWatch
from graytrack.core.tracking import LiveFix
from graytrack.service.daemon.motion import CommandedMotion


class LiveSlide:
    """The daemon's side of the slide watch without a grating: made per model, its σ folded into each fix."""

    def __init__(self, axis_px: float | None = None, stage_acceleration_mm_s2: float | None = None,
                 motion: CommandedMotion | None = None) -> None:
        self.axis_px = axis_px  # None: the prior (core/slide.py AXIS_PRIOR_PX)
        self.stage_acceleration_mm_s2 = stage_acceleration_mm_s2  # None: the estimator's default
        # every motion of the stage commanded through the daemon (``[daemon] stage_commanded_here``): the estimator
        # engine's stage bends its path, and its mount test allows the stage's most, only while it was told to move
        # (motion.py); None: everywhere
        self.motion = motion
        self._told: object = None  # the tracker the phases were last handed to, and the stamp it has seen
        self._stamp = 0
        self._watch: SlideWatch | None = None
        self._stated_um = math.nan  # the slide the estimator's newest bound states (no watch then), µm
        self._lock = threading.Lock()  # the frame loop installs, HTTP threads read the status

    def watch_for(self, model: FourierModel) -> SlideWatch:
        """A new model's slide watch (only the newest σ kept: a daemon runs for days): hand it to the
        model's tracker (``LiveTracker(..., watches=)``), then :meth:`install` it with the tracker."""
        return SlideWatch.for_model(model, self.axis_px, keep=False)

    def install(self, watch: SlideWatch | None) -> None:
        with self._lock:
            self._watch = watch

    def hand_commands(self, tracker: object) -> None:
        """On the frame loop, before a frame: the phases commanded or closed since the last frame (every phase kept,
        to a tracker new since) to a tracker that takes them (the estimator's ``commanded``)."""
        motion = self.motion
        commanded = getattr(tracker, "commanded", None) if motion is not None else None
        if commanded is None:
            return
        if tracker is not self._told:
            self._told, self._stamp = tracker, 0
        self._stamp, phases = motion.since(self._stamp)  # type: ignore[union-attr]
        for start, end in phases:
            commanded(start, end, motion.acceleration_mm_s2)  # type: ignore[union-attr]

    def apply(self, fix: LiveFix, stated_um: float = math.nan) -> float:
        """After the tracker (whose monitor stepped the watch this frame): the fix's bound widened by the
        slide's σ in quadrature; returns that σ in µm (NaN before the first frame the watch saw). A tracker that
        states the slide in its own bound (the estimator) gives it as ``stated_um``: returned, not added again."""
        watch = self._watch
        if watch is None:
            self._stated_um = stated_um
            return stated_um
        sigma_um = watch.last_um
        if math.isfinite(sigma_um):
            fix.crlb_mm = math.hypot(fix.crlb_mm, sigma_um * 1e-3)
        return sigma_um

    def status(self) -> dict[str, Any]:
        """``/api/status``'s ``slide``: the lever and the σ the newest frame's bound carries."""
        with self._lock:
            watch = self._watch
        sigma_um = watch.last_um if watch is not None else self._stated_um
        return {"axis_px": AXIS_PRIOR_PX if self.axis_px is None else self.axis_px,
                "declared": self.axis_px is not None,
                "stage_commands_known": self.motion is not None,
                "lever_mm": watch.lever_mm if watch is not None else None,
                "sigma_um": sigma_um if math.isfinite(sigma_um) else None,
                "stretch_ppm": watch.watch.rms_ppm if watch is not None and math.isfinite(watch.watch.rms_ppm)
                else None}
