"""Held-out validation: which frames a fit does not see, and the figures a model earns on them.

The one place where held-out frames are chosen and measured, for every caller: ``graytrack
calibrate`` and ``batch`` (ideal and paper models), the daemon's calibration sweep, and the closed
loop (``diagnose``, ``--model auto``). Each gets a :class:`HeldOut`. Two choices of frames:

- a separate validation recording of the same rig, when there is one (:func:`validate`,
  :func:`loop_split`);
- blocks of the calibration recording itself, read off its grating readings by one function
  (:func:`reading_blocks`): a block is made of whole runs of one reading, so a held-out frame never
  sits at a position the fit saw (a stop of a step-and-settle sweep is held out whole or not at
  all), and the same recording gets the same blocks whoever calibrates it.

The folds differ, and must. A plain fit (:func:`validate`) is measured two-fold (fit on the even
blocks of :func:`held_out_blocks`, measure on the odd ones, and the other way round): every frame is
held out once, and the figure is the model's, fitted on all. The closed loop (:func:`loop_split`)
compares dozens of candidate models with each other, and its probes read one fitted model's residual
on frames it never saw (:class:`LoopModel`): it needs one model per candidate and one fold none of
them fitted, the same frames for every candidate (two folds would make two models of each and double
every fit). It keeps three quarters of the frames to fit each candidate's extra terms on: every
``HOLDOUT_EVERY``-th block of at least ``HOLDOUT_BLOCK_FRAMES``, fine blocks so that the probes see
held-out frames all along the stroke and the recording time. Its final model is refitted on every
frame afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from graytrack.core.calibration_data import CalibrationData, calibration_data
from graytrack.core.effects.focus import FOCUS_INFO, with_frame_focus
from graytrack.core.errors import CalibrationError
from graytrack.core.holdout import held_out, reading_blocks, reading_runs
from graytrack.core.models.fourier import FourierModel
from graytrack.core.noise import crlb_mm, pooled_bound
from graytrack.core.recording import Recording
from graytrack.core.regression import weighted_affine
from graytrack.core.timing import runs
from graytrack.core.tracking import Tracker, TrackResult, track

if TYPE_CHECKING:
    from graytrack.core.structure import ModelSpec

HELD_OUT_BLOCKS = 40  # a scan (no stops) is cut into this many blocks for the two-fold held-out error


def interleaved_split(data: CalibrationData) -> tuple[CalibrationData, CalibrationData]:
    """The closed loop's one fold (core/holdout.py :func:`~graytrack.core.holdout.held_out`): every
    ``HOLDOUT_EVERY``-th block of :func:`reading_blocks` (at least ``HOLDOUT_BLOCK_FRAMES``) is held out."""
    held = held_out(data.x_mm)
    return data.subset(np.flatnonzero(~held)), data.subset(np.flatnonzero(held))


@dataclass
class Fit:
    """A model's prediction on some frames, with the per-frame common mode solved when it has one."""

    model: FourierModel
    data: CalibrationData
    predicted: np.ndarray  # (K, R, n), broadcast to the data's rows
    smooth: np.ndarray  # (K, Rm, n) the smooth part S
    slope: np.ndarray  # (K, Rm, n) ∂F/∂x
    usable: np.ndarray  # (K, R, n) 0/1

    @property
    def residual(self) -> np.ndarray:
        return (self.data.frames - self.predicted) * self.usable

    @property
    def rmse_gray(self) -> float:
        return float(np.sqrt((self.residual**2).sum() / max(self.usable.sum(), 1.0)))


def fit_on(model: FourierModel, data: CalibrationData) -> Fit:
    values, slope = model.predict(data.x_mm, with_derivative=True)
    smooth = model.predict(data.x_mm, with_response=False)
    usable = (data.weights > 0) * model.seen()
    if model.clip_gray is not None:
        usable *= (data.frames > model.clip_gray[0]) & (data.frames < model.clip_gray[1])
    values = np.broadcast_to(values, data.frames.shape)
    if model.common_mode:
        gain, offset = weighted_affine(data.frames, values, usable, axis=(1, 2))
        values = gain[:, None, None] * values + offset[:, None, None]

    if model.info.get(FOCUS_INFO):  # calibrated with a focus per frame: each held-out frame has its own
        values = with_frame_focus(model, data.x_mm, data.frames, np.asarray(values), usable)
    return Fit(model, data, np.asarray(values), smooth, slope, usable)


@dataclass
class Figures:
    """Held-out figures of one model: the numbers report.json carries."""

    model: str
    rmse_gray: float
    error_std_um: float
    error_max_um: float
    error_mean_um: float
    crlb_um: float
    error_um: np.ndarray
    x_mm: np.ndarray
    tracked: TrackResult
    bound_mm: np.ndarray | None = None  # per frame (the noise curve's when signal-dependent); None: the tracker's

    def as_dict(self) -> dict[str, float | str | int | None]:
        """JSON-safe figures; a figure that does not exist (frames the tracker lost) is null."""
        def number(value: float, digits: int) -> float | None:
            return round(float(value), digits) if np.isfinite(value) else None

        return {"model": self.model, "rmse_gray": number(self.rmse_gray, 5),
                "error_std_um": number(self.error_std_um, 4), "error_max_um": number(self.error_max_um, 4),
                "error_mean_um": number(self.error_mean_um, 4), "crlb_um": number(self.crlb_um, 4),
                "lost_frames": int((~np.isfinite(self.error_um)).sum())}


