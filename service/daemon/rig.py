"""The rig: owns the hardware and the workers, answers requests; state is derived (``status``).

The state the API reports is *derived*, never stored, so it cannot disagree with what the parts
are doing::

    stopping     close() was called
    fault        a part is failing: hardware cannot be opened, camera, stage (grating readout),
                 tracking (frames or model the tracker cannot use), a crashed worker, start-up
    starting     hardware is being opened
    calibrating  a calibration job is active
    tracking     a model is installed (frames tracked: /healthz says whether they are, now)
    idle         hardware open, no model yet (POST /api/calibration to get one)

Who does what: :mod:`stage_control` (moves asked for over the API), :mod:`supervision` (faults, bring-up with
retries, the watchdog), :mod:`jobs` (the calibration state machine), :mod:`snapshot` (the parts read at one
instant) and :mod:`status` (the status document made from it), :mod:`acquisition` and :mod:`grating` (the two
workers). Hardware that fails to open is retried every
``reopen_interval_s``, so a daemon started before its camera is plugged in comes up by itself.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time

import numpy as np
from typing import Any, Callable

from graytrack import __version__
from graytrack.core.calibration_data import readout_mismatch
from graytrack.core.errors import ModelError
from graytrack.core.models import load_model
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import CAMERA_TRIGGER, MAINS_HZ, PIXEL_AXIS_REVERSED
from graytrack.drivers.clock import REAL_TIME, ScaledClock
from graytrack.drivers.factory import Hardware, open_hardware
from graytrack.service.daemon import snapshot as parts
from graytrack.service.daemon import status as status_doc
from graytrack.service.daemon.acquisition import ENGINE_MAPS, Acquisition
from graytrack.wire import Activated, ActiveCalibration, Calibration
from graytrack.service.daemon.motion import CommandedMotion
from graytrack.service.daemon.slide import LiveSlide
from graytrack.service.daemon.trim import ReferenceTrim
from graytrack.service.daemon.errors import Busy, DamagedCalibration, InsufficientStorage, NotFound, NotReady
from graytrack.service.daemon.grating import GratingPoller, Readings
from graytrack.service.daemon.jobs import FINAL, CalibrationJob, JobRunner, calibration_row, mark_interrupted, reconcile
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.event_log import EventLog
from graytrack.service.daemon.history import LabHistory
from graytrack.service.daemon.switch import Switch
from graytrack.service.daemon.settings import Settings
from graytrack.service.daemon.stage_control import StageControl
from graytrack.service.daemon.storage import LEARNED_MAPS, Storage
from graytrack.service.daemon.supervision import Faults, Supervisor, sentence
from graytrack.service.daemon.sweep import Sweep
from graytrack.service.daemon.map_store import MapStore, Stores
from graytrack.service.daemon.worker import describe

log = logging.getLogger("graytrack.daemon")
HardwareFactory = Callable[[Settings, ScaledClock], Hardware]
ROOM_MARGIN_BYTES = 16 * 2**20  # model, report, status and the record's growth
SWITCH_MARGIN_BYTES = 8 * 1024  # the pointer's block and the record's growth, besides the model's copy
DAMAGE_CACHE_ENTRIES = 1024  # model files checked for damage, remembered (more than a page of the list lists)


def default_factory(settings: Settings, clock: ScaledClock) -> Hardware:
    return open_hardware(settings.hardware, clock)


class Rig:
    def __init__(self, settings: Settings, storage: Storage, history: LabHistory,
                 publish: Callable[[dict[str, Any]], None], factory: HardwareFactory = default_factory) -> None:
        daemon = settings.daemon
        self.settings = settings
        self.storage = storage
        self.history = history
        self.publish = publish
        self.factory = factory
        self.clock = ScaledClock(daemon.sim_clock_scale) if settings.simulated else REAL_TIME
        self.faults = Faults()
        self.health = DataDirHealth(storage.root, storage.home, self.faults.reporter("storage"))
        self.events = EventLog(history, self.health.moved, self.faults.reporter("record"), daemon.events_max_age_days,
                               daemon.events_max_count)
        # the maps the engine learns while tracking (the print's texture, the sensor's side), kept with the model of
        # record (map_store.py), by name; the model switch removes every map's file, its own included
        self.maps = {kind.name: MapStore(kind, storage, self.health, self.clock.now, self.event)
                     for kind in ENGINE_MAPS[daemon.engine]}
        self.map_switch = Stores(*self.maps.values())
        # readings are stamped on the host's clock: a virtual rig run k times faster changes its motion k² faster
        self.readings = Readings(daemon.pair_window_s, daemon.pair_tolerance_um * 1e-3, daemon.pair_rest_s,
                                 change_mm_s2=daemon.pair_change_mm_s2 * self.clock.scale ** 2)
        # the stage's most acceleration on the host clock (a virtual rig run k times faster: k² more)
        declared = daemon.stage_acceleration_mm_s2
        self.stage_acceleration_mm_s2 = None if declared is None else declared * self.clock.scale ** 2
        # every command to the stage is noted here before it is sent (motion.py)
        self.motion = CommandedMotion(self.readings, self.stage_acceleration_mm_s2)
        self.hardware: Hardware | None = None
        self.grating: GratingPoller | None = None
        self.acquisition: Acquisition | None = None
        self.model: FourierModel | None = None
        self.installed_calibration: str | None = None  # the id of the calibration whose model is installed
        self.jobs: dict[str, CalibrationJob] = {}
        self.job: CalibrationJob | None = None
        # every end state from the start (a counter that appears late breaks rate()); interrupted ones are the
        # jobs found unfinished at start-up, counted when found
        self.calibrations_finished: dict[str, int] = dict.fromkeys(FINAL, 0)
        self.closing = threading.Event()
        self.started_at = time.monotonic()
        self._sweep_thread: threading.Thread | None = None
        self.stage = StageControl(lambda: self._ready()[0], self._active_job_id, self._abort_active_job,
                                  self.motion, lambda: self.grating.latest_mm() if self.grating else None,
                                  self.event)
        self._lock = threading.RLock()
        self._damage: dict[tuple[Any, ...], str | None] = {}  # Rig.damage's answers by file identity
        self.supervisor = Supervisor(self._bring_up, self._watch, self.faults, daemon.reopen_interval_s)
        self.faults.listeners.append(self._fault_event)

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "Rig":
        self.supervisor.start()
        return self

    def close(self) -> None:
        """Abort a job, stop the threads, close the hardware; safe to call twice."""
        self.closing.set()
        job, thread = self.job, self._sweep_thread
        if job is not None and job.active:
            job.request_abort("calibration aborted: the daemon is shutting down")
        if thread is not None:
            thread.join(timeout=10.0)
        self.supervisor.stop()
        self._detach()
        if self.acquisition is not None:  # what the tracker learned since the last write
            self._save_maps(self.acquisition, force=True)
        if not self.health.probe() and self.health.abandon():  # the writes kept while the disk was full: room now?
            log.error("a calibration whose end was logged above reads 'interrupted' at the next start")
        self.event("shutdown", "daemon stopped")
        self.events.abandon()

    def event(self, kind: str, message: str, **details: Any) -> None:
        """One line in the event log (``GET /api/events``); the record failing never stops the rig,
        but it is a fault (``record``) for as long as it fails, and the event is kept until it can be
        written (:mod:`event_log`): a history that silently stops is a lie."""
        self.events.write(kind, message, **details)

    def _fault_event(self, source: str, reason: str | None, previous: str | None, seconds: float) -> None:
        if reason is None:
            self.event("recovered", f"{source} recovered after {seconds:.1f} s", source=source, was=previous,
                       duration_s=round(seconds, 3))
        else:
            self.event("fault", f"{source}: {reason}", source=source)

    def _stream_event(self, kind: str, message: str) -> None:
        """Lock losses, re-acquisitions and stale-model flags from the frame loop (rare, never per frame)."""
        self.event(kind, message)

    def _bring_up(self) -> None:
        self.events.compact()
        interrupted = mark_interrupted(self.storage)
        self.calibrations_finished["interrupted"] += len(interrupted)
        for job_id in interrupted:
            self.event("calibration_interrupted", f"calibration {job_id} was interrupted by the last shutdown",
                       calibration=job_id)
        removed, restored = reconcile(self.storage, self.history)
        if restored:
            self.event("record_restored", f"{len(restored)} finished calibration(s) were missing from the record and "
                                          f"were restored from their folders", calibrations=restored)
        while not self.closing.is_set():
            try:
                hardware = self.factory(self.settings, self.clock)
            except Exception as exc:  # noqa: BLE001 - any driver error: report, retry; the daemon stays up
                self.faults.set("hardware", f"cannot open the hardware: {describe(exc)}")
                self.closing.wait(self.settings.daemon.reopen_interval_s)
                continue
            self.faults.set("hardware", None)
            try:
                self._attach(hardware)
            except BaseException:
                self._detach(forget=True)
                raise
            return

    def _attach(self, hardware: Hardware) -> None:
        daemon = self.settings.daemon
        with self._lock:
            if self.closing.is_set():
                hardware.close()
                return
            self.hardware = hardware
            self.stage.attached(hardware)
            self.grating = self._new_grating()
            self.acquisition = self._new_acquisition()
        log.info("hardware open: %s camera, %s stage, limits %s mm", self.settings.hardware.camera.kind,
                 self.settings.hardware.stage.kind, hardware.stage.limits())
        self.event("start", f"daemon started ({'virtual rig' if self.settings.simulated else 'hardware'})",
                   simulated=self.settings.simulated)
        try:
            model, repaired = self.storage.reconcile_model()
            if repaired:
                log.warning("data directory: %s", repaired)
                self.event("model_reconciled", repaired)
        except Exception as exc:  # noqa: BLE001 - a broken model file: say so, stay up, let a calibration replace it
            self.faults.set("model", f"the saved model {self.storage.model_path} cannot be used "
                                     f"({describe(exc)}); run a calibration to replace it")
            return
        mismatch = None if model is None else self._camera_mismatch(model)
        if mismatch is not None:
            kind, message = mismatch
            self.faults.set("model", message)
            self.event(kind, message)
        elif model is not None:
            log.info("tracking with the saved model %s", model.describe())
            active = self.storage.active_id()
            self.install(model, active, self._learned(lambda store: store.load(active)))
        elif daemon.auto_calibrate == "always" or (daemon.auto_calibrate == "sim" and self.settings.simulated):
            log.info("no saved model: calibrating (auto_calibrate = %s)", daemon.auto_calibrate)
            try:
                self.start_calibration()
            except (Busy, NotReady) as exc:
                log.warning("automatic calibration not started: %s", exc)
        else:
            log.info("no saved model: idle until POST /api/calibration")

    def _detach(self, forget: bool = False) -> None:
        """Stop the workers and close the hardware (shutdown; ``forget`` after a bring-up that failed half-way)."""
        with self._lock:
            for worker in (self.acquisition, self.grating):
                if worker is not None:
                    worker.stop()
            if self.hardware is not None:
                self.hardware.close()
                log.info("hardware closed")
            self.hardware = None
            if forget:
                self.acquisition, self.grating = None, None

    def _new_grating(self) -> GratingPoller:
        assert self.hardware is not None
        return GratingPoller(self.hardware.stage, self.settings.daemon.grating_poll_s, self.readings,
                             self.faults.reporter("stage"), self.settings.daemon.realtime_priority).start()

    def _new_acquisition(self) -> Acquisition:
        assert self.hardware is not None
        daemon = self.settings.daemon
        acquisition = Acquisition(self.hardware.camera, self.readings, self.publish, self.faults.set,
                                  daemon.camera_fault_after_s, daemon.reopen_interval_s, self._stream_event,
                                  priority=daemon.realtime_priority,
                                  trim=ReferenceTrim(daemon.trim, self._stream_event),
                                  slide=None if daemon.grating else
                                  LiveSlide(daemon.axis_px, self.stage_acceleration_mm_s2,
                                            self.motion if daemon.stage_commanded_here else None),
                                  engine=daemon.engine, rig_meta=self._meta(self.hardware),
                                  loss_quiet_s=daemon.frames_lost_quiet_s)
        if self.model is not None:  # a frame loop restarted: with the maps the last one learned
            calibration = self.installed_calibration
            learned = self._learned(lambda store: store.newest(calibration))
            acquisition.install_model(self.model, self.grating.latest_mm() if self.grating else None, calibration,
                                      learned, self._refused(calibration))
        return acquisition.start()

    def _watch(self) -> None:
        """The watchdog: a worker thread that is gone (it should never be) is a fault, and is replaced; the
        data directory is looked at (full, read-only, removed: :mod:`datadir`) and what waited for it written."""
        self.health.probe()
        self.events.flush()
        acquisition = self.acquisition
        if acquisition is not None:
            self._save_maps(acquisition)
        with self._lock:
            if self.closing.is_set() or self.hardware is None:
                return
            if self.acquisition is not None and not self.acquisition.alive:
                self.faults.set("acquisition", "the frame loop ended unexpectedly; restarted")
                self.acquisition = self._new_acquisition()
            if self.grating is not None and not self.grating.alive:
                self.faults.set("grating-poller", "the grating poller ended unexpectedly; restarted")
                self.grating = self._new_grating()
            silent = self.grating.silent_s() if self.grating is not None else None
            if silent is not None and silent > self.settings.daemon.camera_fault_after_s:
                # the poller is blocked in a read that will time out later: its silence is the fault now,
                # within the camera's time (the poller clears it with its next good reading)
                self.faults.set("stage", f"the controller has not answered POS? for {silent:.1f} s")

    def install(self, model: FourierModel, calibration: str | None = None,
                learned: dict[str, dict[str, Any]] | None = None) -> None:
        """Track with ``model`` (of calibration ``calibration``) from a coming frame on, starting near
        the grating's position, with the maps ``learned`` with it before (by name: map_store.py)."""
        assert self.acquisition is not None
        self.model = model
        self.installed_calibration = calibration
        self.faults.set("model", None)
        self.acquisition.install_model(model, self.grating.latest_mm() if self.grating else None, calibration,
                                       learned, self._refused(calibration))

    def _learned(self, state: Callable[[MapStore], dict[str, Any] | None]) -> dict[str, dict[str, Any]]:
        """Each map's ``state(store)`` that there is, by name."""
        return {name: found for name, store in self.maps.items() if (found := state(store)) is not None}

    def _refused(self, calibration: str | None) -> Callable[[str, str], None]:
        """What the tracker calls when a map's saved state does not fit its model (the store says so)."""
        return lambda name, reason: self.maps[name].ignored(calibration, reason)

    def _save_maps(self, acquisition: Acquisition, force: bool = False) -> None:
        for name, store in self.maps.items():
            store.save(acquisition.snapshots[name].latest, force=force)

    def map_status(self, acquisition: Acquisition | None, name: str) -> dict[str, Any] | None:
        """The status part of the map ``name`` (None: no frame loop, or an engine that keeps none)."""
        store = self.maps.get(name)
        if acquisition is None or store is None:
            return None
        return store.status(acquisition.snapshots[name].latest)

    # -- state -----------------------------------------------------------------------------
    def snapshot(self) -> parts.RigSnapshot:
        """The parts read once, at this instant (what status, health and metrics are made from)."""
        stale_after = self.settings.daemon.stale_after_s
        acquisition, grating, hardware, model, job = self.acquisition, self.grating, self.hardware, self.model, self.job
        return parts.RigSnapshot(
            closing=self.closing.is_set(), faults=self.faults.snapshot(), faults_raised=self.faults.raised,
            devices=parts.read_devices(hardware.camera, hardware.stage) if hardware is not None else None,
            frame_loop=parts.read_frame_loop(acquisition, stale_after) if acquisition is not None else None,
            grating=parts.read_grating(grating, self.readings.moving(), stale_after) if grating is not None else None,
            model=model.describe() if model is not None else None,
            job=parts.job_summary(job.to_dict()) if job is not None else None,
            job_active=job is not None and job.active,
            active_calibration=active.model_dump() if (active := self.active_calibration()) is not None else None,
            target_mm=self.stage.target_mm, velocity_mm_s=self.stage.velocity_mm_s,
            calibrations_finished=dict(self.calibrations_finished), simulated=self.settings.simulated,
            stale_after_s=stale_after, uptime_s=time.monotonic() - self.started_at,
            **{name: self.map_status(acquisition, name) for name in LEARNED_MAPS})

    def frames_lost(self) -> int:
        """Frames the frame loop in work has lost (gaps in the camera's count); 0 without one."""
        acquisition = self.acquisition
        return acquisition.stats.dropped if acquisition is not None else 0

    @property
    def state(self) -> str:
        return self.snapshot().state

    def status(self) -> dict[str, Any]:
        """The ``GET /api/status`` document of this instant."""
        return status_doc.document(self.snapshot())

    # -- requests --------------------------------------------------------------------------
    def _active_job_id(self) -> str | None:
        job = self.job
        return job.id if job is not None and job.active else None

    def _abort_active_job(self, reason: str) -> str | None:
        job = self.job
        if job is None or not job.active:
            return None
        job.request_abort(reason)
        return job.id

    def _ready(self) -> tuple[Hardware, Acquisition]:
        if self.closing.is_set():
            raise NotReady("the daemon is shutting down")
        hardware, acquisition = self.hardware, self.acquisition
        if hardware is None or acquisition is None:
            faults = self.faults.snapshot()
            raise NotReady(f"hardware not ready: {sentence(faults) or 'the hardware is still being opened'}")
        return hardware, acquisition

    def start_calibration(self) -> CalibrationJob:
        # the stage's motion lock first (stage_control.py): a move checked before the job exists has reached
        # the controller before the sweep's first command, which then replaces it
        with self.stage.motion, self._lock:
            hardware, acquisition = self._ready()
            if self.job is not None and self.job.active:
                raise Busy(f"calibration {self.job.id} is already running")
            self.health.refuse()
            blocking = self.faults.blocking_calibration()
            if blocking:
                raise NotReady(f"cannot calibrate during a fault: {sentence(blocking)}")
            config = self.settings.sweep
            self._check_room(acquisition)
            job = CalibrationJob(self.storage.new_calibration_id(), config.model, config.positions,
                                 config.frames_per_position)
            try:
                self.storage.write_status(job.id, job.to_dict())
            except OSError as exc:  # no room even for its status: no job, and no empty folder left behind
                shutil.rmtree(self.storage.calibration_dir(job.id), ignore_errors=True)
                self.event("calibration_refused", f"calibration not started: {describe(exc)}")
                raise InsufficientStorage(f"cannot write to the data directory: {describe(exc)}") from None
            self.jobs[job.id] = job
            self.job = job
            runner = JobRunner(job, self.storage, self._install_calibration, self._finished, health=self.health)
            sweep = Sweep(runner, hardware.stage, acquisition, self.storage, config, self._meta(hardware),
                          self.motion.note_command, self.clock.scale,
                          stated=self.motion.stated if self.settings.daemon.stage_commanded_here else None)
            self._sweep_thread = threading.Thread(target=runner.run, args=(sweep,), name="sweep", daemon=True)
            self._sweep_thread.start()
        log.info("calibration %s started (%s, %s model)", job.id,
                 f"{config.positions} stops x {config.frames_per_position} frames" if config.kind == "stops"
                 else f"a pass of {config.scan_frames} frames", config.model)
        self.event("calibration_started", f"calibration {job.id} started", calibration=job.id)
        return job

    def _check_room(self, acquisition: Acquisition) -> None:
        """Refuse a sweep the data directory has no room for, before anything is written (its
        recording, as float64 samples, plus the model, the report and a margin)."""
        config = self.settings.sweep
        latest = acquisition.latest
        if latest is None:
            return
        frames = config.positions * config.frames_per_position if config.kind == "stops" else 3 * 2 * config.scan_frames
        needed = frames * np.asarray(latest[0].frame.pixels).size * 8 + ROOM_MARGIN_BYTES
        free = shutil.disk_usage(self.storage.calibrations).free
        if free < needed:
            message = (f"the data directory has {free / 1e6:.1f} MB free; a sweep needs about {needed / 1e6:.1f} MB "
                       f"(its recording, model and report): free some space or move [daemon] data_dir")
            self.event("calibration_refused", f"calibration not started: {message}")
            raise InsufficientStorage(message)

    def _install_calibration(self, model: FourierModel, job: CalibrationJob) -> None:
        """The job's ``installing`` step: the pointer and the copy of the model (one switch with its undo,
        :mod:`switch`), the record's row (the switch undone if it cannot be written), then the tracker:
        the tracker only ever gets a model the data directory already names."""
        switch = self._switch_model(job.id)
        try:
            self.history.add_calibration(calibration_row(job, model))
        except BaseException as exc:  # a full disk: both files back, the old model stays what is tracked
            switch.undo()
            raise (self.health.failed(exc) or exc) from None
        switch.commit()
        self.install(model, job.id)
        self.event("model_installed", f"model of calibration {job.id} installed: {model.describe()}",
                   calibration=job.id)

    def _finished(self, job: CalibrationJob) -> None:
        self.calibrations_finished[job.state] = self.calibrations_finished.get(job.state, 0) + 1
        log.info("calibration %s %s in %.1f s: %s", job.id, job.state, job.duration_s or 0.0, job.message)
        self.event(f"calibration_{job.state}", f"calibration {job.id} {job.state}: {job.message}", calibration=job.id)

    def activate(self, calibration_id: str) -> Activated:
        """Roll back (or forward) to the model of an earlier calibration that finished ``done``."""
        with self._lock:
            self._ready()
            if self.job is not None and self.job.active:
                raise Busy(f"calibration {self.job.id} is running; stop it first")
            self.health.refuse()  # a vanished or read-only directory: 507 before its files are read
            row = self.history.calibration(calibration_id)
            if row is None:
                raise NotFound(f"no finished calibration {calibration_id!r}")
            model = self._stored_model(calibration_id)
            mismatch = self._camera_mismatch(model)
            if mismatch is not None:  # a conflict with the camera's configuration, not a wait: retrying will not help
                raise Busy(mismatch[1])
            self._switch_model(calibration_id).commit()  # both files or neither: a 507 changes nothing
            self.install(model, calibration_id)
        self.event("model_installed", f"model of calibration {calibration_id} activated: {model.describe()}",
                   calibration=calibration_id)
        return Activated(active=calibration_id, model=model.describe())

    def _stored_model(self, calibration_id: str) -> FourierModel:
        """The model a finished calibration left, or :class:`DamagedCalibration` naming the file and why."""
        try:
            return load_model(self.storage.calibration_dir(calibration_id) / "model.json")
        except ModelError as exc:  # the message names the file: missing, not JSON, another schema, inconsistent
            raise DamagedCalibration(f"calibration {calibration_id} cannot be activated: {exc}") from None

    def damage(self, calibration_id: str) -> str | None:
        """Why a listed calibration's model cannot be read back (None: it reads), cached while the file is
        unchanged: the list shows it on every page load, and the check parses the whole model."""
        path = self.storage.calibration_dir(calibration_id) / "model.json"
        try:
            stat = path.stat()
            key: tuple[Any, ...] = (calibration_id, stat.st_mtime_ns, stat.st_size, stat.st_ino)
        except OSError:
            key = (calibration_id, None)
        if key not in self._damage:
            try:
                load_model(path)
                found = None
            except ModelError as exc:
                found = str(exc)
            if len(self._damage) >= DAMAGE_CACHE_ENTRIES:
                self._damage.clear()
            self._damage[key] = found
        return self._damage[key]

    def _switch_model(self, calibration_id: str) -> Switch:
        """``DATA/active`` and ``DATA/model.json`` to that calibration's, as one step with its undo; a full,
        read-only or vanished data directory is the ``storage`` fault and a 507 naming it, nothing changed."""
        needed = (self.storage.calibration_dir(calibration_id) / "model.json").stat().st_size + SWITCH_MARGIN_BYTES
        self.health.refuse(needed)
        try:
            # the old model's maps go with it: no save of them slips in after the switch removed their files
            return self.map_switch.switch(lambda: self.storage.switch_model(calibration_id))
        except OSError as exc:
            raise (self.health.failed(exc, needed) or exc) from None

    def active_calibration(self) -> ActiveCalibration | None:
        """The calibration whose model is tracked now (None: no model, or one not from a calibration)."""
        active = self.storage.active_id()
        if active is None or self.model is None:
            return None
        row = self.history.calibration(active)
        if row is None:
            return ActiveCalibration(id=active)
        return ActiveCalibration.model_validate({key: row[key] for key in ActiveCalibration.model_fields})

    def _camera_mismatch(self, model: FourierModel) -> tuple[str, str] | None:
        """Why ``model`` cannot track this camera's frames, as (event kind, message): calibrated on another readout
        range (``pixels``: a pixel format changed since), or with the other ``[camera] flip`` (``geometry``)."""
        if self.hardware is not None:
            readout = readout_mismatch(model.info, self._meta(self.hardware))
            if readout is not None:
                return "pixels", f"{readout}; recalibrate, or set the camera's pixel format back"
        calibrated = model.info.get("camera_flip")
        now = bool(getattr(self.hardware.camera.settings, "flip", False)) if self.hardware is not None else None
        if calibrated is None or now is None or bool(calibrated) == now:
            return None
        return "geometry", (f"the model was calibrated with [camera] flip = {str(bool(calibrated)).lower()} and the "
                            f"camera now has flip = {str(now).lower()}: its frames run the other way; recalibrate or "
                            f"set flip back")

    def _meta(self, hardware: Hardware) -> dict[str, Any]:
        meta: dict[str, Any] = hardware.rig.meta() if hardware.rig is not None else {}  # type: ignore[attr-defined]
        meta.update({"source": "graytrack serve", "daemon_version": __version__})
        if hardware.rig is None:  # a real camera: [camera] trigger, where its driver has one, starts each exposure
            meta[CAMERA_TRIGGER] = str(getattr(hardware.camera, "trigger", "free-run"))
            if hardware.camera.bit_depth is not None:  # its readout's ceiling: samples clipped there set aside
                meta["bit_depth"] = hardware.camera.bit_depth
        if getattr(hardware.camera.settings, "flip", False):  # [camera] flip: frames reversed at the driver
            meta[PIXEL_AXIS_REVERSED] = True
        for key in ("pixel_pitch_mm", "period_mm"):
            value = getattr(self.settings.sweep, key)
            if value is not None:
                meta[key] = value
        if self.settings.daemon.mains_hz is not None:  # [daemon] mains_hz: the lamp's mains, its flicker at twice it
            meta[MAINS_HZ] = self.settings.daemon.mains_hz
        return meta

    def calibration(self, calibration_id: str) -> Calibration:
        """A job of this run (from memory, as it is now) or of an earlier one (its ``status.json``)."""
        job = self.jobs.get(calibration_id)
        document = job.to_dict() if job is not None else self.storage.read_status(calibration_id)
        if document is None:
            raise NotFound(f"no calibration {calibration_id!r}")
        return Calibration.model_validate(document)

    def latest_calibration(self) -> Calibration:
        latest = self.storage.latest_calibration_id()
        if latest is None:
            raise NotFound("no calibration has been run yet")
        return self.calibration(latest)
