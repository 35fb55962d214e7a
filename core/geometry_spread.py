"""How well one calibration pins τ_w and α·d: the spread of the same fit on interleaved parts.

A drift over months is only a drift when it exceeds what a single calibration can tell apart.
The fit itself reports no covariance for the two nonlinear parameters (the linear coefficients
are profiled out), so the uncertainty is measured the model-agnostic way: split the sweep into
``parts`` interleaved sets of frame blocks (each covers the whole stroke), calibrate each, and
scale their spread to the full data: std(estimates) / √parts. Noise, quantisation and whatever
the model misses all show up in that spread, not only the part a noise model would predict.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording

MAX_PARTS = 8  # more parts, a better estimate of the spread (7 degrees of freedom at 8)
FRAMES_PER_PART = 25  # calibration refuses fewer than 20 frames
BLOCKS_PER_PART = 32  # enough blocks that every part spans the whole stroke


@dataclass(frozen=True)
class GeometrySpread:
    period_mm: float       # standard uncertainty of τ_w from the full recording
    pixel_pitch_mm: float  # standard uncertainty of α·d
    parts: int


def interleaved_parts(n_frames: int, parts: int) -> list[np.ndarray]:
    """Frame indices of ``parts`` sets, block ``b`` going to set ``b % parts``."""
    block = max(n_frames // (parts * BLOCKS_PER_PART), 1)
    owner = (np.arange(n_frames) // block) % parts
    return [np.flatnonzero(owner == part) for part in range(parts)]


def geometry_spread(rec: Recording, kind: str = "paper", parts: int | None = None) -> GeometrySpread:
    """Uncertainty of τ_w and α·d of ``calibrate(rec, kind)``, from ``parts`` interleaved refits
    (default: as many as the frames allow, up to 8; NaN when fewer than two parts fit)."""
    parts = parts or min(MAX_PARTS, rec.n_frames // FRAMES_PER_PART)
    if parts < 2:
        return GeometrySpread(float("nan"), float("nan"), parts)
    estimates = np.array([
        (model.period_mm, model.pixel_pitch_mm)
        for model in (calibrate(rec.subset(index), kind).model for index in interleaved_parts(rec.n_frames, parts))
    ])
    spread = estimates.std(axis=0, ddof=1) / np.sqrt(parts)
    return GeometrySpread(float(spread[0]), float(spread[1]), parts)