def track_runs(model: FourierModel, data: CalibrationData, robust: bool = False) -> TrackResult:
    """Track each run of consecutive frames from its own first reference.

    Held-out blocks are separated by the frames the fit used; a rig tracks continuously, and
    tracking across those gaps would test re-acquisition, not the model. Frames with transients
    (glints) are always tracked robustly: a glint says nothing about the model, and a plain solve
    would lose those frames and blame it. Data without frame times is one run.
    """
    robust = robust or (data.transients is not None and bool(data.transients.any()))
    tracker = Tracker(model, robust=robust)  # model-level work (folded weights, Gram polynomials) once for all runs
    times = data.t_s if data.t_s is not None else np.arange(len(data.x_mm), dtype=np.float64)
    parts = [track(model, data.frames[run], reference=data.x_mm[run], tracker=tracker) for run in runs(times)]

    def joined(key: str) -> np.ndarray:
        return np.concatenate([getattr(part, key) for part in parts])

    return TrackResult(x_mm=joined("x_mm"), locked=joined("locked"), rms_gray=joined("rms_gray"),
                       crlb_mm=joined("crlb_mm"), iterations=joined("iterations"), gain=joined("gain"),
                       offset_gray=joined("offset_gray"), events=[event for part in parts for event in part.events])


def _spread(tracked: TrackResult, data: CalibrationData) -> tuple[int, float]:
    """(frames lost, error std in µm) of a held-out tracking: what makes one tracking worse than another."""
    error = tracked.error_um(data.x_mm)
    finite = np.isfinite(error)
    return int((~finite).sum()), float(np.std(error[finite])) if finite.any() else float("inf")


def figures(model: FourierModel, data: CalibrationData, fit: Fit | None = None) -> Figures:
    """Residual and tracking error of ``model`` on held-out ``data`` (tracked frame by frame).

    The frames are tracked plainly and robustly (as the instrument tracks them: a frame whose χ²
    is beyond the noise has its worst samples set aside), and the worse of the two is the model's
    figure. A model that holds a defect only in part (a map the rows share, of a spot only some
    rows see) leaves samples the robust solve sets aside, and what it keeps then pulls the
    position: the plain solve's figure alone hides that (0.58 µm held out, 1.47 µm on the
    instrument, for such a map of a 16-row lab strip).
    """
    fit = fit or fit_on(model, data)
    tracked = max((track_runs(model, data, robust) for robust in (False, True)),
                  key=lambda result: _spread(result, data))
    error = tracked.error_um(data.x_mm)
    finite = np.isfinite(error)
    lost, spread = _spread(tracked, data)
    worst = float(np.max(np.abs(error[finite]))) if finite.any() else float("inf")
    if lost:  # a frame the tracker could not place counts as the worst error there is
        worst = float("inf")
    bound_mm = tracked.crlb_mm
    if model.pixel_noise is not None and model.pixel_noise.signal_dependent:
        bound_mm = np.where(np.isfinite(bound_mm), curve_bound_mm(model, data, fit), np.nan)
    mean = float(np.mean(error[finite])) if finite.any() else float("nan")  # no frame placed: no mean (not 0)
    return Figures(model.describe(), fit.rmse_gray, spread, worst, mean, pooled_bound(bound_mm) * 1e3, error,
                   data.x_mm, tracked, bound_mm)


def curve_bound_mm(model: FourierModel, data: CalibrationData, fit: Fit) -> np.ndarray:
    """Cramér–Rao bound per frame with the photon-transfer curve: each sample's σ²(y) at its
    expected value (a row average of R raw rows has 1/R of it), masked pixels carrying nothing
    (their slope is 0), the per-frame gain and offset profiled out when the model solves them."""
    noise = model.pixel_noise
    if noise is None:
        raise ValueError("a model without a photon-transfer curve has the tracker's white-noise bound")
    predicted = np.asarray(fit.predicted)[:, :model.n_rows]  # a shared model's rows are all alike
    variance = noise.variance(predicted) / model.rows_averaged(data.frames.shape[1])
    nuisance = np.stack([predicted, np.ones_like(predicted)], axis=-1) if model.common_mode else None
    return crlb_mm(fit.slope, 1.0, nuisance, variance)


@dataclass
class LoopModel:
    """One model of the loop, fitted on the training frames and measured on the held-out ones:
    what every effect's probe looks at."""

    spec: "ModelSpec"
    model: FourierModel
    train: Fit
    val: Fit
    figures: Figures


