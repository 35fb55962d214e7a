"""The imaging geometry: target period τ_w, pixel footprint α·d and the row shift of a tilted strip.

First estimated (from the recording's nominal meta, else from the data), then refined by variable
projection: for given geometry the model is linear in its coefficients, which are solved exactly;
Levenberg–Marquardt runs only over the 2–3 geometry parameters, with Kaufman's Jacobian of the
projected residual. That is the structure the seed paper's 45-unknown LM ignores, and it is what
makes a 1,000-frame calibration take a fraction of a second.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from graytrack.core.calibration_data import CalibrationData
from graytrack.core.errors import CalibrationError
from graytrack.core.linear_fit import LinearSystem, fit_coefficients, geometry_sensitivities, project_columns
from graytrack.core.models.fourier import TWO_PI, FourierModel

Progress = Callable[[float, str], None]
CONVERGED_RELATIVE_GAIN = 1e-9  # relative cost decrease below which the geometry is converged


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
    design = np.stack([np.sin(TWO_PI * x_mm / period_mm), np.cos(TWO_PI * x_mm / period_mm), np.ones_like(x_mm)],
                      axis=1)
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
    positive = np.array([name in ("period_mm", "pixel_pitch_mm") for name in names])
    model, residual, system = _projected_fit(template, x_mm, data, weights)
    cost = float((residual**2).sum())
    damping, history, iteration = 1e-3, [], 0
    sqrt_w = np.sqrt(weights)
    for iteration in range(1, max_iterations + 1):
        jacobian = _kaufman_jacobian(model, system, x_mm, weights, names) * sqrt_w[..., None]
        jac = jacobian.reshape(-1, len(names))
        normal, gradient = jac.T @ jac, jac.T @ residual.reshape(-1)
        improved = converged = False
        while damping < 1e12:
            step = -np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-300), gradient)
            # What the local linear model promises; below rounding of the cost there is nothing
            # left to gain, and trying would only cost full refits.
            promised = -2.0 * float(gradient @ step) - float(step @ normal @ step)
            if promised <= CONVERGED_RELATIVE_GAIN * cost:
                converged = True
                break
            trial_params = params + step
            if np.any(trial_params[positive] <= 0):
                damping *= 10
                continue
            trial = template.with_changes(**dict(zip(names, trial_params)))
            trial_model, trial_residual, trial_system = _projected_fit(trial, x_mm, data, weights)
            trial_cost = float((trial_residual**2).sum())
            if trial_cost <= cost:
                improved = True
                break
            damping *= 10
        if converged or not improved:
            break
        relative_drop = (cost - trial_cost) / max(cost, 1e-300)
        params, model, residual, cost, system = trial_params, trial_model, trial_residual, trial_cost, trial_system
        damping = max(damping / 10, 1e-9)
        history.append({"iteration": iteration, "cost": cost, **dict(zip(names, params.tolist()))})
        if progress:
            progress(min(0.95, iteration / 10),
                     f"geometry iteration {iteration}, rms {np.sqrt(cost / residual.size):.3f}")
        if relative_drop < CONVERGED_RELATIVE_GAIN:
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
