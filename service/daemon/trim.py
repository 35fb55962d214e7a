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

The scale watch is handed to the model's tracker through its constructor and fed by its validity
monitor (one monitor, so the stale flag and the bound follow the trim in force); ``apply`` runs on
the frame loop after it (O(1)); ``reset`` and ``status`` come from HTTP threads, hence the lock.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import Any, Callable

from graytrack.core.models.fourier import FourierModel
from graytrack.core.reference_monitor import drift_message, scale_tells
from graytrack.core.tracking import LiveFix
from graytrack.core.watches.scale import ScaleWatch

EventSink = Callable[[str, str], None]


class ReferenceTrim:
    """The daemon's side of the scale watch: the watch (core/watches/scale.py) owns the monitor and,
    with ``[daemon] trim``, the trim; it is made here for each model (:meth:`watch_for`), handed to
    that model's :class:`~graytrack.core.tracking.LiveTracker` through its constructor, and fed there
    once per frame by the validity monitor. Here its events are logged, the stream's positions
    trimmed (their bound widened by the trim's uncertainty and lag) and the status shown."""

    def __init__(self, enabled: bool = False, on_event: EventSink = lambda kind, message: None,
                 reference_resolution_mm: float = 0.0, **monitor_options: Any) -> None:
        self.enabled = enabled
        self.on_event = on_event
        self.resolution_mm = reference_resolution_mm
        self.monitor_options = monitor_options
        self._watch: ScaleWatch | None = None  # None: no model, or one the grating cannot check (scale_tells)
        self._flagged = False
        # held by the frame loop around a frame's tracking (the watch is fed there) and by HTTP threads
        # around a reset or a status
        self.lock = threading.Lock()

    def watch_for(self, model: FourierModel) -> ScaleWatch | None:
        """A new model's scale watch, with a trim of its own when enabled: hand it to the model's
        tracker (``LiveTracker(..., watches=)``), then :meth:`install` it with the model."""
        if not scale_tells(model):  # its positions are off by its own structure: nothing to learn here
            return None
        return ScaleWatch.for_model(model, self.resolution_mm, trim=self.enabled, **self.monitor_options)

    def install(self, model: FourierModel, watch: ScaleWatch | None) -> None:
        """A new model (a calibration) and its tracker's watch: the line starts again from it; a trim
        in force is cleared."""
        with self.lock:
            old, self._watch, self._flagged = self._watch, watch, False
        if old is not None and old.trimmer is not None and old.trimmer.trim is not None:
            self.on_event("trim_cleared", "trim cleared (a new model is installed)")

    def apply(self, fix: LiveFix, reference_mm: float) -> LiveFix:
        """After the tracker (whose monitor fed the watch this frame): the events, and the fix with its
        position trimmed and its bound widened while a trim is in force."""
        watch = self._watch
        if watch is None:
            return fix
        events: list[tuple[str, str]] = []
        with self.lock:
            trimmer, monitor = watch.trimmer, watch.monitor
            drifted = trimmer.drifted if trimmer is not None else monitor.stale
            if drifted != self._flagged:
                self._flagged = drifted
                events.append(("scale_drift", drift_message(monitor)) if drifted else
                              ("scale_ok", "camera against grating agrees again with "
                                           + ("the trim in force" if trimmer is not None and trimmer.trim
                                              else "calibration")))
            if watch.events:
                events.extend((event.kind, event.message) for _, event in watch.events)
                watch.events.clear()
                self._flagged = monitor.stale
            if trimmer is not None and trimmer.trim is not None:
                x, added = trimmer.step(fix.x_mm)
                fix = _Trimmed(**{f.name: getattr(fix, f.name) for f in dataclasses.fields(fix)},
                               trim_um=(fix.x_mm - x) * 1e3, trim_sigma_um=added * 1e3)
                fix.x_mm = x
                fix.crlb_mm = math.hypot(fix.crlb_mm, added)  # the trim's uncertainty and lag are the position's
        for kind, message in events:  # outside the lock: the event log writes to disk
            self.on_event(kind, message)
        return fix

    @property
    def drifting(self) -> bool:
        """The camera against the grating has drifted from calibration (or from the trim in force)."""
        return self._flagged

    @staticmethod
    def annotate(message: dict[str, Any], fix: LiveFix) -> None:
        """The stream message's trim figures (only while a trim is in force)."""
        if isinstance(fix, _Trimmed) and math.isfinite(fix.trim_um):
            message["trim_um"] = fix.trim_um
            message["trim_sigma_um"] = fix.trim_sigma_um

    def reset(self, why: str = "on request") -> bool:
        """Clear the trim in force (True if there was one); drift is measured against calibration again."""
        with self.lock:
            trimmer = self._watch.trimmer if self._watch is not None else None
            event = trimmer.clear(why) if trimmer is not None else None
            if event is not None:
                self._flagged = False
        if event is not None:
            self.on_event(event.kind, event.message)
        return event is not None

    def status(self) -> dict[str, Any]:
        """``/api/status``'s ``trim``: the trim in force (figures null without one) and the window's line."""
        with self.lock:
            watch = self._watch
            trimmer = watch.trimmer if watch is not None else None
            trim = trimmer.trim if trimmer else None
            monitor = watch.monitor if watch is not None else None
            doc: dict[str, Any] = {
                "enabled": self.enabled, "active": trim is not None,
                "scale_ppm": None, "scale_sigma_ppm": None, "offset_um": None, "offset_sigma_um": None,
                "center_mm": None, "frames": None, "mean_mm": None, "at_mean_um": None, "at_mean_sigma_um": None,
                "drift": bool(monitor and monitor.stale),
                "window": monitor.estimate.as_dict() if monitor and monitor.estimate else None,
            }
            if trim is not None:
                doc.update({key: value for key, value in trim.as_dict().items() if key in doc})
                doc["following_um"] = trimmer.following.correction_um
                doc["lag_um"] = trimmer.following.lag_um
            follow = watch.stretch_follow if watch is not None else None
            if follow is not None:  # the lens's stretch followed (core/stretch_follow.py): explained, not stale
                doc["stretch"] = follow.status()
        return doc


@dataclasses.dataclass
class _Trimmed(LiveFix):
    """A fix whose position carries the trim (its size and what it adds to the bound, µm)."""

    trim_um: float = float("nan")
    trim_sigma_um: float = float("nan")
