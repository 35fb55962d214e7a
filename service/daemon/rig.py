"""The rig's lifecycle: open the hardware, track, calibrate on request, survive faults, close.

The state the API reports is *derived*, never stored, so it cannot disagree with what the parts
are doing::

    stopping     close() was called
    fault        hardware could not be opened, or the camera / the grating readout is failing
    starting     hardware is being opened
    calibrating  a calibration sweep is running
    tracking     a model is installed and frames are being tracked
    idle         hardware open, no model yet (POST /api/calibration to get one)

Hardware that fails to open is retried every ``reopen_interval_s`` by a supervisor thread, so a
daemon started before its camera or USB adapter is plugged in comes up by itself.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any, Callable

from graytrack import __version__
from graytrack.drivers.clock import REAL_TIME, ScaledClock
from graytrack.drivers.factory import Hardware, open_hardware
from graytrack.drivers.stage.errors import StageError, StageLimitError
from graytrack.service.daemon.acquisition import Acquisition
from graytrack.service.daemon.grating import GratingPoller
from graytrack.service.daemon.settings import Settings
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.sweep import CalibrationJob, Sweep

log = logging.getLogger("graytrack.daemon")
HardwareFactory = Callable[[Settings, ScaledClock], Hardware]


class RigError(Exception):
    """A request the rig refuses; ``status`` is the HTTP status the API answers with."""

    status = 409


class NotReady(RigError):
    status = 503


class Busy(RigError):
    status = 409


class OutOfLimits(RigError):
    status = 422


def default_factory(settings: Settings, clock: ScaledClock) -> Hardware:
    return open_hardware(settings.hardware, clock)


class Faults:
    """Current faults by source (``hardware``, ``camera``, ``stage``), thread-safe, logged on change."""

    def __init__(self) -> None:
        self._faults: dict[str, str] = {}
        self._lock = threading.Lock()
        self.raised = 0

    def reporter(self, source: str) -> Callable[[str | None], None]:
        """A callback setting (reason) or clearing (None) this source's fault."""
        return lambda reason: self.set(source, reason)

    def set(self, source: str, reason: str | None) -> None:
        with self._lock:
            previous = self._faults.get(source)
            if reason == previous:
                return
            if reason is None:
                del self._faults[source]
            else:
                self._faults[source] = reason
                self.raised += previous is None
        if reason is None:
            log.info("%s fault cleared", source)
        elif previous is None:
            log.warning("%s fault: %s", source, reason)

    def snapshot(self) -> dict[str, str]:
        with self._lock:
            return dict(self._faults)


