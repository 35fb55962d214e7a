"""A calibration's quality in the unit a user cares about: held-out position error in µm, next to
the Cramér–Rao bound of the same frames.

The installed model is fitted on every stop; its quality is measured on frames it did not see,
by a two-fold split *by stop* (fit on the even stops, track the odd ones, and the other way round):
stops are the independent units of a sweep, and the frames of one stop share its reference, so
holding out frames within a stop would flatter the model.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.core.tracking import track

MIN_STOPS_PER_FOLD = 4


def held_out_quality(recording: Recording, frames_per_stop: int) -> dict[str, Any] | None:
    """``{"error_std_um", "bound_um", "frames", "method"}``, or None when the sweep is too short to split."""
    stops = np.arange(recording.n_frames) // frames_per_stop
    n_stops = int(stops.max()) + 1
    if n_stops < 2 * MIN_STOPS_PER_FOLD:
        return None
    errors, bounds = [], []
    for fold in (0, 1):
        train, test = stops % 2 != fold, stops % 2 == fold
        model = calibrate(_subset(recording, train), "paper").model
        held = _subset(recording, test)
        result = track(model, held.frames, x0_mm=float(held.reference[0]))
        errors.append(result.error_um(held.reference))
        bounds.append(result.crlb_mm * 1e3)
    error, bound = np.concatenate(errors), np.concatenate(bounds)
    placed = np.isfinite(error)
    if placed.sum() < 2:
        return None
    return {"error_std_um": float(np.std(error[placed])), "bound_um": float(np.median(bound[placed])),
            "frames": int(placed.sum()), "method": "two-fold by stop, paper model"}


def _subset(recording: Recording, keep: np.ndarray) -> Recording:
    return Recording(recording.frames[keep], recording.t[keep], recording.reference[keep], dict(recording.meta))
