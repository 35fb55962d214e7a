"""The estimator as the daemon's frame loop drives it: the same interface as today's live tracker
(``update(frame, reference_mm, t)`` → the frame's record, ``restart_at``, ``texture``, ``stale``), so
``[daemon] engine = "estimator"`` swaps the per-frame path and nothing else. It also exposes the maps the
estimator learns (``sensor_map``, the sensor's side; ``print_map``, the print), looked at for their events every
``LOOK_FRAMES`` frames, and takes the state of those an earlier tracker of the same model learned."""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from graytrack.core.estimator.filter import Estimator, FrameEstimate
from graytrack.core.estimator.print_map import PrintMap
from graytrack.core.estimator.sensor_map import SensorMap
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.models.fourier import FourierModel


RECORD = ("x_mm", "locked", "rms_gray", "crlb_mm", "chi2", "rejected_px", "gain", "offset_gray", "stale",
          "focus_px2", "focus_sigma_px2", "iterations")
LOOK_FRAMES = 20  # frames between two looks at the maps' marks (their events): a mark is resolved over many more
# frames than this, and a look costs the map's test of every place (~20 µs for 100 samples, on the frame loop)


class LiveEstimator:
    """One :class:`Estimator` for a running rig. ``grating``: ``"check"``, ``"fuse"`` (the daemon's trim)
    or ``"none"`` (a rig without one). ``sensor_map``, ``print_map``: the states of the maps an earlier tracker
    of this model learned (:meth:`SensorMap.state`, :meth:`PrintMap.state`); one that does not fit is refused
    (``refused(name, why)``) and the tracker starts from that side as calibrated."""

    texture = None  # the per-frame path's texture: the estimator's print is its print_map

    def __init__(self, model: FourierModel, x0_mm: float | None = None, grating: str = "check",
                 settings: EstimatorSettings | None = None, axis_px: float | None = None,
                 sensor_map: dict[str, Any] | None = None, print_map: dict[str, Any] | None = None,
                 refused: Callable[[str, str], None] = lambda name, reason: None, commands_known: bool = False):
        self.model = model
        # commands_known: every phase of acceleration the stage is given comes through :meth:`commanded` (between
        # them it holds its speed or rests), so a knock without the grating is told from the stage's motion
        self.estimator = Estimator(model, settings=settings, grating=grating, axis_px=axis_px,
                                   stage_phases=np.zeros((0, 3)) if commands_known else None)
        self._start = x0_mm
        self.last: FrameEstimate | None = None
        self.frames = 0
        for name, learned, state in (("sensor_map", self.sensor_map, sensor_map),
                                     ("print_map", self.print_map, print_map)):
            if state is not None:
                try:
                    learned.restore(state)
                except ValueError as exc:
                    refused(name, str(exc))

    @property
    def sensor_map(self) -> SensorMap:
        """The map of the sensor's side the estimator learns (its ``events`` and ``state()``)."""
        return self.estimator.sensor

    @property
    def print_map(self) -> PrintMap:
        """The map of the print the estimator learns (its ``events`` and ``state()``)."""
        return self.estimator.print_map

    @property
    def stale(self) -> bool:
        return bool(self.last is not None and self.last.stale)

    @property
    def slide_um(self) -> float:
        """What the lens's slide adds to the newest frame's bound without the grating, µm (in its ``crlb_mm``;
        NaN with the grating or before a frame)."""
        return self.last.slide_mm * 1e3 if self.last is not None else math.nan

    def commanded(self, start: float, end: float, acceleration: float | None = None) -> None:
        """A phase of acceleration the daemon commanded of the stage (s on the frames' clock, mm/s²): see
        :meth:`Estimator.commanded`."""
        self.estimator.commanded(start, end, acceleration)

    def restart_at(self, x_mm: float) -> None:
        """The next frame starts from ``x_mm`` (the grating's reading at a model switch)."""
        self._start = x_mm

    def update(self, frame: np.ndarray, reference_mm: float = math.nan, t: float | None = None):
        """The frame at mid-exposure ``t`` (s, the host's monotonic clock) with its grating reading."""
        from graytrack.core.tracking import LiveFix

        estimator = self.estimator
        t = float(t) if t is not None else (estimator.t_last or 0.0) + 1e-3
        if self._start is not None and math.isfinite(self._start):
            estimator.start(self._start, t, max(estimator.settings.grating_sigma, 0.01 * self.model.period_mm))
            estimator.t_last = t
        self._start = None
        before, errors = self.last, estimator.update_errors
        estimate = self.last = estimator.update(frame, t, reference_mm)
        self.frames += 1
        event = None
        if estimator.update_errors > errors:  # the estimate starts again from the next frame: the lock is lost
            from graytrack.core.tracking import LockEvent

            event = LockEvent(frame=self.frames, reason=estimate.message.removeprefix("not placed: "),
                              x_before_mm=before.x_mm if before is not None else math.nan, x_after_mm=math.nan,
                              reacquired=False)
        if self.frames % LOOK_FRAMES == 0:
            estimator.sensor.look(self.frames)
            estimator.print_map.look(self.frames)
        # the record's quantities by the names core/frame_record.py declares (None: no event, no reason)
        record: dict[str, Any] = {name: getattr(estimate, name) for name in RECORD}
        record.update(event=event, stale_reason=estimate.stale_reason or None)
        return LiveFix(**record)
