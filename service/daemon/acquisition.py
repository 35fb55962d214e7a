"""The frame loop: every camera frame is paired with the grating, handed to listeners and tracked.

One thread owns the camera (cameras are not thread-safe, and one reader guarantees that every
frame is seen once, in order). Per frame it: pairs the grating (:class:`Readings`), offers the frame to subscribers
(the calibration sweep), and, when a model is installed, runs the :class:`LiveTracker` and publishes one message.

Faults: no frame for ``camera_fault_after_s`` raises a camera fault; any other camera error
closes the camera and reopens it every ``reopen_interval_s``; an exception from the tracker
(a frame of another width after an ROI change, a model that cannot be evaluated) is a
``tracking`` fault that clears on the next frame tracked. Anything else is a crash of the
worker, which :class:`Worker` reports and restarts. The loop never ends on a fault.

Per-frame cost matters at 1 kHz (the stream's latency tail): the loop allocates one dict per
frame and nothing else of its own, and hands the message to the broadcaster, which encodes it
once for all clients.
"""

from __future__ import annotations

import logging
import math
import queue
import dataclasses
import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from graytrack.core.models.fourier import FourierModel
from graytrack.core.texture import Texture
from graytrack.core.estimator.live import LiveEstimator
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.tracking import LiveFix, LiveTracker
from graytrack.drivers.camera.base import Camera, CameraError, CameraTimeout, Frame
from graytrack.service.daemon.clock import HOST_CLOCK, Clock
from graytrack.service.daemon.framerate import FrameRate
from graytrack.service.daemon.grating import Readings
from graytrack.service.daemon.loss_log import QUIET_S as LOSS_QUIET_S, LossLog
from graytrack.service.daemon.stale_log import StaleLog
from graytrack.service.daemon.map_store import MapKind, MapLog, MapSnapshotter
from graytrack.service.daemon.print_map_store import PRINT_MAP
from graytrack.service.daemon.sensor_map_store import SENSOR_MAP
from graytrack.service.daemon.texture_store import TEXTURE
from graytrack.core.slide import SlideWatch
from graytrack.core.watches.scale import ScaleWatch
from graytrack.service.daemon.slide import LiveSlide
from graytrack.service.daemon.trim import ReferenceTrim
from graytrack.core import frame_record
from graytrack.drivers.realtime import raise_thread_priority
from graytrack.service.daemon.worker import Worker, describe

log = logging.getLogger("graytrack.daemon")
# a model's tracker built off the frame loop: (model, tracker or None, why it cannot be used, its calibration's
# id, its scale watch, its slide watch without a grating)
Built = tuple[FourierModel, "LiveTracker | LiveEstimator | None", "str | None", "str | None", "ScaleWatch | None",
              "SlideWatch | None"]
READ_TIMEOUT_S = 0.25  # short, so stop requests and fault timing are honoured promptly
# the maps each engine learns while tracking, each its tracker's attribute of the kind's name (map_store.py): today's
# tracker learns the print's texture; the estimator the sensor's map and the print's
ENGINE_MAPS: dict[str, tuple[MapKind, ...]] = {"watches": (TEXTURE,), "estimator": (SENSOR_MAP, PRINT_MAP)}


@dataclass(frozen=True)
class Sample:
    """A frame, its mid-exposure on the host clock and the grating position paired with it (NaN if none)."""

    frame: Frame
    t: float
    reference_mm: float


@dataclass
class AcquisitionStats:
    frames: int = 0
    tracked: int = 0
    unplaced: int = 0  # tracked frames the solver could not place (x = NaN)
    lock_events: int = 0
    camera_errors: int = 0
    camera_reopens: int = 0
    tracking_errors: int = 0
    dropped: int = 0  # frames missing from the camera's frame_id sequence
    last_message: dict[str, Any] | None = None
    last_frame_wall: float = 0.0
    last_tracked_wall: float = -math.inf


def fix_message(seq: int, sample: Sample, fix: LiveFix, dropped: int, calibration: str | None = None) -> dict[str, Any]:
    """The stream message of one tracked frame (docs/contracts.md; ``t_unix`` and ``age_ms`` are added at send).
    ``calibration``: the id of the calibration whose model placed the frame, when it has one."""
    record = frame_record.of_frame(fix)  # every quantity named and typed as in the CSV and /api/status
    x = record["x_mm"]
    message: dict[str, Any] = {"seq": seq, "t": sample.t, "x_mm": x, "locked": record["locked"],
                               "frame_id": sample.frame.frame_id, "dropped": dropped}
    if calibration is not None:
        message["calibration"] = calibration
    message.update((name, value) for name, value in record.items() if name not in message)
    if sample.reference_mm == sample.reference_mm:  # not NaN
        message["reference_mm"] = sample.reference_mm
        if x is not None:
            message["error_um"] = (x - sample.reference_mm) * 1e3
    if fix.event is not None:
        message["event"] = fix.event.reason
    return message


