"""Calibration: fit a gray-level model to a sweep against the grating reference.

Variable projection: for given geometry (τ_w, α·d and, for tilted strips, the row shift) the model
is linear in its coefficients and those are solved exactly by least squares; Levenberg–Marquardt
runs only over the 2–3 geometry parameters, with Kaufman's Jacobian of the projected residual.
That is the structure the seed paper's 45-unknown LM ignores, and it is what makes a 1,000-frame
calibration take a fraction of a second.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Literal

import numpy as np
from scipy.optimize import minimize_scalar

from graytrack.core.errors import CalibrationError
from graytrack.core.linear_fit import LinearSystem, fit_coefficients, geometry_sensitivities, project_columns
from graytrack.core.models.fourier import TWO_PI, FourierModel, ideal_model, paper_model
from graytrack.core.noise import estimate_sigma
from graytrack.core.recording import Recording

Progress = Callable[[float, str], None]
RowMode = Literal["auto", "mean", "each"]
MIN_FRAMES = 20
# Rows are modelled separately when the shared model leaves this much more variance than noise.
ROW_DISAGREEMENT_EXCESS = 0.10


@dataclass
class CalibrationData:
    """What a fit needs from a recording: positions, frames in the model's row layout, weights."""

    x_mm: np.ndarray  # (K,)
    frames: np.ndarray  # (K, R, n) raw strip, float64
    weights: np.ndarray  # (K, R, n) 1 for usable samples, 0 for saturated or clipped ones
    sigma_gray: float  # model-free per-pixel noise
    meta: dict[str, Any]

    @property
    def stroke_mm(self) -> float:
        return float(self.x_mm.max() - self.x_mm.min())


@dataclass
class Calibration:
    model: FourierModel
    rmse_gray: float
    sigma_gray: float
    iterations: int
    history: list[dict[str, float]] = field(default_factory=list)


def calibration_data(rec: Recording) -> CalibrationData:
    """Frames with a finite reference, checked for what would make any fit meaningless."""
    valid = np.isfinite(rec.reference)
    if not valid.any():
        raise CalibrationError("the recording has no reference positions: calibration needs the grating readout")
    if valid.sum() < MIN_FRAMES:
        raise CalibrationError(f"only {int(valid.sum())} frames have a reference; calibration needs at least {MIN_FRAMES}")
    frames = rec.strip()[valid]
    spread = np.percentile(frames, 99) - np.percentile(frames, 1)
    if spread < 2.0 or frames.std(axis=-1).mean() < 0.5:
        raise CalibrationError(f"the frames are flat (gray spread {spread:.2f}): no target is visible")
    weights = usable_samples(frames, rec.meta)
    x_mm = rec.reference[valid]
    period = rec.meta.get("period_mm")
    sigma = estimate_sigma(frames, x_mm, period)
    return CalibrationData(x_mm, frames, weights, sigma, dict(rec.meta))


def usable_samples(frames: np.ndarray, meta: dict[str, Any]) -> np.ndarray:
    """0 where a pixel sits at the sensor's floor or ceiling (clipped: carries no position)."""
    bit_depth = meta.get("bit_depth")
    weights = np.ones(frames.shape)
    if isinstance(bit_depth, int) and 1 <= bit_depth <= 32:
        weights[(frames >= 2**bit_depth - 1) | (frames <= 0)] = 0.0
    return weights


# --------------------------------------------------------------------------- initial geometry
def estimate_period(x_mm: np.ndarray, line: np.ndarray, stroke_mm: float) -> float:
    """Period along the stroke: the frequency whose sine best explains every pixel's trace.

    ``line`` is ``(K, n)``. A sine + offset per pixel is solved for all pixels at once at each trial
    frequency; the residual sum is scanned on a grid fine enough that no peak falls between points,
    then refined.
    """
    centred = line - line.mean(axis=0)
    total = float((centred**2).sum())

    def residual(freq: float) -> float:
        design = np.stack([np.sin(TWO_PI * freq * x_mm), np.cos(TWO_PI * freq * x_mm), np.ones_like(x_mm)], axis=1)
        q, _ = np.linalg.qr(design)
        return total - float(((q.T @ centred) ** 2).sum())

    steps = np.abs(np.diff(np.sort(x_mm)))
    typical_step = float(np.median(steps[steps > 0])) if (steps > 0).any() else stroke_mm / len(x_mm)
    f_lo, f_hi = 1.0 / stroke_mm, min(1.0 / (4 * typical_step), 40.0 / stroke_mm)
    grid = np.arange(f_lo, f_hi, 0.05 / stroke_mm)
    if grid.size < 3:
        raise CalibrationError("the sweep is too coarse to find the target period; give meta period_mm")
    costs = np.array([residual(f) for f in grid])
    best = int(np.argmin(costs))
    if best == 0:
        raise CalibrationError(
            f"the stroke ({stroke_mm:.3f} mm) seems shorter than one target period; "
            "calibration needs at least one full period (or give meta period_mm)"
        )
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    refined = minimize_scalar(residual, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6 / stroke_mm})
    return 1.0 / float(refined.x)


