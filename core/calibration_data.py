"""Calibration data: the frames with a reference, checked, with their noise and usable samples.

Everything that fits a model starts here, so the refusals live here too: no reference, too few
frames, flat frames (nothing to see) get a message that says which.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from graytrack.core import repeats
from graytrack.core.errors import CalibrationError
from graytrack.core.models.fourier import FourierModel
from graytrack.core.noise import estimate_pixel_noise, estimate_sigma
from graytrack.core.pixel_noise import PixelNoise
from graytrack.core.recording import SENSOR_RANGE, Recording
from graytrack.core.transients import find_transients

MIN_FRAMES = 20


@dataclass
class CalibrationData:
    """What a fit needs from a recording: positions, frames in the model's row layout, weights."""

    x_mm: np.ndarray  # (K,) reference positions
    frames: np.ndarray  # (K, R, n) raw strip, float64
    weights: np.ndarray  # (K, R, n) 1 for usable samples, 0 for saturated or clipped ones
    sigma_gray: float  # model-free per-pixel noise
    meta: dict[str, Any]
    t_s: np.ndarray | None = None  # (K,) frame times, for velocity-dependent effects
    pixel_noise: PixelNoise | None = None  # photon-transfer curve of one raw sample (None: σ for all)
    transients: np.ndarray | None = None  # (K, R, n) bool: samples set aside as transients (also weight 0)

    def subset(self, index: np.ndarray) -> "CalibrationData":
        t_s = None if self.t_s is None else self.t_s[index]
        transients = None if self.transients is None else self.transients[index]
        return replace(self, x_mm=self.x_mm[index], frames=self.frames[index], weights=self.weights[index], t_s=t_s,
                       transients=transients)

    def with_reference(self, x_mm: np.ndarray) -> "CalibrationData":
        return replace(self, x_mm=x_mm)

    def with_weights(self, weights: np.ndarray) -> "CalibrationData":
        return replace(self, weights=weights)

    def with_frames(self, frames: np.ndarray) -> "CalibrationData":
        return replace(self, frames=frames)

    @property
    def stroke_mm(self) -> float:
        return float(self.x_mm.max() - self.x_mm.min())


@dataclass
class CalibrationFit:
    """A model fitted to a calibration recording, with its residual and noise (the daemon's and the API's
    ``Calibration`` is the job that made one)."""

    model: FourierModel
    rmse_gray: float
    sigma_gray: float
    iterations: int
    history: list[dict[str, float]] = field(default_factory=list)
    geometry: Any = None  # core.geometry_check.GeometryCheck of the fit (None: not checked)


def calibration_data(rec: Recording) -> CalibrationData:
    """Frames with a finite reference, checked for what would make any fit meaningless."""
    valid = np.isfinite(rec.reference)
    if not valid.any():
        raise CalibrationError("the recording has no reference positions: calibration needs the grating readout")
    if valid.sum() < MIN_FRAMES:
        raise CalibrationError(f"only {int(valid.sum())} frames have a reference; calibration needs at least "
                               f"{MIN_FRAMES}")
    frames = rec.strip()[valid]
    spread = np.percentile(frames, 99) - np.percentile(frames, 1)
    if spread < 2.0 or frames.std(axis=-1).mean() < 0.5:
        raise CalibrationError(f"the frames are flat (gray spread {spread:.2f}): no target is visible")
    x_mm, t_s, meta = rec.reference[valid], rec.t[valid], dict(rec.meta)
    period = rec.meta.get("period_mm")
    sigma = estimate_sigma(frames, x_mm, period)
    # An image the driver delivered twice pairs an old position with a new reading: left out, counted.
    repeated = repeats.repeated(frames, sigma)
    if repeated.any():
        frames, x_mm, t_s = frames[~repeated], x_mm[~repeated], t_s[~repeated]
        meta["repeated_frames"] = int(repeated.sum())
    weights = usable_samples(frames, rec.meta)
    # Transients (glints, passing dust) lose the samples they cover in the frames they last, not
    # their pixels; the noise is measured without them (core/transients.py).
    numbers = np.flatnonzero(valid) if not repeated.any() else np.flatnonzero(valid)[~repeated]
    found = find_transients(frames, x_mm, sigma, period, rec.meta.get("pixel_pitch_mm"), numbers)
    exclude = None
    if found.events:
        exclude = found.mask
        weights[exclude] = 0.0
        sigma = estimate_sigma(frames, x_mm, period, exclude)
        meta["transients"] = found.summary()
    noise = estimate_pixel_noise(frames, x_mm, period, rec.meta.get("bit_depth"), exclude=exclude)
    return CalibrationData(x_mm, frames, weights, sigma, meta, t_s, noise if noise.signal_dependent else None, exclude)


def sensor_range(meta: dict[str, Any]) -> tuple[float, float] | None:
    """The readout's floor and ceiling when the recording states them (``sensor_range_gray``: a camera that clips
    its float output), else (0, 2^bits − 1) when it states its bit depth."""
    stated = meta.get(SENSOR_RANGE)
    if isinstance(stated, (list, tuple)) and len(stated) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in stated) \
            and stated[0] < stated[1]:
        return float(stated[0]), float(stated[1])
    bit_depth = meta.get("bit_depth")
    if isinstance(bit_depth, int) and not isinstance(bit_depth, bool) and 1 <= bit_depth <= 32:
        return 0.0, float(2**bit_depth - 1)
    return None


def readout_mismatch(model_info: dict[str, Any], meta: dict[str, Any]) -> str | None:
    """Why a model cannot read frames whose recording (or camera) states ``meta``: calibrated on one readout range
    (``model_info['sensor_range_gray']``, its calibration's camera) and read out on another (a camera set to 12 or 16
    bits since, whose gray values are 16 or 256 times the model's: either engine would take them for a light changed
    past anything a lamp does, and flag every frame). None where either does not say, or both agree."""
    calibrated, now = model_info.get("sensor_range_gray"), sensor_range(meta)
    if calibrated is None or now is None:
        return None
    try:
        lo, hi = float(calibrated[0]), float(calibrated[1])
    except (TypeError, ValueError, IndexError):
        return None
    if math.isclose(lo, now[0], abs_tol=1e-9) and math.isclose(hi, now[1], rel_tol=1e-9):
        return None
    return (f"the model was calibrated on a camera reading out {lo:g}-{hi:g} gray and these frames read out "
            f"{now[0]:g}-{now[1]:g}: their gray values are not the model's")


def usable_samples(frames: np.ndarray, meta: dict[str, Any]) -> np.ndarray:
    """0 where a pixel sits at the sensor's floor or ceiling (clipped: carries no position)."""
    weights = np.ones(frames.shape)
    limits = sensor_range(meta)
    if limits is not None:
        weights[(frames >= limits[1]) | (frames <= limits[0])] = 0.0
    return weights


# --------------------------------------------------------------------------- initial geometry
