"""One recording's work in a batch, as run on a Dask worker: the single command's outputs under
``OUT/<name>/``, and the recording's row of ``summary.csv``.

Whatever goes wrong with one recording (an unreadable file, a refused calibration, a bug) ends
as that row's ``failed`` status with a one-line reason; the batch goes on. A row is written to
``OUT/<name>/batch.json`` after every output file, so its presence means the outputs are
complete; with the work's kind, options and the input's size and time in it, that is what resume
checks.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from graytrack.core.errors import GraytrackError
from graytrack.core.files import write_atomic
from graytrack.core.geometry_spread import geometry_spread
from graytrack.core.models import load_model, save_model
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import Recording, load
from graytrack.service.batch.discover import Source
from graytrack.service.batch.summary import MARKER, format_row

KINDS = ("track", "diagnose", "calibrate")


@dataclass(frozen=True)
class Job:
    kind: str
    source: Source
    out_dir: str
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def folder(self) -> Path:
        return Path(self.out_dir) / self.source.name


def one_line(exc: BaseException) -> str:
    """The reason a row failed: the message of a refusal, the type too for anything unexpected."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, (GraytrackError, FileNotFoundError, PermissionError)):
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _geometry(model: FourierModel) -> dict[str, Any]:
    return {"model": model.describe(), "tau_w_mm": model.period_mm, "alpha_d_mm": model.pixel_pitch_mm,
            "noise_gray": model.noise_gray}


def _spread(rec: Recording) -> dict[str, Any]:
    """τ_w and α·d uncertainty; unknown (empty) when the parts cannot be calibrated on their own."""
    try:
        spread = geometry_spread(rec)
    except GraytrackError:
        return {}
    return {"tau_w_u_mm": spread.period_mm, "alpha_d_u_mm": spread.pixel_pitch_mm}


def _calibrate(rec: Recording, job: Job) -> dict[str, Any]:
    from graytrack.service.calibration_run import calibrate_recording, write_files

    kind = job.options.get("model", "paper")
    run = calibrate_recording(rec, kind)
    if kind == "auto":
        return _loop_row(run, rec, job, write_all=False)
    write_files(run, job.folder)
    return {**_geometry(run.model), "rmse_gray": run.report["rmse_gray"], "noise_gray": run.report["sigma_gray"],
            **_spread(rec)}


def _diagnose(rec: Recording, job: Job) -> dict[str, Any]:
    from graytrack.service.calibration_run import calibrate_recording

    return _loop_row(calibrate_recording(rec, "auto"), rec, job)


def _loop_row(run: Any, rec: Recording, job: Job, write_all: bool = True) -> dict[str, Any]:
    """The closed loop's row: its report and model written (only the model for ``calibrate
    --model auto``); a refused geometry fails the row with its cause, after the report says more."""
    from graytrack.service.calibration_run import write_files

    report = run.report
    if write_all:
        write_files(run, job.folder)
    run.raise_if_refused()
    if not write_all:
        save_model(run.model, job.folder / "model.json")
    before, after = report["before"], report["after"]
    return {**_geometry(run.model), "rmse_gray": after["rmse_gray"], "noise_gray": report["noise"]["gray"],
            "error_std_before_um": before["error_std_um"], "crlb_before_um": report["noise"]["crlb_before_um"],
            "error_std_after_um": after["error_std_um"], "crlb_after_um": report["noise"]["crlb_um"],
            "effects": ";".join(step["effect"] for step in report["steps"]), **_spread(rec)}


def _track_model(rec_path: Path, option: str | None) -> Path:
    path = Path(option) if option else rec_path.parent / "model.json"
    if not path.is_file():
        raise GraytrackError(f"no model: {path} does not exist (pass --model, or keep model.json beside the recording)")
    return path


