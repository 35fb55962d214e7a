"""A calibration's quality in the unit a user cares about: held-out position error in µm, next to
the Cramér–Rao bound of the same frames.

The installed model is fitted on every frame; its quality is measured on frames it did not see,
by a two-fold split *by block* (fit on the even blocks, track the odd ones, and the other way
round). A block is a stop of a step-and-settle sweep (its frames share one reference, so holding
out frames within a stop would flatter the model), or a stretch of a scan's pass.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.noise import pooled_bound
from graytrack.core.recording import Recording
from graytrack.core.tracking import track

MIN_STOPS_PER_FOLD = 4


def held_out_folds(recording: Recording, block_frames: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per fold, for the held-out frames: ``(reference_mm, error_um, bound_um)``; [] when too short to split."""
    stops = np.arange(recording.n_frames) // block_frames
    if int(stops.max()) + 1 < 2 * MIN_STOPS_PER_FOLD:
        return []
    folds = []
    for fold in (0, 1):
        model = calibrate(_subset(recording, stops % 2 != fold), "paper").model
        held = _subset(recording, stops % 2 == fold)
        # frames with glints (the calibration found transients) are tracked robustly, as live tracking does
        result = track(model, held.frames, x0_mm=float(held.reference[0]), robust=bool(model.info.get("transients")))
        folds.append((held.reference, result.error_um(held.reference), result.crlb_mm * 1e3))
    return folds


def held_out_quality(recording: Recording, block_frames: int) -> dict[str, Any] | None:
    """``{"error_std_um", "bound_um", "frames", "method"}``, or None when the sweep is too short to split."""
    folds = held_out_folds(recording, block_frames)
    if not folds:
        return None
    error = np.concatenate([f[1] for f in folds])
    bound = np.concatenate([f[2] for f in folds])
    placed = np.isfinite(error)
    if placed.sum() < 2:
        return None
    return {"error_std_um": float(np.std(error[placed])), "bound_um": pooled_bound(bound[placed]),
            "frames": int(placed.sum()), "method": "two-fold by block, paper model"}


def _subset(recording: Recording, keep: np.ndarray) -> Recording:
    return Recording(recording.frames[keep], recording.t[keep], recording.reference[keep], dict(recording.meta))