def fundamental_phase(x_mm: np.ndarray, line: np.ndarray, period_mm: float) -> np.ndarray:
    """Phase of the fundamental seen by each column of ``line`` ``(K, m)`` along the stroke."""
    design = np.stack([np.sin(TWO_PI * x_mm / period_mm), np.cos(TWO_PI * x_mm / period_mm), np.ones_like(x_mm)], axis=1)
    coef, *_ = np.linalg.lstsq(design, line, rcond=None)
    return np.unwrap(np.arctan2(coef[1], coef[0]))


def phase_rate_mm(phases: np.ndarray, period_mm: float) -> float:
    """Target shift per index step from a straight-line fit of unwrapped phases."""
    index = np.arange(phases.size, dtype=np.float64)
    slope = np.polyfit(index, phases, 1)[0]
    return float(slope * period_mm / TWO_PI)


def initial_geometry(data: CalibrationData) -> tuple[float, float, float]:
    """(τ_w, α·d, row shift) from the recording's nominal meta when given, else from the data."""
    mean_line = data.frames.mean(axis=1)
    period = data.meta.get("period_mm")
    if period is None:
        period = estimate_period(data.x_mm, mean_line, data.stroke_mm)
    elif data.stroke_mm < period:
        raise CalibrationError(
            f"the stroke ({data.stroke_mm:.3f} mm) is shorter than one target period ({period:.3f} mm)"
        )
    pitch = data.meta.get("pixel_pitch_mm")
    if pitch is None:
        pitch = phase_rate_mm(fundamental_phase(data.x_mm, mean_line, period), period)
        if pitch == 0:
            raise CalibrationError("cannot tell the pixel footprint from the data; give meta pixel_pitch_mm")
    row_shift = 0.0
    if data.frames.shape[1] > 1:
        centre = data.frames.shape[-1] // 2
        row_phases = fundamental_phase(data.x_mm, data.frames[:, :, centre], period)
        row_shift = phase_rate_mm(row_phases, period)
    return float(period), float(pitch), row_shift


# --------------------------------------------------------------------------- variable projection
def _projected_fit(model: FourierModel, x_mm: np.ndarray, data: np.ndarray, weights: np.ndarray):
    fitted, system = fit_coefficients(model, x_mm, data, weights)
    residual = (data - fitted.predict(x_mm, with_response=False)) * np.sqrt(weights)
    return fitted, residual, system


def fit_geometry(template: FourierModel, x_mm: np.ndarray, data: np.ndarray, weights: np.ndarray,
                 names: tuple[str, ...], max_iterations: int = 40,
                 progress: Progress | None = None) -> tuple[FourierModel, int, list[dict[str, float]]]:
    """Levenberg–Marquardt over geometry ``names`` with the linear coefficients projected out.

    ``data`` is in the model's smooth-part domain (any flat field and common mode divided out).
    """
    params = np.array([getattr(template, name) for name in names], dtype=np.float64)
    model, residual, system = _projected_fit(template, x_mm, data, weights)
    cost = float((residual**2).sum())
    damping, history, iteration = 1e-3, [], 0
    sqrt_w = np.sqrt(weights)
    for iteration in range(1, max_iterations + 1):
        jacobian = _kaufman_jacobian(model, system, x_mm, weights, names) * sqrt_w[..., None]
        jac = jacobian.reshape(-1, len(names))
        normal, gradient = jac.T @ jac, jac.T @ residual.reshape(-1)
        improved = False
        while damping < 1e12:
            step = -np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-300), gradient)
            trial_params = params + step
            if trial_params[0] <= 0 or (len(names) > 1 and trial_params[1] == 0):
                damping *= 10
                continue
            trial = template.with_changes(**dict(zip(names, trial_params)))
            trial_model, trial_residual, trial_system = _projected_fit(trial, x_mm, data, weights)
            trial_cost = float((trial_residual**2).sum())
            if trial_cost <= cost:
                improved = True
                break
            damping *= 10
        if not improved:
            break
        relative_drop = (cost - trial_cost) / max(cost, 1e-300)
        params, model, residual, cost, system = trial_params, trial_model, trial_residual, trial_cost, trial_system
        damping = max(damping / 10, 1e-9)
        history.append({"iteration": iteration, "cost": cost, **dict(zip(names, params.tolist()))})
        if progress:
            progress(min(0.95, iteration / 10), f"geometry iteration {iteration}, rms {np.sqrt(cost / residual.size):.3f}")
        if relative_drop < 1e-10 or np.all(np.abs(step) <= 1e-12 * np.abs(params) + 1e-15):
            break
    return model, iteration, history