def _track(rec: Recording, job: Job) -> dict[str, Any]:
    from graytrack.core.noise import pooled_bound
    from graytrack.core.slide import carry
    from graytrack.service.commands.track import oriented, result_columns, slide_for, solve
    from graytrack.service.tables import write_csv

    model = load_model(_track_model(job.source.path, job.options.get("model")))
    notes: list[str] = []  # what `track` prints besides its summary: the row's, on a worker nobody watches
    rec = oriented(rec, model, False, note=notes.append)  # a model calibrated with --flip reverses its frames too
    no_reference = bool(job.options.get("no_reference"))
    slide = slide_for(rec, model, no_reference)  # no grating: the bounds carry the slide, as `track`'s do
    result, grating, _ = solve(rec, model, no_reference, slide=slide, note=notes.append)  # no trim: no watch
    write_csv(job.folder / "track.csv", {**result_columns(rec.t, result, grating), **carry(result, slide)})
    error = result.error_um(grating)
    placed = np.isfinite(error)
    return {**_geometry(model), "rmse_gray": float(np.nanmedian(result.rms_gray)) if result.locked.any() else None,
            "error_std_after_um": float(np.nanstd(error)) if placed.sum() > 1 else None,
            "crlb_after_um": pooled_bound(result.crlb_mm) * 1e3 if result.locked.any() else None,
            "locked": int(result.locked.sum()), "lock_events": len(result.events),
            "notes": "; ".join(" ".join(line.split()) for line in notes)}


WORK: dict[str, Callable[[Recording, Job], dict[str, Any]]] = {
    "track": _track, "diagnose": _diagnose, "calibrate": _calibrate,
}


def _where_and_when(source: Source, rec: Recording | None) -> dict[str, Any]:
    """Rig and calibration time: from the data directory's layout, else the recording's meta,
    else the folder the recording sits in and the file's modification time."""
    meta = rec.meta if rec is not None else {}
    when = source.calibrated_at or str(meta.get("calibrated_at", ""))
    if not when and source.path.exists():
        stamp = datetime.fromtimestamp(source.path.stat().st_mtime, timezone.utc)
        when = stamp.isoformat().replace("+00:00", "Z")
    return {"path": str(source.path), "name": source.name,
            "rig": source.rig or str(meta.get("rig", "")) or source.path.resolve().parent.name,
            "calibrated_at": when}


def fingerprint(path: Path) -> list[int]:
    """Size and modification time of the input: a replaced recording is new work, not a finished one."""
    stat = path.stat()
    return [stat.st_size, stat.st_mtime_ns]


def run_job(job: Job) -> dict[str, str]:
    """Do one recording's work and return its summary row (never raises for the recording's sake)."""
    started = time.perf_counter()
    rec: Recording | None = None
    try:
        rec = load(job.source.path)
        figures = WORK[job.kind](rec, job)
        status, reason = "ok", ""
    except Exception as exc:  # noqa: BLE001 - one recording's failure is its row, never the batch's
        figures, status, reason = {}, "failed", one_line(exc)
    shape = {"frames": rec.n_frames, "rows_x_pixels": f"{rec.n_rows}x{rec.n_pixels}"} if rec is not None else {}
    row = format_row({**_where_and_when(job.source, rec), **shape, **figures,
                      "seconds": time.perf_counter() - started, "status": status, "reason": reason})
    if status == "ok":
        marker = {"kind": job.kind, "options": job.options, "path": str(job.source.path),
                  "input": fingerprint(job.source.path), "row": row}
        write_atomic(job.folder / MARKER, json.dumps(marker, indent=1))
    return row


def finished_row(job: Job) -> dict[str, str] | None:
    """The row of an earlier run whose outputs are complete for the same work, else None."""
    try:
        marker = json.loads((job.folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    try:
        current = fingerprint(job.source.path)
    except OSError:
        return None
    same = (marker.get("kind") == job.kind and marker.get("options") == job.options
            and marker.get("path") == str(job.source.path) and marker.get("input") == current)
    return marker.get("row") if same and isinstance(marker.get("row"), dict) else None
