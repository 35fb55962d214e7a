"""One calibration pipeline: a recording in; the model, its held-out error next to the bound of the
same frames, the report and its files out.

`graytrack calibrate`, `graytrack diagnose`, `graytrack batch` and the daemon's sweep all calibrate
through :func:`calibrate_recording` and write through :func:`write_files`, so a calibration reads
the same (``report.json`` keys, ``report.html``, the terminal's lines) wherever it was made, and
what is written is what the caller holds: nothing is read back.

``report.json`` of every kind carries ``kind``, ``model``, ``summary`` (one sentence: the job's
message and the history's row), ``held_out`` (``error_std_um``, ``bound_um``, ``frames``, ``method``,
or null when the data cannot be split), ``noise`` (``gray``, ``crlb_um``), ``geometry`` and
``findings``; the closed loop adds its contract's ``before``, ``steps`` and ``after``
(docs/contracts.md), the seed paper's and ideal models their fit in gray levels.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from graytrack.core.files import write_atomic
from graytrack.core.jsonable import finite_or_none
from graytrack.service.figures import positive, shown, structure

if TYPE_CHECKING:
    from graytrack.core.diagnosis.heldout import HeldOut
    from graytrack.core.diagnosis.loop import DiagnosisResult
    from graytrack.core.geometry_check import GeometryCheck
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording

KINDS = ("ideal", "paper", "auto")
Progress = Callable[[float, str], None]
NO_TRANSIENTS = {"count": 0, "frames": 0, "samples": 0, "events": []}
SHARED_NOISE_SPREAD = 2.0  # a frames' χ² spread (core/chi2_curve.py frame_spread) from which the calibration says
# the sensor's noise is shared between samples: each frame's test then counts a quarter of its samples or fewer,
# and a camera with row banding or flickering pixels is worth a look (its black level, its readout settings)


@dataclass
class CalibrationRun:
    """A finished calibration: what every caller keeps, installs or prints."""

    kind: str
    model: "FourierModel"
    report: dict[str, Any]  # report.json, exactly as written
    held_out: "HeldOut | None"
    geometry: "GeometryCheck | None"
    diagnosis: "DiagnosisResult | None" = None  # the closed loop's stages (its plots), for kind "auto"
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def refused(self) -> bool:
        """The rig's geometry is at fault (a reversed pixel axis, a wrong period): no model to keep."""
        return self.geometry is not None and self.geometry.refused

    def raise_if_refused(self) -> None:
        from graytrack.core.geometry_check import raise_if_refused

        raise_if_refused(self.geometry)

    @property
    def summary(self) -> str:
        return str(self.report.get("summary", ""))

    def lines(self) -> list[str]:
        """What the terminal prints (ASCII), the report's figures in short."""
        return loop_lines(self.report) if self.kind == "auto" else fit_lines(self.report)

    def warnings(self) -> list[str]:
        """Lines for stderr: a doubtful geometry's causes, a model that errs on its own calibration."""
        check = self.report.get("geometry") or {}
        doubtful = check.get("status") == "doubtful"
        lines = [f"warning: {text}" for text in check.get("warnings") or []] if doubtful else []
        from graytrack.core.adequacy import inadequacy
        from graytrack.core.compression import judged_factor

        info = self.model.info
        stream = info.get("stream")
        if stream:
            lines.append(f"warning: the frames come from a JPEG stream (quality ~{stream['quality']}): "
                         f"its quantisation widens every position's bound {stream['bound_factor']:.1f}x "
                         "(tracking reports the wider bound); "
                         "set the camera to an uncompressed pixel format (Mono8, Mono12) for the sensor's own")
        spread = float(info.get("frame_chi2_spread") or 1.0)
        if info.get("row_offset_gray"):
            lines.append(f"warning: every row of the strip is offset by {float(info['row_offset_gray']):.2f} gray (σ) "
                         "drawn afresh each frame (row banding: the readout's reference drifting line by line); "
                         "tracking takes each row's offset out of every frame, at some cost in precision: the "
                         "camera's black-level clamp or readout settings may remove it")
        if info.get("frame_offset_gray"):
            lines.append(f"warning: every frame is offset by {float(info['frame_offset_gray']):.2f} gray (σ) drawn "
                         "afresh each frame (the readout's black level drifting frame by frame); tracking takes "
                         "each frame's offset out of its solve, at some cost in precision: the camera's black-level "
                         "clamp or readout settings may remove it")
        if info.get("frame_gain_rate"):
            lines.append(f"warning: the light's gain walks {100 * float(info['frame_gain_rate']):.1f} % per √s from "
                         "frame to frame (a camera hunting its exposure or gain); tracking lets the light move that "
                         "fast, at some cost in precision: fix the camera's exposure and gain (auto-exposure off)")
        if spread >= SHARED_NOISE_SPREAD:
            lines.append(f"warning: the frames' residual scatters {spread:.1f}x as widely from frame to frame as "
                         "independent noise in each sample would: the sensor's noise is shared between samples (a "
                         "row's offset drawn each frame, pixels flickering between two levels); each frame's test "
                         f"counts {1.0 / spread ** 2:.0%} of its samples as independent")
        flipping = [entry for entry in info.get("bad_pixels") or [] if "two levels" in str(entry.get("reason", ""))]
        if flipping:  # (core/estimator/two_level.py: set aside by calibration)
            named = ", ".join(f"({entry['row']}, {entry['pixel']})" for entry in flipping[:8])
            more = f" and {len(flipping) - 8} more" if len(flipping) > 8 else ""
            lines.append(f"warning: pixel(s) {named}{more} read at one of two levels, switching at random (a charge "
                         "trap in the sensor: random telegraph noise); set aside (weight 0) in the model and in "
                         f"tracking; ({flipping[0]['row']}, {flipping[0]['pixel']}) {flipping[0]['reason']}")
        if inadequacy(info):
            ratio = info["calibration_error_ratio"] / judged_factor(info)
            lines.append(f"warning: this model places its own calibration frames {ratio:.1f}x as far off as their "
                         "noise floor: it does not describe this rig, and every position it gives will be flagged "
                         "stale (geometry); use --model auto (the closed loop) or graytrack diagnose for the cause")
        return lines

    @classmethod
    def of_diagnosis(cls, result: "DiagnosisResult") -> "CalibrationRun":
        """A closed-loop result as a calibration: its report gains the keys every kind carries."""
        from graytrack.core.diagnosis.heldout import HeldOut

        report = result.report()
        after = result.after.figures
        held_out = HeldOut.of([after], f"closed loop, {report['heldout']}")
        added = ", ".join(step["effect"].replace("_", " ") for step in report["steps"])
        report.update(finite_or_none({
            "kind": "auto", "model": result.final_model.describe(), "held_out": held_out.as_dict(),
            "summary": (f"closed loop: held-out error {shown(report['after']['error_std_um'], 2, 'µm')} "
                        f"(bound {shown(report['noise']['crlb_um'], 2, 'µm')}); "
                        + (f"added {added}" if added else "nothing added: the seed paper's model holds")
                        + _doubts(report.get("geometry")))}))
        return cls("auto", result.final_model, report, held_out, result.geometry, result)


