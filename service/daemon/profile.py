"""The line view's data: the latest frame along the pixels, the model at the tracked position, the
residual with its noise band, saturated and bad pixels (``GET /api/profile``).

It is what a person aligns the target, focuses, sets the exposure and chooses the ROI with, so it
shows the frame even without a model (idle, or a model that does not fit) and says which parts are
missing. Computed on request from the frame the loop kept (no copy per frame): a page asks a few
times a second, never the frame loop.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from graytrack.core.models.fourier import FourierModel
from graytrack.service.daemon.acquisition import Acquisition


def _rounded(values: np.ndarray) -> list[float | None]:
    return [None if not math.isfinite(v) else round(float(v), 2) for v in values]


def saturation_level(pixels: np.ndarray, model: FourierModel | None) -> float:
    """The gray value a saturated pixel reads: the model's clip, else the integer type's maximum."""
    if model is not None and model.clip_gray is not None:
        return float(model.clip_gray[1])
    if np.issubdtype(pixels.dtype, np.integer):
        return float(np.iinfo(pixels.dtype).max)
    return math.inf


def profile(acquisition: Acquisition | None, model: FourierModel | None, row: int | None) -> dict[str, Any] | None:
    """The line view of the latest frame (``row``: one sensor row, else the rows averaged); None before any frame."""
    latest = acquisition.latest if acquisition is not None else None
    if latest is None:
        return None
    sample, fix = latest
    raw = np.asarray(sample.frame.pixels)
    raw = raw[None, :] if raw.ndim == 1 else raw
    rows = raw.shape[0]
    if row is not None and not 0 <= row < rows:
        raise IndexError(f"row {row} is outside the frame's {rows} row(s)")
    line = raw[row].astype(np.float64) if row is not None else raw.mean(axis=0)
    level = saturation_level(raw, model)
    shown = raw if row is None else raw[row:row + 1]
    saturated = np.flatnonzero(shown >= level).tolist() if math.isfinite(level) else []
    document: dict[str, Any] = {
        "t": sample.t, "frame_id": sample.frame.frame_id, "rows": rows, "row": row, "pixels": _rounded(line),
        "saturation_gray": level if math.isfinite(level) else None,
        "saturated": sorted(set(int(i) % line.size for i in saturated)), "bad": [], "x_mm": None, "locked": None,
        "model": None, "residual": None, "sigma": None, "why_no_model": None,
    }
    if model is None:
        document["why_no_model"] = "no model installed: calibrate to see the model over the frame"
        return document
    if model.pixel_weight is not None:
        weights = np.asarray(model.pixel_weight).reshape(-1, model.n_pixels)
        document["bad"] = np.flatnonzero(weights.min(axis=0) == 0).tolist()
    x = fix.x_mm if fix is not None else float("nan")
    if fix is None or not math.isfinite(x):
        document["why_no_model"] = "the latest frame was not placed: no model prediction"
        return document
    if line.size != model.n_pixels:
        document["why_no_model"] = f"the frame has {line.size} pixels, the model {model.n_pixels}"
        return document
    predicted = np.asarray(model.predict(np.array([x])))[0]  # (R_model, n)
    predicted = predicted[min(row, predicted.shape[0] - 1)] if row is not None else predicted.mean(axis=0)
    gain, offset = getattr(fix, "gain", None), getattr(fix, "offset_gray", None)
    if gain is not None and offset is not None and math.isfinite(gain) and math.isfinite(offset):
        predicted = predicted * gain + offset
    averaged = rows if row is None and model.n_rows == 1 else 1
    sigma = model.noise().sigma(predicted) / math.sqrt(averaged)
    document.update(x_mm=x, locked=bool(fix.locked), model=_rounded(predicted), residual=_rounded(line - predicted),
                    sigma=_rounded(sigma))
    return document