class Rig:
    def __init__(self, settings: Settings, storage: Storage, publish: Callable[[dict[str, Any]], None],
                 factory: HardwareFactory = default_factory) -> None:
        self.settings = settings
        self.storage = storage
        self.publish = publish
        self.factory = factory
        self.clock = ScaledClock(settings.daemon.sim_clock_scale) if settings.simulated else REAL_TIME
        self.faults = Faults()
        self.hardware: Hardware | None = None
        self.grating: GratingPoller | None = None
        self.acquisition: Acquisition | None = None
        self.model = None
        self.jobs: dict[str, CalibrationJob] = {}
        self.calibrations_finished: dict[str, int] = {"done": 0, "failed": 0, "aborted": 0}
        self._job: CalibrationJob | None = None
        self._sweep_thread: threading.Thread | None = None
        self._lock = threading.RLock()
        self._closing = threading.Event()
        self._started_wall = time.monotonic()
        self._supervisor = threading.Thread(target=self._bring_up, name="rig-supervisor", daemon=True)

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "Rig":
        self._supervisor.start()
        return self

    def wait_ready(self, timeout_s: float) -> bool:
        """True once the hardware is open (for tests and the command line's start message)."""
        deadline = time.monotonic() + timeout_s
        while self.acquisition is None and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.acquisition is not None

    def close(self) -> None:
        """Abort a sweep, stop the threads, close the hardware; safe to call twice."""
        self._closing.set()
        job, thread = self._job, self._sweep_thread
        if job is not None:
            job.abort.set()
        if thread is not None:
            thread.join(timeout=10.0)
        if self._supervisor.is_alive():
            self._supervisor.join(timeout=10.0)
        with self._lock:
            if self.acquisition is not None:
                self.acquisition.stop()
            if self.grating is not None:
                self.grating.stop()
            if self.hardware is not None:
                self.hardware.close()
                log.info("hardware closed")
            self.hardware = None

    def _bring_up(self) -> None:
        while not self._closing.is_set():
            try:
                hardware = self.factory(self.settings, self.clock)
            except Exception as exc:  # any driver error: report, retry; the daemon must stay up
                self.faults.set("hardware", f"cannot open the hardware: {exc}")
                self._closing.wait(self.settings.daemon.reopen_interval_s)
                continue
            self.faults.set("hardware", None)
            self._attach(hardware)
            return

    def _attach(self, hardware: Hardware) -> None:
        daemon = self.settings.daemon
        with self._lock:
            if self._closing.is_set():
                hardware.close()
                return
            self.hardware = hardware
            self.grating = GratingPoller(hardware.stage, daemon.grating_poll_s, daemon.pair_window_s,
                                         self.faults.reporter("stage")).start()
            self.acquisition = Acquisition(hardware.camera, self.grating, self.publish, self.faults.reporter("camera"),
                                           daemon.camera_fault_after_s, daemon.reopen_interval_s).start()
        log.info("hardware open: %s camera, %s stage, limits %s mm", self.settings.hardware.camera.kind,
                 self.settings.hardware.stage.kind, hardware.stage.limits())
        model = self.storage.load_current_model()
        if model is not None:
            log.info("tracking with the saved model %s", model.describe())
            self._install(model)
        elif daemon.auto_calibrate == "always" or (daemon.auto_calibrate == "sim" and self.settings.simulated):
            log.info("no saved model: calibrating (auto_calibrate = %s)", daemon.auto_calibrate)
            try:
                self.start_calibration()
            except RigError as exc:
                log.warning("automatic calibration not started: %s", exc)
        else:
            log.info("no saved model: idle until POST /api/calibration")

    def _install(self, model: Any) -> None:
        assert self.acquisition is not None and self.grating is not None
        latest = self.grating.latest()
        self.model = model
        self.acquisition.install_model(model, None if latest is None else latest.position_mm)

    # -- state -----------------------------------------------------------------------------
    @property
    def state(self) -> str:
        if self._closing.is_set():
            return "stopping"
        if self.faults.snapshot():
            return "fault"
        if self.acquisition is None:
            return "starting"
        if self._job is not None and self._job.active:
            return "calibrating"
        return "tracking" if self.model is not None else "idle"

    def status(self) -> dict[str, Any]:
        faults = self.faults.snapshot()
        acquisition, grating = self.acquisition, self.grating
        last = acquisition.stats.last_message if acquisition is not None else None
        fresh = acquisition is not None and acquisition.seconds_since_frame() <= self.settings.daemon.camera_fault_after_s
        latest = grating.latest() if grating is not None else None
        job = self._job
        return {
            "state": self.state,
            "calibrated": self.model is not None,
            "position_mm": last["x_mm"] if last is not None and fresh else None,
            "locked": bool(last["locked"]) if last is not None and fresh else None,
            "crlb_um": last.get("crlb_um") if last is not None and fresh else None,
            "grating_mm": latest.position_mm if latest is not None else None,
            "reason": "; ".join(f"{source}: {reason}" for source, reason in faults.items()) or None,
            "faults": faults,
            "model": self.model.describe() if self.model is not None else None,
            "limits_mm": list(self.hardware.stage.limits()) if self.hardware is not None else None,
            "frame_rate_hz": round(acquisition.frame_rate_hz(), 2) if acquisition is not None else 0.0,
            "frames": acquisition.stats.frames if acquisition is not None else 0,
            "calibration": None if job is None else {key: job.to_dict()[key] for key in
                                                       ("id", "state", "progress", "message")},
            "simulated": self.settings.simulated,
            "uptime_s": round(time.monotonic() - self._started_wall, 3),
            "version": __version__,
        }

    # -- requests --------------------------------------------------------------------------
    def _ready(self) -> tuple[Hardware, Acquisition]:
        if self._closing.is_set():
            raise NotReady("the daemon is shutting down")
        if self.hardware is None or self.acquisition is None:
            reason = self.faults.snapshot().get("hardware", "the hardware is still being opened")
            raise NotReady(f"hardware not ready: {reason}")
        return self.hardware, self.acquisition

    def start_calibration(self) -> CalibrationJob:
        with self._lock:
            hardware, acquisition = self._ready()
            if self._job is not None and self._job.active:
                raise Busy(f"calibration {self._job.id} is already running")
            faults = self.faults.snapshot()
            if faults:
                raise NotReady("cannot calibrate during a fault: " + "; ".join(f"{k}: {v}" for k, v in faults.items()))
            config = self.settings.sweep
            job = CalibrationJob(self.storage.new_calibration_id(), config.model, config.positions,
                                 config.frames_per_position)
            self.storage.write_status(job.id, job.to_dict())
            self.jobs[job.id] = job
            self._job = job
            sweep = Sweep(job, hardware.stage, acquisition, self.storage, config, self._meta(hardware))
            self._sweep_thread = threading.Thread(target=self._run_sweep, args=(sweep,), name="sweep", daemon=True)
            self._sweep_thread.start()
        log.info("calibration %s started (%d stops x %d frames, %s model)", job.id, config.positions,
                 config.frames_per_position, config.model)
        return job

    def _run_sweep(self, sweep: Sweep) -> None:
        model = sweep.run()
        job = sweep.job
        self.calibrations_finished[job.state] = self.calibrations_finished.get(job.state, 0) + 1
        if model is None or self._closing.is_set():
            return
        self.storage.save_current_model(model)
        self._install(model)
        log.info("calibration %s done in %.1f s: %s", job.id, job.duration_s or 0.0, job.message)

    def _meta(self, hardware: Hardware) -> dict[str, Any]:
        meta: dict[str, Any] = hardware.rig.meta() if hardware.rig is not None else {}  # type: ignore[attr-defined]
        meta.update({"source": "graytrack serve", "daemon_version": __version__})
        for key in ("pixel_pitch_mm", "period_mm"):
            value = getattr(self.settings.sweep, key)
            if value is not None:
                meta[key] = value
        return meta

    def calibration(self, calibration_id: str) -> dict[str, Any] | None:
        job = self.jobs.get(calibration_id)
        return job.to_dict() if job is not None else self.storage.read_status(calibration_id)

    def latest_calibration(self) -> dict[str, Any] | None:
        latest = self.storage.latest_calibration_id()
        return None if latest is None else self.calibration(latest)

    def move(self, target_mm: float) -> dict[str, Any]:
        hardware, _ = self._ready()
        if self._job is not None and self._job.active:
            raise Busy(f"calibration {self._job.id} is moving the stage; POST /api/stage/stop aborts it")
        low, high = hardware.stage.limits()
        if not (math.isfinite(target_mm) and low <= target_mm <= high):
            raise OutOfLimits(f"target_mm {target_mm:g} is outside the soft limits [{low:g}, {high:g}] mm")
        try:
            hardware.stage.move_to(target_mm)
        except StageLimitError as exc:
            raise OutOfLimits(str(exc)) from None
        except StageError as exc:
            raise NotReady(f"stage: {exc}") from None
        return {"target_mm": target_mm, "limits_mm": [low, high]}

    def stop(self) -> dict[str, Any]:
        """Stop the stage now; a running calibration is aborted first (it would move it again)."""
        hardware, _ = self._ready()
        job = self._job
        aborted = job is not None and job.active
        if aborted:
            job.abort.set()
        try:
            hardware.stage.stop()
        except StageError as exc:
            raise NotReady(f"stage: {exc}") from None
        return {"stopped": True, "aborted_calibration": job.id if aborted and job is not None else None}