def _kaufman_jacobian(model: FourierModel, system: LinearSystem, x_mm: np.ndarray, weights: np.ndarray,
                      names: tuple[str, ...]) -> np.ndarray:
    """∂(residual)/∂(geometry) ≈ −(I − P_Φ)·∂S/∂g with P_Φ the weighted projection on the model's span."""
    sens = geometry_sensitivities(model, x_mm, names)  # (K, R, n, m)
    projected = project_columns(model, x_mm, sens, weights)  # (m, ncoef)
    columns = []
    for index in range(len(names)):
        fitted = model.with_changes(coeffs=system.solve(projected[index]))
        columns.append(sens[..., index] - fitted.predict(x_mm, with_response=False))
    return -np.stack(columns, axis=-1)


# --------------------------------------------------------------------------- public entry
def template_model(kind: str, period_mm: float, pitch_mm: float, n_pixels: int,
                   harmonics: int | None = None, pixel_degree: int | None = None) -> FourierModel:
    if kind == "ideal":
        return ideal_model(period_mm, pitch_mm, n_pixels)
    if kind == "paper":
        return paper_model(period_mm, pitch_mm, n_pixels, harmonics or 5, 3 if pixel_degree is None else pixel_degree)
    raise CalibrationError(f"unknown model kind {kind!r} (expected 'ideal' or 'paper')")


def rows_disagree(model: FourierModel, data: CalibrationData) -> bool:
    """True when the rows differ from each other by clearly more than noise.

    Only the spread of the residual across rows counts: whatever the shared model misses in all
    rows alike (a too-simple model) cancels there, so this asks about the rows, not the model.
    """
    n_rows = data.frames.shape[1]
    residual = (data.frames - model.predict(data.x_mm)) * data.weights
    spread = residual - residual.mean(axis=1, keepdims=True)
    expected = data.sigma_gray**2 * (1.0 - 1.0 / n_rows)
    excess = float((spread**2).sum() / data.weights.sum()) / expected - 1.0
    return excess > ROW_DISAGREEMENT_EXCESS


def fit_model(template: FourierModel, data: CalibrationData, progress: Progress | None = None) -> Calibration:
    """Fit a template (any structure) to calibration data; the geometry is refined as well."""
    names: tuple[str, ...] = ("period_mm", "pixel_pitch_mm") + (("row_shift_mm",) if template.n_rows > 1 else ())
    shaped = template.prepare(data.frames)
    weights = template.prepare(data.weights) if template.n_rows > 1 else data.weights.min(axis=1, keepdims=True)
    lo, hi = float(data.x_mm.min()), float(data.x_mm.max())
    template = template.with_changes(stroke_range_mm=(lo, hi))
    model, iterations, history = fit_geometry(template, data.x_mm, shaped, weights, names, progress=progress)
    residual = (data.frames - model.predict(data.x_mm)) * np.sqrt(data.weights)
    rmse = float(np.sqrt((residual**2).sum() / data.weights.sum()))
    model = model.with_changes(noise_gray=data.sigma_gray, info={**model.info, "calibration_rmse_gray": rmse})
    return Calibration(model, rmse, data.sigma_gray, iterations, history)


def calibrate(rec: Recording, model: str = "paper", *, harmonics: int | None = None, pixel_degree: int | None = None,
              rows: RowMode = "auto", progress: Progress | None = None) -> Calibration:
    """Calibrate the ``ideal`` or ``paper`` model on a recording with a reference."""
    data = calibration_data(rec)
    period, pitch, row_shift = initial_geometry(data)
    template = template_model(model, period, pitch, rec.n_pixels, harmonics, pixel_degree)
    result = fit_model(template, data, progress)
    n_rows = data.frames.shape[1]
    if n_rows > 1 and (rows == "each" or (rows == "auto" and rows_disagree(result.model, data))):
        per_row = result.model.with_changes(n_rows=n_rows, row_degree=min(2, n_rows - 1), row_shift_mm=row_shift)
        result = fit_model(per_row, data, progress)
    if progress:
        progress(1.0, f"done, rms {result.rmse_gray:.3f} gray")
    return result