def calibrate_recording(recording: "Recording", kind: str = "paper", *, validation: "Recording | None" = None,
                        harmonics: int | None = None, pixel_degree: int | None = None, rows: str = "auto",
                        info: dict[str, Any] | None = None, progress: Progress | None = None) -> CalibrationRun:
    """Calibrate ``recording`` with the model ``kind`` (``ideal``, ``paper``, or ``auto``: the closed loop).

    Every kind is judged by core/diagnosis/heldout.py on frames its fit did not see: ``validation``
    when given, else blocks of ``recording`` (the same frames whoever calls: the CLI, batch, the
    daemon). ``info`` is added to the model's info before anything is written (the daemon's camera
    orientation, ``--flip``). A refused geometry raises :class:`GeometryError` for
    ``ideal``/``paper``; the closed loop returns the run with ``refused`` set, so that its report
    can still be written.
    """
    if kind not in KINDS:
        from graytrack.core.errors import CalibrationError

        raise CalibrationError(f"unknown model kind {kind!r} (expected one of {', '.join(KINDS)})")
    if kind == "auto":
        from graytrack.core.diagnosis import diagnose

        run = CalibrationRun.of_diagnosis(diagnose(recording, validation, progress=progress))
    else:
        run = _fit(recording, kind, harmonics, pixel_degree, rows, validation, progress)
    run.model.info.update(info or {})
    run.report["recording"] = recording_facts(recording)
    return run