MIN_BLOCKS_PER_FOLD = 4


@dataclass
class HeldOut:
    """Held-out position error of a calibration, next to the bound of the same frames: the figure
    a user judges a calibration by, and the one result every caller reports as ``held_out``. Per
    frame too (``x_mm``, ``error_um``, ``bound_um``) for plots."""

    error_std_um: float
    bound_um: float
    method: str
    x_mm: np.ndarray
    error_um: np.ndarray
    bound_um_per_frame: np.ndarray

    @property
    def frames(self) -> int:
        return int(np.isfinite(self.error_um).sum())

    def as_dict(self) -> dict[str, float | int | str | None]:
        """JSON-safe: a figure that does not exist (no frame placed) is null."""
        def number(value: float) -> float | None:
            return round(float(value), 4) if np.isfinite(value) else None

        return {"error_std_um": number(self.error_std_um), "bound_um": number(self.bound_um),
                "frames": self.frames, "method": self.method}

    @classmethod
    def of(cls, parts: list[Figures], method: str) -> "HeldOut":
        """One figure from held-out parts: their frames pooled."""
        error = np.concatenate([part.error_um for part in parts])
        bound = np.concatenate([(part.tracked.crlb_mm if part.bound_mm is None else part.bound_mm) * 1e3
                                for part in parts])
        placed = np.isfinite(error)
        spread = float(np.std(error[placed])) if placed.sum() > 1 else float("nan")
        pooled = pooled_bound(bound[placed]) if placed.any() else float("nan")
        return cls(spread, pooled, method, np.concatenate([part.x_mm for part in parts]), error, bound)


def held_out_blocks(recording: Recording) -> np.ndarray:
    """Each frame's held-out block, read off the recording so that every caller holds out the same frames.

    :func:`reading_blocks` of at least ``1/HELD_OUT_BLOCKS`` of the recording and its longest rest
    (a scan's frames at rest at its ends), so that the blocks are alike in length.
    """
    _, lengths = reading_runs(recording.reference)
    least = max(recording.n_frames // HELD_OUT_BLOCKS, int(lengths.max()), 1)
    return reading_blocks(recording.reference, least)


def check_same_roi(calibration: Recording, validation: Recording) -> None:
    """A validation recording must come from the camera ROI the model describes."""
    if (validation.n_rows, validation.n_pixels) != (calibration.n_rows, calibration.n_pixels):
        raise CalibrationError(
            f"the validation recording has {validation.n_rows} row(s) × {validation.n_pixels} px, the calibration "
            f"{calibration.n_rows} × {calibration.n_pixels}: both must come from the same camera ROI")


def validate(recording: Recording, fit: Callable[[Recording], FourierModel], *,
             validation: Recording | None = None, fitted: FourierModel | None = None,
             label: str = "") -> "HeldOut | None":
    """The held-out figures of the model ``fit`` makes of a recording: on ``validation`` (the model
    fitted on all of ``recording``: ``fitted`` when the caller has it already) when given, else
    two-fold by :func:`held_out_blocks`. None when the recording has too few blocks to split.
    ``label`` (the model's kind) ends the method's text."""
    suffix = f", {label}" if label else ""
    if validation is not None:
        check_same_roi(recording, validation)
        part = figures(fitted or fit(recording), calibration_data(validation))
        return HeldOut.of([part], f"validation recording ({validation.n_frames} frames){suffix}")
    blocks = held_out_blocks(recording)
    parts = two_fold_by_block(recording, blocks, fit)
    method = f"two-fold by block ({int(blocks.max()) + 1} blocks, no stop cut){suffix}"
    return HeldOut.of(parts, method) if parts else None


def loop_split(calibration: Recording, validation: Recording | None) -> tuple[CalibrationData, CalibrationData,
                                                                              CalibrationData, str]:
    """The closed loop's frames: (all calibration data, training part, held-out part, how the
    held-out part was chosen). One fold of :func:`interleaved_split` (why one: this module's
    docstring), or the whole validation recording."""
    data = calibration_data(calibration)
    if validation is None:
        train, val = interleaved_split(data)
        return data, train, val, f"{len(val.x_mm)} of {len(data.x_mm)} frames, interleaved blocks the fit did not see"
    check_same_roi(calibration, validation)
    val = calibration_data(validation)
    return data, data, val, f"validation recording ({len(val.x_mm)} frames)"


def two_fold_by_block(recording: Recording, block: np.ndarray,
                      fit: Callable[[Recording], FourierModel]) -> list[Figures]:
    """Fit on the even blocks (``block``: each frame's, :func:`held_out_blocks`) and measure on the
    odd ones, then the other way round: every frame is held out once. [] when the recording has too
    few blocks to split."""
    if int(block.max()) + 1 < 2 * MIN_BLOCKS_PER_FOLD:
        return []
    parts = []
    for fold in (0, 1):
        model = fit(recording.subset(block % 2 != fold))
        parts.append(figures(model, calibration_data(recording.subset(block % 2 == fold))))
    return parts
