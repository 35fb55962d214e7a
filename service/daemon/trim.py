"""The daemon's camera-against-grating watch and its optional online trim (``[daemon] trim``).

The daemon reads the grating with every frame, so it can always tell when the line camera −
grating has moved since calibration (a print grown in humidity, a camera shifted on its mount): a
``scale_drift`` event, and ``scale_ok`` when it holds again. With ``[daemon] trim = true`` it also
corrects the positions it streams, ``x' = x − (offset + scale·(x − x_c))``, with the estimate and
uncertainty of core/reference_monitor.py: only on evidence (``trim_applied``, with the figures),
refined in a few logged steps as the stage covers more of the stroke, shown in ``/api/status``
(``trim``) and in each stream message (``trim_um``, ``trim_sigma_um``), cleared by
``POST /api/trim/reset`` or by installing a new model (``trim_cleared``). Off by default: a
position that silently follows the grating is not what everyone wants from a second sensor.

Runs on the frame loop (``apply`` per frame, O(1)); ``reset`` and ``status`` come from HTTP
threads, hence the lock.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import Any, Callable

from graytrack.core.compression import stream_bound_factor
from graytrack.core.models.fourier import FourierModel
from graytrack.core.reference_monitor import ReferenceMonitor, Trimmer, drift_message, scale_tells
from graytrack.core.tracking import LiveFix
from graytrack.core.watches.scale import Disagreement

EventSink = Callable[[str, str], None]


class ReferenceTrim:
    def __init__(self, enabled: bool = False, on_event: EventSink = lambda kind, message: None,
                 reference_resolution_mm: float = 0.0, **monitor_options: Any) -> None:
        self.enabled = enabled
        self.on_event = on_event
        self.resolution_mm = reference_resolution_mm
        self.monitor_options = monitor_options
        self._trimmer: Trimmer | None = None  # None: no model, or one the grating cannot check (scale_tells)
        self.bound_scale = 1.0  # the frames' bound over the sensor's (a JPEG stream's quantisation)
        self._flagged = False
        self._lock = threading.Lock()

    def install(self, model: FourierModel, tracker: Any = None) -> None:
        """A new model (a calibration): the line starts again from it; a trim in force is cleared.
        ``tracker`` (the live one's :class:`~graytrack.core.tracking.Tracker`) gets this monitor's
        watch, so its validity monitor blames ``scale`` from here and honours the trim."""
        trimmer = None
        self.bound_scale = stream_bound_factor(getattr(model, "info", None) or {})
        if scale_tells(model):  # else its positions are off by its own structure: nothing to learn here
            trimmer = Trimmer(ReferenceMonitor.for_model(model, self.resolution_mm, **self.monitor_options))
            if tracker is not None:
                tracker.scale_watch = self.watch()
        with self._lock:
            old, self._trimmer, self._flagged = self._trimmer, trimmer, False
        if old is not None and old.trim is not None:
            self.on_event("trim_cleared", "trim cleared (a new model is installed)")

    def apply(self, fix: LiveFix, reference_mm: float) -> LiveFix:
        """Feed one tracked frame; the fix with its position trimmed when a trim is in force."""
        trimmer = self._trimmer
        if trimmer is None:
            return fix
        events: list[tuple[str, str]] = []
        with self._lock:
            monitor = trimmer.monitor
            if fix.locked:
                monitor.observe(fix.x_mm, reference_mm, fix.crlb_mm)
            if monitor.stale != self._flagged:
                self._flagged = monitor.stale
                events.append(("scale_drift", drift_message(monitor)) if monitor.stale else
                              ("scale_ok", "camera against grating agrees again with "
                                           + ("the trim in force" if trimmer.trim else "calibration")))
            if self.enabled:
                event = trimmer.consider()
                if event is not None:
                    events.append((event.kind, event.message))
                    self._flagged = monitor.stale
            if trimmer.trim is not None:
                x, sigma = trimmer.step(fix.x_mm)
                fix = _Trimmed(**{f.name: getattr(fix, f.name) for f in dataclasses.fields(fix)},
                               trim_um=(fix.x_mm - x) * 1e3, trim_sigma_um=sigma * 1e3)
                fix.x_mm = x
        for kind, message in events:  # outside the lock: the event log writes to disk
            self.on_event(kind, message)
        return fix

    @property
    def drifting(self) -> bool:
        """The camera against the grating has drifted from calibration (or from the trim in force)."""
        return self._flagged

    def watch(self) -> "TrimWatch":
        """A ``scale`` watch for the validity monitor that reads this monitor (fed here, once per
        frame) instead of running a second one on the same frames."""
        return TrimWatch(self)

    @staticmethod
    def annotate(message: dict[str, Any], fix: LiveFix) -> None:
        """The stream message's trim figures (only while a trim is in force)."""
        if isinstance(fix, _Trimmed) and math.isfinite(fix.trim_um):
            message["trim_um"] = fix.trim_um
            message["trim_sigma_um"] = fix.trim_sigma_um

    def reset(self, why: str = "on request") -> bool:
        """Clear the trim in force (True if there was one); drift is measured against calibration again."""
        with self._lock:
            event = self._trimmer.clear(why) if self._trimmer is not None else None
            if event is not None:
                self._flagged = False
        if event is not None:
            self.on_event(event.kind, event.message)
        return event is not None

    def status(self) -> dict[str, Any]:
        """``/api/status``'s ``trim``: the trim in force (figures null without one) and the window's line."""
        with self._lock:
            trimmer = self._trimmer
            trim = trimmer.trim if trimmer else None
            monitor = trimmer.monitor if trimmer else None
            doc: dict[str, Any] = {
                "enabled": self.enabled, "active": trim is not None,
                "scale_ppm": None, "scale_sigma_ppm": None, "offset_um": None, "offset_sigma_um": None,
                "center_mm": None, "frames": None, "mean_mm": None, "at_mean_um": None, "at_mean_sigma_um": None,
                "drift": bool(monitor and monitor.stale),
                "window": monitor.estimate.as_dict() if monitor and monitor.estimate else None,
            }
            if trim is not None:
                doc.update({key: value for key, value in trim.as_dict().items() if key in doc})
        return doc


@dataclasses.dataclass
class _Trimmed(LiveFix):
    """A fix whose position carries the trim (its size and standard error, µm)."""

    trim_um: float = float("nan")
    trim_sigma_um: float = float("nan")


class TrimWatch:
    """``observe(sign) -> "scale" | None`` from the daemon's own camera-against-grating monitor, and,
    as batch tracking's scale watch does (core/watches/scale.py), the running mean of camera −
    grating against the line in force: an episode of frames several bounds off (a smudge coming into
    view) that the line's outlier gate leaves out."""

    family = "scale"

    def __init__(self, trim: ReferenceTrim) -> None:
        self.trim = trim
        self._off: Disagreement | None = None

    def observe(self, sign: Any) -> str | None:
        far = self._disagrees(sign)
        if getattr(sign, "chi2_suspect", False):  # the images changed: off the grating as well, the
            return "geometry" if self.trim.drifting or far else None  # model does not describe the rig
        return self.family if self.trim.drifting or far else None

    def _disagrees(self, sign: Any) -> bool:
        trimmer = self.trim._trimmer
        if trimmer is None or sign is None:
            return False
        if self._off is None or self._off.monitor is not trimmer.monitor:  # a new model: a new line
            self._off = Disagreement(trimmer.monitor)
        information = sign.information
        bound = self.trim.bound_scale / math.sqrt(information) if sign.placed and information > 0 else math.nan
        return self._off.add(sign.x_mm, sign.reference_mm, bound)
