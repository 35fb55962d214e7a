"""Calibration jobs as one state machine, persisted at every step in ``status.json``::

    queued → sweeping → fitting → installing → done
                 ↘          ↘           ↘
                  aborted (stop request, shutdown)   failed (any exception, with its reason)
    (found unfinished at start-up: a crash or kill -9) → interrupted

Installing the new model (``DATA/model.json`` and the running tracker) is a step of the job and
happens before ``done`` is written, so ``done`` always means "this is the model in use". Any
exception ends the job ``failed`` with its reason; the rig's state is derived from the job being
active, so it is restored by the job ending, whatever ended it.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Callable, Protocol

from graytrack.core.models import load_model
from graytrack.core.models.fourier import FourierModel
from graytrack.service.daemon.clock import HOST_CLOCK, Clock
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.worker import describe

log = logging.getLogger("graytrack.daemon")
ACTIVE = ("queued", "sweeping", "fitting", "installing")
FINAL = ("done", "failed", "aborted", "interrupted")


class Aborted(Exception):
    """The job was stopped on request (``POST /api/stage/stop``) or by shutdown."""


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat()


@dataclass
class CalibrationJob:
    """One calibration request, its progress and its outcome; what ``GET /api/calibration/{id}`` returns."""

    id: str
    model: str
    positions: int
    frames_per_position: int
    state: str = "queued"
    progress: float = 0.0
    message: str = "queued"
    started: str = field(default_factory=utc_now)
    finished: str | None = None
    duration_s: float | None = None
    error: str | None = None
    report: dict[str, Any] | None = None
    files: dict[str, str] = field(default_factory=dict)
    abort: threading.Event = field(default_factory=threading.Event, repr=False)
    abort_reason: str = field(default="calibration aborted by a stop request", repr=False)

    @property
    def active(self) -> bool:
        return self.state in ACTIVE

    def to_dict(self) -> dict[str, Any]:
        return {key: value for key, value in self.__dict__.items() if key not in ("abort", "abort_reason")}

    def request_abort(self, reason: str) -> None:
        self.abort_reason = reason
        self.abort.set()

    def check_abort(self) -> None:
        if self.abort.is_set():
            raise Aborted(self.abort_reason)


class Steps(Protocol):
    """What a job runs: the sweep, then the fit (:class:`graytrack.service.daemon.sweep.Sweep`)."""

    def sweep(self) -> Any: ...

    def fit(self, recording: Any) -> FourierModel: ...


class JobRunner:
    """Runs one job through its states on the calling thread and persists every change."""

    def __init__(self, job: CalibrationJob, storage: Storage, install: Callable[[FourierModel, CalibrationJob], None],
                 on_finish: Callable[[CalibrationJob], None], clock: Clock = HOST_CLOCK,
                 health: DataDirHealth | None = None) -> None:
        self.job, self.storage, self.install, self.on_finish = job, storage, install, on_finish
        self.clock = clock  # the job's duration is measured on it (service/daemon/clock.py)
        self.health = health  # a full or vanished data directory: the cause it names, the final status kept
        self._logged_tenth = -1  # of the progress, logged last

    def enter(self, state: str, progress: float | None = None, message: str | None = None) -> None:
        self._commit(state, progress, message)

    def update(self, progress: float | None = None, message: str | None = None) -> None:
        self._commit(None, progress, message)

    def _commit(self, state: str | None, progress: float | None, message: str | None) -> None:
        """On disk first, then in memory: whoever saw the job in a state (the API, a kill -9 right
        after) finds its status.json there too."""
        changes: dict[str, Any] = {}
        if state is not None:
            changes["state"] = state
        if progress is not None:
            changes["progress"] = round(float(progress), 4)
        if message is not None:
            changes["message"] = message
        self.storage.write_status(self.job.id, {**self.job.to_dict(), **changes})
        for key, value in changes.items():
            setattr(self.job, key, value)
        self._log_progress(state is not None)

    def _log_progress(self, entered: bool) -> None:
        """A log line per state and per tenth of the progress bar: the daemon's first start calibrates for
        ~30 s, and a log that said only "started" and "done" looked like a daemon that hung."""
        tenth = int(self.job.progress * 10 + 1e-9)
        if entered or tenth > self._logged_tenth:
            self._logged_tenth = tenth
            log.info("calibration %s: %s %d %% · %s", self.job.id, self.job.state, round(100 * self.job.progress),
                     self.job.message)

    def run(self, steps: Steps) -> None:
        job, started = self.job, self.clock.now()
        outcome: dict[str, Any]
        try:
            recording = steps.sweep()
            model = steps.fit(recording)
            job.check_abort()  # a stop during the fit: the operator asked for no new model
            self.enter("installing", message="installing the new model")
            self.install(model, job)
            outcome = {"state": "done", "progress": 1.0, "message": (job.report or {}).get("summary", "done")}
        except Aborted as exc:
            outcome = {"state": "aborted", "error": str(exc), "message": str(exc)}
        except Exception as exc:  # noqa: BLE001 - every failure ends the job with its reason
            if job.abort.is_set():  # a stop request interrupted a move or a settle
                outcome = {"state": "aborted", "error": describe(exc), "message": job.abort_reason}
            else:
                refused = self.health.failed(exc) if self.health is not None else None
                reason = str(refused) if refused is not None else describe(exc)
                outcome = {"state": "failed", "error": reason, "message": f"failed: {reason}"}
                log.error("calibration %s failed: %s", job.id, reason, exc_info=not _expected(exc))
        outcome.update(finished=utc_now(), duration_s=round(self.clock.now() - started, 3))
        # on disk first, then in memory: whoever sees the job ended finds its status.json ended too
        final = {**job.to_dict(), **outcome}
        try:
            self.storage.write_status(job.id, final)
        except Exception as exc:  # noqa: BLE001 - a full disk: the job is over anyway; its end is kept for later
            if self.health is not None and self.health.failed(exc) is not None:
                self.health.defer(f"calibration {job.id}'s final status ({outcome['state']})",
                                  lambda: self.storage.write_status(job.id, final), final)
            else:
                log.exception("calibration %s: cannot write its final status", job.id)
        for key, value in outcome.items():
            setattr(job, key, value)
        self.on_finish(job)


def _expected(exc: Exception) -> bool:
    """Failures with a clear message of their own (no traceback needed in the log)."""
    from graytrack.core.errors import GraytrackError
    from graytrack.drivers.stage.errors import StageError

    return isinstance(exc, (GraytrackError, StageError))


def mark_interrupted(storage: Storage) -> list[str]:
    """Jobs left active by a crash or kill -9 become ``interrupted``; their ids."""
    marked = []
    for calibration_id in storage.calibration_ids():
        document = storage.read_status(calibration_id)
        if document is not None and document.get("state") in ACTIVE:
            document.update(state="interrupted", finished=document.get("finished") or utc_now(),
                            message=f"interrupted while {document['state']} (the daemon stopped)",
                            error="the daemon stopped before the job finished")
            storage.write_status(calibration_id, document)
            marked.append(calibration_id)
    if marked:
        log.warning("calibration(s) %s were interrupted by the last shutdown", ", ".join(marked))
    return marked


def calibration_row(job: CalibrationJob, model: FourierModel) -> dict[str, Any]:
    """The record's row of a job being installed (its files by name, its quality in µm)."""
    return row_of(job.to_dict(), model.describe(), utc_now())