def recording_facts(recording: "Recording") -> dict[str, Any]:
    """What the recording says about itself that a reader of the report needs: its source, and for
    the virtual rig its scenario and the effects switched on (which no model is told about)."""
    meta = recording.meta
    return {"source": meta.get("source"), "scenario": meta.get("scenario"),
            "simulated_effects": [str(effect) for effect in meta.get("effects") or []]}


HELD_OUT_SHARE = 0.6  # of the progress bar, the fit on all frames; the held-out refits take the rest


def _fit(recording: "Recording", kind: str, harmonics: int | None, pixel_degree: int | None, rows: str,
         validation: "Recording | None", progress: Progress | None) -> CalibrationRun:
    """The ideal or seed paper's model, fitted on all frames, with its held-out error."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.diagnosis.heldout import validate

    scaled = None if progress is None else (lambda f, label: progress(HELD_OUT_SHARE * f, label))
    result = calibrate(recording, kind, harmonics=harmonics, pixel_degree=pixel_degree, rows=rows, progress=scaled)
    model = result.model
    if progress:
        progress(HELD_OUT_SHARE, "held-out error: refitting without the held-out frames")

    def fit(part: "Recording") -> "FourierModel":
        return calibrate(part, kind, harmonics=harmonics, pixel_degree=pixel_degree, rows=rows).model

    held_out = validate(recording, fit, validation=validation, fitted=model, label=f"{kind} model")
    held = held_out.as_dict() if held_out is not None else None
    quality = "" if held is None else (f"held-out error {shown(held['error_std_um'], 2, 'µm')} "
                                       f"(bound {shown(held['bound_um'], 2, 'µm')}), ")
    report = finite_or_none({
        "kind": kind, "model": model.describe(), "rmse_gray": result.rmse_gray, "sigma_gray": result.sigma_gray,
        "iterations": result.iterations, "frames": recording.n_frames,
        "stroke_mm": float(np.ptp(recording.reference[np.isfinite(recording.reference)])),
        "period_mm": model.period_mm, "pixel_pitch_mm": model.pixel_pitch_mm,
        "noise": {"gray": result.sigma_gray, "crlb_um": None if held is None else held["bound_um"]},
        "held_out": held,
        "geometry": result.geometry.as_dict(),
        "summary": (f"{kind} model: {quality}rms {shown(result.rmse_gray, 3)} gray "
                    f"(noise {shown(result.sigma_gray, 3)} gray)" + _doubts(result.geometry.as_dict())),
        "findings": {"transients": model.info.get("transients") or NO_TRANSIENTS},
    })
    if progress:
        progress(1.0, f"done, held-out error {shown(held['error_std_um'] if held else None, 2, 'µm')}")
    return CalibrationRun(kind, model, report, held_out, result.geometry)


def _doubts(geometry: dict[str, Any] | None) -> str:
    """A doubtful geometry check's causes, appended to the summary (and so to the job's event)."""
    if not geometry or geometry.get("status") != "doubtful":
        return ""
    return "; geometry doubtful: " + "; ".join(geometry.get("warnings") or [])


def write_files(run: CalibrationRun, folder: str | os.PathLike[str], name: str = "") -> dict[str, Path]:
    """``model.json`` (not for a refused geometry: an older one is removed rather than left to look
    current), ``report.json`` and ``report.html`` in ``folder``; the paths by name, also kept in
    ``run.files``. ``name``: the calibration's id, in the page's title."""
    from graytrack.core.models import save_model
    from graytrack.service.report import render_html

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"model": folder / "model.json", "json": folder / "report.json", "html": folder / "report.html"}
    if run.refused:
        paths.pop("model").unlink(missing_ok=True)
    else:
        save_model(run.model, paths["model"])
    write_atomic(paths["json"], json.dumps(run.report, indent=1, allow_nan=False, default=float))
    write_atomic(paths["html"], render_html(run, name))
    run.files.update(paths)
    return paths


# ----------------------------------------------------------------------------- terminal lines
def _figure(value: float | None, digits: int) -> str:
    return shown(value, digits, missing="n/a")  # the terminal gets ASCII


def _figures(entry: dict) -> str:
    lost = f", {_figure(entry['lost_frames'], 0)} frame(s) not tracked" if entry.get("lost_frames") else ""
    return f"rmse {_figure(entry['rmse_gray'], 4)} gray, error std {_figure(entry['error_std_um'], 3)} um{lost}"


def geometry_lines(report: dict) -> list[str]:
    """The geometry check first: a refusal, or the likely causes of a doubt."""
    check = report.get("geometry") or {}
    if check.get("status") == "refused":
        return [f"REFUSED {check['message']} (the loop stopped; no model written)"]
    return [f"warning {text}" for text in check.get("warnings") or []] if check.get("status") == "doubtful" else []


def _transient_line(report: dict) -> list[str]:
    transients = (report.get("findings") or {}).get("transients")
    if not (transients and transients.get("count")):
        return []
    from graytrack.core.transients import summary_line

    return [f"data    {summary_line(transients)}"]


def loop_lines(report: dict) -> list[str]:
    """The closed loop's figures: before, each step, after, the bound and what limits it."""
    before, after, noise = report["before"], report["after"], report["noise"]
    lines = geometry_lines(report) + [f"before  {structure(before['model'])}: {_figures(before)}"]
    for step in report["steps"]:
        lines.append(f"  + {step['effect']:<16} {step['evidence']}")
        lines.append(f"    {'':<16} {_figures(step)}")
    lines.append(f"after   {structure(after['model'])}: {_figures(after)}")
    if report.get("final_model") and (report.get("geometry") or {}).get("status") != "refused":
        lines.append(f"model   {report['final_model']} (model.json: fitted on every calibration frame)")
    lines.append(f"noise   sigma {_figure(noise['gray'], 4)} gray, Cramer-Rao bound {_figure(noise['crlb_um'], 3)} um")
    compression = (report.get("findings") or {}).get("compression")
    if compression:
        lines.append(f"        frames from a JPEG stream (quality ~{_figure(compression.get('quality'), 0)}): "
                     f"with its quantisation the bound is {_figure(compression.get('crlb_um'), 3)} um")
    if positive(noise.get("reference_resolution_um")):
        lines.append(f"        grating readout in steps of {_figure(noise['reference_resolution_um'], 3)} um: "
                     f"readout floor {_figure(noise['floor_um'], 3)} um")
    return lines + _transient_line(report)


def fit_lines(report: dict) -> list[str]:
    """An ideal or paper fit: the model, its fit against the noise, its held-out error when measured."""
    lines = [f"model   {report['model']}",
             f"rmse    {_figure(report.get('rmse_gray'), 4)} gray "
             f"(noise sigma {_figure(report.get('sigma_gray'), 4)} gray from the data)"]
    held = report.get("held_out")
    if held:
        lines.append(f"held    error std {_figure(held.get('error_std_um'), 3)} um "
                     f"on {_figure(held.get('frames'), 0)} held-out frames, "
                     f"Cramer-Rao bound {_figure(held.get('bound_um'), 3)} um ({held.get('method')})")
    return lines + _transient_line(report)
