"""The frame loop: every camera frame is paired with the grating, handed to listeners and tracked.

One thread owns the camera (cameras are not thread-safe, and one reader guarantees that every
frame is seen once, in order). Per frame it: pairs the grating reading by host time, offers the
frame to subscribers (the calibration sweep), and, when a model is installed, runs the
:class:`LiveTracker` and publishes one message (the WebSocket stream).

Faults: no frame for ``camera_fault_after_s`` raises a camera fault; any other camera error
closes the camera and reopens it every ``reopen_interval_s``. The loop itself never ends on a
fault, so the daemon recovers by itself when frames return.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from graytrack.core.models.fourier import FourierModel
from graytrack.core.tracking import LiveFix, LiveTracker
from graytrack.drivers.camera.base import Camera, CameraError, CameraTimeout, Frame
from graytrack.service.daemon.grating import GratingPoller
from graytrack.service.daemon.worker import Worker

log = logging.getLogger("graytrack.daemon")
READ_TIMEOUT_S = 0.25  # short, so stop requests and fault timing are honoured promptly
RATE_WINDOW = 200


@dataclass(frozen=True)
class Sample:
    """A frame and the grating position paired with it (NaN when none was close in time)."""

    frame: Frame
    reference_mm: float


@dataclass
class AcquisitionStats:
    frames: int = 0
    tracked: int = 0
    unplaced: int = 0  # tracked frames the solver could not place (x = NaN)
    lock_events: int = 0
    camera_errors: int = 0
    camera_reopens: int = 0
    last_message: dict[str, Any] | None = None
    last_frame_wall: float = 0.0


def fix_message(seq: int, sample: Sample, fix: LiveFix) -> dict[str, Any]:
    """The WebSocket message of one tracked frame (DESIGN.md: seq, t, x_mm, locked, reference_mm?)."""
    finite = math.isfinite(fix.x_mm)
    message: dict[str, Any] = {
        "seq": seq,
        "t": sample.frame.t_host,
        "x_mm": fix.x_mm if finite else None,
        "locked": bool(fix.locked),
        "frame_id": sample.frame.frame_id,
        "rms_gray": fix.rms_gray if math.isfinite(fix.rms_gray) else None,
        "crlb_um": fix.crlb_mm * 1e3 if math.isfinite(fix.crlb_mm) else None,
    }
    if math.isfinite(sample.reference_mm):
        message["reference_mm"] = sample.reference_mm
        if finite:
            message["error_um"] = (fix.x_mm - sample.reference_mm) * 1e3
    if fix.event is not None:
        message["event"] = fix.event.reason
    return message


class Acquisition(Worker):
    def __init__(self, camera: Camera, grating: GratingPoller, publish: Callable[[dict[str, Any]], None],
                 on_fault: Callable[[str | None], None], fault_after_s: float, reopen_interval_s: float) -> None:
        super().__init__("acquisition")
        self.camera = camera
        self.grating = grating
        self.publish = publish
        self.on_fault = on_fault
        self.fault_after_s = fault_after_s
        self.reopen_interval_s = reopen_interval_s
        self.stats = AcquisitionStats(last_frame_wall=time.monotonic())
        self._tracker: LiveTracker | None = None
        self._pending: tuple[FourierModel, float | None] | None = None
        self._subscribers: list[queue.Queue[Sample]] = []
        self._lock = threading.Lock()
        self._arrivals: deque[float] = deque(maxlen=RATE_WINDOW)
        self._seq = 0

    # -- control (any thread) --------------------------------------------------------------
    def install_model(self, model: FourierModel, x0_mm: float | None = None) -> None:
        """Track with ``model`` from the next frame on (started near ``x0_mm`` when given)."""
        with self._lock:
            self._pending = (model, x0_mm)

    @property
    def tracking(self) -> bool:
        return self._tracker is not None or self._pending is not None

    def subscribe(self, maxsize: int = 1000) -> "queue.Queue[Sample]":
        """A queue receiving every following frame (the oldest are dropped if it is not emptied)."""
        q: queue.Queue[Sample] = queue.Queue(maxsize)
        with self._lock:
            self._subscribers.append(q)
        return q

    def unsubscribe(self, q: "queue.Queue[Sample]") -> None:
        with self._lock:
            if q in self._subscribers:
                self._subscribers.remove(q)

    def frame_rate_hz(self) -> float:
        """Frames per wall second over the last few hundred frames."""
        arrivals = list(self._arrivals)
        if len(arrivals) < 2 or arrivals[-1] <= arrivals[0]:
            return 0.0
        return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])

    def seconds_since_frame(self) -> float:
        return time.monotonic() - self.stats.last_frame_wall

    # -- the loop --------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            frame = self._next_frame()
            if frame is None:
                continue
            sample = Sample(frame, self.grating.at(frame.t_host))
            self._offer(sample)
            self._track(sample)

    def _next_frame(self) -> Frame | None:
        try:
            frame = self.camera.read(READ_TIMEOUT_S)
        except CameraTimeout:
            silent = self.seconds_since_frame()
            if silent > self.fault_after_s:
                self.on_fault(f"no frame for {silent:.1f} s")
            return None
        except CameraError as exc:
            self.stats.camera_errors += 1
            self.on_fault(f"camera error: {exc}")
            self._reopen()
            return None
        now = time.monotonic()
        self.stats.frames += 1
        self.stats.last_frame_wall = now
        self._arrivals.append(now)
        self.on_fault(None)
        return frame

    def _reopen(self) -> None:
        """Close, wait, open again; failures leave the fault standing for the next round."""
        self.camera.close()
        if self._stop.wait(self.reopen_interval_s):
            return
        try:
            self.camera.open()
            self.stats.camera_reopens += 1
            log.info("camera reopened")
        except CameraError as exc:
            self.on_fault(f"camera cannot be reopened: {exc}")

    def _offer(self, sample: Sample) -> None:
        with self._lock:
            subscribers = list(self._subscribers)
        for q in subscribers:
            try:
                q.put_nowait(sample)
            except queue.Full:
                try:
                    q.get_nowait()
                    q.put_nowait(sample)
                except (queue.Empty, queue.Full):
                    pass

    def _track(self, sample: Sample) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is not None:
            model, x0 = pending
            self._tracker = LiveTracker(model, x0 if x0 is not None and math.isfinite(x0) else None)
        if self._tracker is None:
            return
        fix = self._tracker.update(np.asarray(sample.frame.pixels), sample.reference_mm)
        self.stats.tracked += 1
        self.stats.unplaced += not math.isfinite(fix.x_mm)
        self.stats.lock_events += fix.event is not None
        self._seq += 1
        message = fix_message(self._seq, sample, fix)
        self.stats.last_message = message
        self.publish(message)