def row_of(document: dict[str, Any], model: str | None, finished: str | None) -> dict[str, Any]:
    """The record's row from a job's document (as ``status.json`` keeps it)."""
    report = document.get("report") or {}
    held_out = report.get("held_out") or {}
    effects = [step.get("effect") for step in report.get("steps", []) if step.get("effect")]
    return {"id": document["id"], "started": document.get("started") or "", "finished": finished or "",
            "model_kind": document.get("model") or "", "model": model,
            "error_std_um": held_out.get("error_std_um"), "bound_um": held_out.get("bound_um"),
            "frames": report.get("frames"), "effects": effects,
            "files": sorted({Path(p).name for p in (document.get("files") or {}).values()}),
            "summary": report.get("summary")}


def reconcile(storage: Storage, record: Any) -> tuple[list[str], list[str]]:
    """Make the record's calibrations those the folders say ended ``done``: ``(removed, restored)``."""
    done = {}
    for calibration_id in storage.calibration_ids():
        document = storage.read_status(calibration_id)
        if document is not None and document.get("state") == "done" and document.get("id") == calibration_id:
            done[calibration_id] = document
    listed = set(record.calibration_ids())
    removed = sorted(listed - set(done))
    record.remove_calibrations(removed)
    restored = sorted(set(done) - listed)
    for calibration_id in restored:
        document = done[calibration_id]
        try:
            model = load_model(storage.calibration_dir(calibration_id) / "model.json").describe()
        except Exception:  # noqa: BLE001 - the row says what it can; activating it will say why not
            model = None
        record.add_calibration(row_of(document, model, document.get("finished")))
    return removed, restored
