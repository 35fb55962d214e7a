"""Calibration: fit a gray-level model to a sweep against the grating reference.

The entry point for the named kinds (``ideal``, the 5-parameter sine; ``paper``, Fourier order 5 ×
cubic in the pixel index) and for multi-row strips, whose rows are averaged when they agree and
modelled one by one when they do not. The work is done by calibration_data.py (checks, noise),
geometry.py (τ_w, α·d by variable projection) and structure.py (a model's effects).
"""

from __future__ import annotations

from typing import Callable, Literal

import numpy as np

from graytrack.core import effects
from graytrack.core.adequacy import assessed
from graytrack.core.calibration_data import CalibrationFit, CalibrationData, calibration_data
from graytrack.core.errors import CalibrationError
from graytrack.core.estimator.mount import SHOWN_ACCELERATION, SHOWN_BEYOND, shown_acceleration
from graytrack.core.estimator.settings import TUNABLES
from graytrack.core.geometry import initial_geometry
from graytrack.core.geometry_check import MIN_SEEN_SHARE, GeometryError, check_geometry, dark_pixels
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import Recording, acceleration_phases
from graytrack.core.calibration_line import record_calibration_line
from graytrack.core.structure import ModelSpec, fit_spec
from graytrack.core.effects.bad_pixels import EFFECT as BAD_PIXELS

Progress = Callable[[float, str], None]
RowMode = Literal["auto", "mean", "each"]
# Rows are modelled separately when the shared model leaves this much more variance than noise.
ROW_DISAGREEMENT_EXCESS = 0.10

__all__ = ["CalibrationFit", "CalibrationData", "KIND_SPECS", "calibrate", "calibration_data", "rows_disagree"]


def rows_disagree(model: FourierModel, data: CalibrationData) -> bool:
    """True when the rows differ from each other by clearly more than noise.

    Only the spread of the residual across rows counts: whatever the shared model misses in all
    rows alike (a too-simple model) cancels there, so this asks about the rows, not the model.
    """
    n_rows = data.frames.shape[1]
    weights = data.weights * model.seen()
    predicted = model.predict(data.x_mm)
    residual = (data.frames - predicted) * weights
    spread = (residual - residual.mean(axis=1, keepdims=True)) * weights
    noise = data.pixel_noise if data.pixel_noise is not None else model.noise()
    variance = float((noise.variance(np.broadcast_to(predicted, weights.shape)) * weights).sum() / weights.sum())
    expected = variance * (1.0 - 1.0 / n_rows)
    excess = float((spread**2).sum() / weights.sum()) / expected - 1.0
    return excess > ROW_DISAGREEMENT_EXCESS


def _two_level_pixels(model: FourierModel, rec: Recording, rows: int) -> list[tuple[int, int, str]]:
    """The (row, pixel, reason) of each pixel that reads at one of two levels on the sweep ``rec`` against the
    ``model`` just fitted (none without a grating); a model that averages ``rows`` rows names its pixel in every
    row (its sample is their mean: which row flips it cannot tell)."""
    from graytrack.core.estimator.two_level import calibration_two_level

    if rec.reference is None or not np.isfinite(rec.reference).any():
        return []
    found = calibration_two_level(model, rec)
    if found is None:
        return []
    named = found.bad_pixels(model.n_pixels)
    if model.n_rows == 1 and rows > 1:
        named = [(row, pixel, reason) for _, pixel, reason in named for row in range(rows)]
    return named


KIND_SPECS = {
    "ideal": ModelSpec(harmonics=1, pixel_degree=0, name="ideal"),
    "paper": ModelSpec(harmonics=5, pixel_degree=3, name="paper"),
}


def calibrate(rec: Recording, model: str = "paper", *, harmonics: int | None = None, pixel_degree: int | None = None,
              rows: RowMode = "auto", progress: Progress | None = None, check: bool = True) -> CalibrationFit:
    """Calibrate the ``ideal`` or ``paper`` model on a recording with a reference.

    The fit's geometry is then checked (core/geometry_check.py): a fault of the rig's set-up (a
    reversed pixel axis, a wrong period) raises :class:`GeometryError` naming the cause and the
    fix; a doubt is kept as warnings in ``result.geometry`` and the model's info. ``check=False``
    keeps a refused model (to study it), marked refused in its info all the same.
    """
    if model not in KIND_SPECS:
        raise CalibrationError(f"unknown model kind {model!r} (expected one of {', '.join(KIND_SPECS)})")
    spec = KIND_SPECS[model]
    if harmonics is not None:
        spec = spec.with_changes(harmonics=harmonics)
    if pixel_degree is not None:
        spec = spec.with_changes(pixel_degree=pixel_degree)
    raw = calibration_data(rec)
    # Data quality first, whatever the kind: a stuck pixel left in a cubic pixel fit biases the
    # whole model (core/effects: bad pixels are masked and listed in the model's info).
    spec = effects.screened(spec, raw)

    def fitted(spec: ModelSpec) -> tuple[CalibrationFit, CalibrationData]:
        data = effects.prepare_data(spec, raw)
        period, pitch, row_shift = initial_geometry(data)
        result = fit_spec(spec, data, period, pitch, progress=progress)
        n_rows = data.frames.shape[1]
        # Whole rows set aside (off the print) blind the row mean at every column: only rows of their own see.
        blind = float(np.mean(result.model.seen())) < MIN_SEEN_SHARE
        # A ROI that sees the print on fewer pixels than any model may use is refused whatever models its
        # rows: the geometry check says so below, without a row-by-row fit that cannot help.
        hopeless = n_rows > 1 and 1.0 - float(dark_pixels(data, result.model.period_mm).mean()) < MIN_SEEN_SHARE
        if n_rows > 1 and not hopeless and (rows == "each" or (rows == "auto" and (
                blind or rows_disagree(result.model, data)))):
            geometry = result.model
            result = fit_spec(spec.with_changes(per_row=True), data, geometry.period_mm, geometry.pixel_pitch_mm,
                              row_shift, progress)
        return result, data

    result, data = fitted(spec)
    # Pixels that read at one of two levels at random (a charge trap) show only against a model, on the sweep with
    # the grating pinning it: set aside as bad pixels too, and the model fitted again without them
    # (core/estimator/two_level.py)
    flipping = _two_level_pixels(result.model, rec, data.frames.shape[1])
    if flipping:
        spec = BAD_PIXELS.grow(spec, tuple(flipping)) or spec
        result, data = fitted(spec)
    assessed(result.model, data)
    result.geometry = check_geometry(data, result.model, result.rmse_gray)
    result.model.info["geometry"] = result.geometry.as_dict()
    if check and result.geometry.refused:
        raise GeometryError(result.geometry)
    record_calibration_line(result.model, rec)  # camera against grating on its own run: drift is measured from it
    # what the stage's own motion showed on the grating (core/estimator/mount.py): no step of the mount is smaller
    result.model.info[SHOWN_ACCELERATION] = shown_acceleration(rec.t, rec.reference)
    phases = acceleration_phases(rec.meta)
    if phases is not None:
        result.model.info[SHOWN_BEYOND] = shown_acceleration(rec.t, rec.reference, phases,
                                                             TUNABLES["stage_settle"].default)
    # the print's own marks and the model's own error as the estimator meets them on this very sweep (what tracking
    # then starts from, and what its bound states)
    from graytrack.core.estimator.filter import kept_from_calibration

    kept_from_calibration(result.model, rec)
    if progress:
        progress(1.0, f"done, rms {result.rmse_gray:.3f} gray")
    return result