class Acquisition(Worker):
    def __init__(self, camera: Camera, readings: Readings,
                 publish: Callable[[dict[str, Any]], None], faults: Callable[[str, str | None], None],
                 fault_after_s: float, reopen_interval_s: float,
                 on_event: Callable[[str, str], None] = lambda kind, message: None, priority: int = 0,
                 trim: ReferenceTrim | None = None, clock: Clock = HOST_CLOCK, slide: LiveSlide | None = None,
                 engine: str = "watches", rig_meta: dict[str, Any] | None = None,
                 loss_quiet_s: float = LOSS_QUIET_S) -> None:
        super().__init__("acquisition", lambda reason: faults("acquisition", reason))
        self.clock = clock  # what silence, rates and the reopen pause are measured on (service/daemon/clock.py)
        self.on_event = on_event  # lock losses, re-acquisitions, stale-model flags: the event log
        self.priority = priority  # SCHED_FIFO level of the frame loop (realtime.py), 0 = normal
        self.trim = trim or ReferenceTrim(False, on_event)  # camera against grating (service/daemon/trim.py)
        self.slide = slide  # no grating on the rig: each bound carries the slide (service/daemon/slide.py)
        self.engine = engine  # the per-frame path: "watches" (LiveTracker) or "estimator" (core/estimator/)
        # what the rig states of itself, as its recordings' meta does (what triggers the camera): the estimator's
        # settings read it as they read a recording's
        self.estimator_settings = EstimatorSettings().for_recording(rig_meta or {})
        self.camera = camera
        self.readings = readings
        self.publish = publish
        self.faults = faults
        self.fault_after_s = fault_after_s
        self.reopen_interval_s = reopen_interval_s
        self.stats = AcquisitionStats(last_frame_wall=clock.now())
        self.latest: tuple[Sample, LiveFix | None] | None = None  # the line view reads it (no copy)
        self._tracker: LiveTracker | None = None
        # a model's tracker and watches (:data:`Built`): built off the frame loop, taken at a frame
        self._pending: Built | None = None
        self._calibration: str | None = None  # the calibration of the model tracking now (each message names it)
        self._skew_s = 0.0  # its grating latch against the exposure (reference_skew_s): taken out of the pairing
        self._generation = 0  # of the last install asked for: an older build that finishes later is dropped
        self._subscribers: list[queue.Queue[Sample]] = []
        self._lock = threading.Lock()
        self.rate = FrameRate()  # restarts after an outage (service/daemon/framerate.py)
        self._seq = 0
        self._last_id: int | None = None
        self._losses = LossLog(on_event, loss_quiet_s)  # frames the camera's counter skipped: frames_lost events
        self._stale = StaleLog(on_event)  # the flag's events: a model gone stale, or a single frame
        # what the tracker learns into its maps, as events, and each map's newest state for the model of record
        # (map_store.py), by the map's name
        self.kinds = ENGINE_MAPS[engine]
        self._map_logs = [MapLog(kind, on_event) for kind in self.kinds]
        self.snapshots = {kind.name: MapSnapshotter(kind) for kind in self.kinds}

    # -- control (any thread) --------------------------------------------------------------
    def install_model(self, model: FourierModel, x0_mm: float | None = None, calibration: str | None = None,
                      learned: dict[str, dict[str, Any]] | None = None,
                      refused: Callable[[str, str], None] = lambda name, reason: None) -> None:
        """Track with ``model`` (of calibration ``calibration``) from a coming frame on (started near
        the grating's reading then, or ``x0_mm``), with the maps ``learned`` (by name: ``texture``, the
        marks on the print; ``sensor_map`` and ``print_map``, the estimator's two sides) an earlier tracker of it
        learned (``refused(name, why)`` when one does not fit it: tracked without it). Its tracker (tables, the
        compiled solves loaded: 40–500 ms, seconds with no compiler cache) is built on a thread of its own:
        the frame loop keeps every frame meanwhile, tracked with the model it has, and switches between two frames;
        each message names the calibration whose model placed it."""
        with self._lock:
            self._generation += 1
            generation = self._generation
        threading.Thread(target=self._build, args=(model, x0_mm, generation, calibration, dict(learned or {}), refused),
                         name="tracker-build", daemon=True).start()

    def _build(self, model: FourierModel, x0: float | None, generation: int, calibration: str | None,
               learned: dict[str, dict[str, Any]], refused: Callable[[str, str], None]) -> None:
        start = x0 if x0 is not None and math.isfinite(x0) else None
        texture = learned.get(TEXTURE.name)
        if texture is not None:
            try:
                Texture.from_state(model, texture)  # the saved marks fit this model's grid (else: without them)
            except ValueError as exc:
                refused(TEXTURE.name, describe(exc))
                texture = None
        try:
            # without a grating the slide watch (in place of the scale watch), else the tracker's scale watch,
            # with the trim when enabled
            if self.engine == "estimator":  # the one estimator: the trim is its fused grating, the slide its lever
                grating = "none" if self.slide is not None else ("fuse" if self.trim.enabled else "check")
                axis_px = self.slide.axis_px if self.slide is not None else None
                acceleration = self.slide.stage_acceleration_mm_s2 if self.slide is not None else None
                settings = self.estimator_settings if acceleration is None else \
                    self.estimator_settings.replace(stage_acceleration=acceleration)
                estimator = LiveEstimator(model, start, grating, settings=settings, axis_px=axis_px,
                                          sensor_map=learned.get(SENSOR_MAP.name),
                                          print_map=learned.get(PRINT_MAP.name), refused=refused,
                                          commands_known=self.slide is not None and self.slide.motion is not None)
                built: Built = (model, estimator, None, calibration, None, None)
            else:
                slide = self.slide.watch_for(model) if self.slide is not None else None
                watch = self.trim.watch_for(model) if slide is None else None
                given = [w for w in (watch, slide) if w is not None]
                built = (model, LiveTracker(model, start, watches=given, texture=texture), None, calibration,
                         watch, slide)
        except Exception as exc:  # noqa: BLE001 - an unusable model: said at the switch, frames still read
            built = (model, None, describe(exc), calibration, None, None)
        with self._lock:
            if generation == self._generation:
                self._pending = built

    @property
    def tracker(self) -> LiveTracker | None:
        return self._tracker

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

    @property
    def model_stale(self) -> str | None:
        """The family of causes the tracker's model is stale for (None: it holds)."""
        return self._stale.family

    def frame_rate_hz(self, stale_after_s: float) -> float:
        """Frames per second since the last outage (at most a few hundred frames); 0 when the newest is older
        than ``stale_after_s``."""
        return self.rate.hz(self.clock.now(), stale_after_s)

    def seconds_since_frame(self) -> float:
        return self.clock.now() - self.stats.last_frame_wall

    def seconds_since_tracked(self) -> float:
        return self.clock.now() - self.stats.last_tracked_wall

    # -- the loop --------------------------------------------------------------------------
    def _run(self) -> None:
        if raise_thread_priority(self.priority, "frame loop"):
            raise_parts = getattr(self.camera, "raise_priority", None)  # a camera that exposes in a process of its own
            if raise_parts is not None:  # (the virtual rig's, drivers/sim/process.py): its exposures too
                try:
                    raise_parts(self.priority)
                except CameraError as exc:
                    self.faults("camera", f"camera error: {exc}")
        while not self._stop.is_set():
            frame = self._next_frame()
            if frame is None:
                continue
            t = frame.t_host  # mid-exposure on time.monotonic, for every driver (the camera contract)
            sample = Sample(frame, t, self.readings.at(t))
            self._offer(sample)
            self._track(sample)

    def _recover(self) -> None:
        self._reopen()

    def _next_frame(self) -> Frame | None:
        try:
            frame = self.camera.read(READ_TIMEOUT_S)
        except CameraTimeout:
            silent = self.seconds_since_frame()
            if silent > self.fault_after_s:
                self.faults("camera", f"no frame for {silent:.1f} s")
            return None
        except CameraError as exc:
            self.stats.camera_errors += 1
            self.faults("camera", f"camera error: {exc}")
            self._reopen()
            return None
        now = self.clock.now()
        stats = self.stats
        stats.frames += 1
        stats.last_frame_wall = now
        self.rate.arrive(frame.t_host)  # exposure times: a host stall and its backlog are no outage
        missing = frame.frame_id - self._last_id - 1 if self._last_id is not None else 0
        if missing > 0:
            stats.dropped += missing
        self._losses.observe(missing, frame.frame_id, now)  # the count's events (loss_log.py)
        self._last_id = frame.frame_id
        self.faults("camera", None)
        self.faults("acquisition", None)
        return frame

    def _reopen(self) -> None:
        """Close, wait, open again; failures leave the fault standing for the next round."""
        self.camera.close()
        self._last_id = None
        self.rate.restart()
        if self.clock.wait(self._stop, self.reopen_interval_s):
            return
        try:
            self.camera.open()
            self.stats.camera_reopens += 1
            log.info("camera reopened")
        except CameraError as exc:
            self.faults("camera", f"camera cannot be reopened: {exc}")

    def _offer(self, sample: Sample) -> None:
        if not self._subscribers:
            return
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
        if self._pending is not None:
            with self._lock:
                pending, self._pending = self._pending, None
            if pending is not None:
                self._switch(*pending, sample.reference_mm)
        tracker = self._tracker
        if tracker is None:
            self.latest = (sample, None)
            return
        if self._skew_s:  # the grating at the exposure, as the model's calibration found it read (subscribers,
            # the sweep's recorder among them, keep the raw pairing: the next calibration measures the skew again)
            sample = dataclasses.replace(sample, reference_mm=self.readings.at(sample.t, self._skew_s))
        if self.slide is not None:  # the stage's readout is no grating: the frames go without it
            sample = dataclasses.replace(sample, reference_mm=math.nan)
            self.slide.hand_commands(tracker)  # what the stage was told since the last frame (motion.py)
        try:
            with self.trim.lock:  # the tracker feeds the scale watch, which a reset may clear meanwhile
                fix = tracker.update(np.asarray(sample.frame.pixels), sample.reference_mm, sample.t)
        except Exception as exc:  # noqa: BLE001 - a frame or model the tracker cannot use: a fault, not a dead loop
            self.stats.tracking_errors += 1
            self.faults("tracking", f"frame {sample.frame.frame_id} cannot be tracked: {describe(exc)}")
            self.latest = (sample, None)
            return
        self.faults("tracking", None)
        fix = self.trim.apply(fix, sample.reference_mm)
        slide_um = self.slide.apply(fix, getattr(tracker, "slide_um", math.nan)) if self.slide is not None else math.nan
        stats = self.stats
        stats.tracked += 1
        stats.last_tracked_wall = self.clock.now()
        if fix.x_mm != fix.x_mm:
            stats.unplaced += 1
        if fix.event is not None:
            stats.lock_events += 1
            event = fix.event
            if not getattr(event, "lost", True):
                self.on_event("frame_repeated", f"frame {sample.frame.frame_id}: {event.reason}")
            else:
                self.on_event("lock_reacquired" if event.reacquired else "lock_lost",
                              f"{'lock re-acquired' if event.reacquired else 'lock lost'} at frame "
                              f"{sample.frame.frame_id}: {event.reason}")
        self._stale.observe(sample.frame.frame_id,
                            getattr(fix, "stale_reason", None) if getattr(fix, "stale", False) else None)
        for log_map in self._map_logs:
            learned = getattr(tracker, log_map.kind.name, None)
            log_map.observe(learned)
            self.snapshots[log_map.kind.name].observe(learned, self._calibration)
        self._seq += 1
        message = fix_message(self._seq, sample, fix, stats.dropped, self._calibration)
        self.trim.annotate(message, fix)
        if slide_um == slide_um:  # not NaN: the slide σ the bound carries (crlb_um includes it)
            message["slide_sigma_um"] = slide_um
        stats.last_message = message
        self.latest = (sample, fix)
        self.publish(message)

    def _switch(self, model: FourierModel, tracker: LiveTracker | None, error: str | None, calibration: str | None,
                watch: ScaleWatch | None, slide: SlideWatch | None, reference_mm: float) -> None:
        """Track with ``tracker`` from this frame on, started at the grating's reading when there is
        one (the stage may have moved while it was built)."""
        for log_map in self._map_logs:
            log_map.replaced(f"calibration {calibration} installed" if calibration else "a model installed")
        self._calibration = calibration
        skew = float(model.info.get("reference_skew_s", 0.0) or 0.0)
        self._skew_s = skew if math.isfinite(skew) else 0.0
        if tracker is None:
            self._tracker = None
            self.faults("tracking", f"cannot track with this model: {error}")
            return
        if math.isfinite(reference_mm):
            tracker.restart_at(reference_mm)
        self._tracker = tracker
        self.trim.install(model, watch)
        if self.slide is not None:
            self.slide.install(slide)
