"""How far a compressed stream scatters a frame's focus estimate beyond its white-noise error.

JPEG quantises each 8×8 block's DCT coefficients, the high frequencies coarsely: a low-pass that
differs from frame to frame with the image's place on the blocks and its noise. The blur direction
½∂²F/∂x² is the image's high frequencies, so that error lands on it far more than white noise
does: on the `lab` strip at quality 75 the closed loop's model read a steady run's focus at
−0.11 ± 2.1 px² a frame where each estimate's error said ±0.02 (100 of them), and on a 16-row strip
±3.2 px² against ±0.55. Judged against their white error, every frame's focus term gained far more
χ² than chance, and the focus was taken on 472–577 frames of runs where nothing changed (2–24 %
flagged).

The calibration knows the stream (core/compression.py) and replays its model's images through it
(core/replay.py): each replayed frame's focus
estimated as the tracker estimates it (the frame's gain, blur and offset with x, by least squares
at the place it was rendered), against its white-noise error, gives the rms pull — the factor by
which the stream widens a focus estimate's standard error (``info["stream"]["focus_factor"]``).
The tracker (core/tracking.py) carries it in every estimate's error and judges the χ² the focus term
gains against what it gains on this stream by chance: a steady compressed run takes no focus term,
and a blur that moves the estimates by more than the stream does is still found.
"""

from __future__ import annotations

import numpy as np

from graytrack.core.calibration_data import CalibrationData
from graytrack.core.focus_solve import FOCUS_STEP_PERIODS
from graytrack.core.models.fourier import FourierModel
from graytrack.core.replay import frame_weights, picked_frames, replayed_frames


def focus_pulls(model: FourierModel, data: CalibrationData) -> np.ndarray:
    """Each frame's focus estimate over its white-noise standard error, at the frames' own places
    ``data.x_mm`` (the truth: a replay knows it). The frame model is y ≈ g·F + h·B + o + F′·dx with
    B = ½F″ (core/focus_solve.py), by weighted least squares; the estimate is δ = h/g and its error
    the Fisher matrix's, as the tracker's focus solve reports it (``focus_sigma``)."""
    x = data.x_mm
    values, slopes = model.predict(x, with_derivative=True)
    step = FOCUS_STEP_PERIODS * model.period_mm
    _, ahead = model.predict(x + step, with_derivative=True)
    _, behind = model.predict(x - step, with_derivative=True)
    shape = (x.size, -1)
    frames = model.prepare(data.frames).reshape(shape)
    values, slopes = values.reshape(shape), slopes.reshape(shape)
    blur = (0.25 / step) * (ahead - behind).reshape(shape)  # ½F″ by central differences of the slopes
    weights = frame_weights(model, data, values)
    basis = np.stack([slopes, values, blur, np.ones_like(values)], axis=2)  # (K, P, 4): x, gain, blur, offset
    fisher = np.einsum("kp,kpi,kpj->kij", weights, basis, basis)
    usable = np.linalg.det(fisher) > 0
    if not usable.any():
        return np.empty(0)
    fisher, basis, weights, frames = fisher[usable], basis[usable], weights[usable], frames[usable]
    score = np.einsum("kp,kpi,kp->ki", weights, basis, frames)
    solved = np.linalg.solve(fisher, score[..., None])[..., 0]
    blur_sigma = np.sqrt(np.linalg.inv(fisher)[:, 2, 2])
    return solved[:, 2] / blur_sigma  # δ/σ: the gain divides both


def stream_focus_factor(model: FourierModel, data: CalibrationData, table: np.ndarray, seed: int = 0) -> float:
    """The rms over the replayed stream's frames (the calibration's places, the model's images with
    the sensor's noise through 8 bits and ``table``) of :func:`focus_pulls`: how many of its white
    errors a focus estimate scatters on this stream when the focus has not moved. At least 1."""
    replays = [focus_pulls(model, streamed) for streamed in replayed_frames(model, picked_frames(data), table, seed)]
    pulls = np.concatenate(replays) if replays else np.empty(0)
    pulls = pulls[np.isfinite(pulls)]
    return max(1.0, float(np.sqrt(np.mean(pulls**2)))) if pulls.size else 1.0


def focus_factor(info: dict) -> float:
    """The factor a model's calibration found for its stream's focus estimates (1: raw frames)."""
    return float((info.get("stream") or {}).get("focus_factor") or 1.0)
