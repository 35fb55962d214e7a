"""Calibration: fit a gray-level model to a sweep against the grating reference.

Variable projection: for given geometry (τ_w, α·d and, for tilted strips, the row shift) the model
is linear in its coefficients and those are solved exactly by least squares; Levenberg–Marquardt
runs only over the 2–3 geometry parameters, with Kaufman's Jacobian of the projected residual.
That is the structure the seed paper's 45-unknown LM ignores, and it is what makes a 1,000-frame
calibration take a fraction of a second.

A model's structure (:class:`ModelSpec`: which effects it has) is fitted by :func:`fit_spec`; the
bilinear parts (flat field, per-frame common mode, target map) by alternation around the
projection. :func:`calibrate` is the entry for the named kinds ``ideal`` and ``paper``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Literal

import numpy as np
from scipy.linalg import solveh_banded
from scipy.optimize import minimize_scalar

from graytrack.core.basis import legendre_basis, scaled, trig_basis
from graytrack.core.errors import CalibrationError
from graytrack.core.linear_fit import LinearSystem, fit_coefficients, geometry_sensitivities, project_columns
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.noise import estimate_sigma
from graytrack.core.recording import Recording

Progress = Callable[[float, str], None]
RowMode = Literal["auto", "mean", "each"]
MIN_FRAMES = 20
# Rows are modelled separately when the shared model leaves this much more variance than noise.
ROW_DISAGREEMENT_EXCESS = 0.10
ALTERNATION_ROUNDS = 4


@dataclass
class CalibrationData:
    """What a fit needs from a recording: positions, frames in the model's row layout, weights."""

    x_mm: np.ndarray  # (K,) reference positions
    frames: np.ndarray  # (K, R, n) raw strip, float64
    weights: np.ndarray  # (K, R, n) 1 for usable samples, 0 for saturated or clipped ones
    sigma_gray: float  # model-free per-pixel noise
    meta: dict[str, Any]
    t_s: np.ndarray | None = None  # (K,) frame times, for velocity-dependent effects

    def subset(self, index: np.ndarray) -> "CalibrationData":
        t_s = None if self.t_s is None else self.t_s[index]
        return CalibrationData(self.x_mm[index], self.frames[index], self.weights[index], self.sigma_gray,
                               self.meta, t_s)

    def with_reference(self, x_mm: np.ndarray) -> "CalibrationData":
        return CalibrationData(x_mm, self.frames, self.weights, self.sigma_gray, self.meta, self.t_s)

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
    return CalibrationData(x_mm, frames, weights, sigma, dict(rec.meta), rec.t[valid])


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


# --------------------------------------------------------------------------- model structures
# The structure of a model and its bilinear parts (flat field, common mode) are fitted here; the
# smooth part goes through the variable projection above. Alternation converges in a few rounds
# because the parts live on different axes (pixels vs frames vs smooth functions). To keep the
# split unique, the flat field holds only what the pixel polynomials cannot: its smooth trend is
# projected out.
@dataclass(frozen=True)
class ModelSpec:
    """The structure of a model: what the closed loop edits, one effect at a time."""

    harmonics: int = 5
    pixel_degree: int = 3
    stroke_degree: int = 0
    per_row: bool = False
    flat_field: bool = False
    common_mode: bool = False
    clip_gray: tuple[float, float] | None = None
    target_map: bool = False
    reference_skew_s: float = 0.0  # grating latched this long after mid-exposure (a data correction)
    name: str = "paper"

    def with_changes(self, **changes) -> "ModelSpec":
        return replace(self, **changes)

    def template(self, period_mm: float, pitch_mm: float, n_pixels: int, n_rows: int,
                 row_shift_mm: float = 0.0) -> FourierModel:
        rows = n_rows if self.per_row else 1
        return FourierModel(
            period_mm, pitch_mm, n_pixels, harmonics=self.harmonics, pixel_degree=self.pixel_degree,
            stroke_degree=self.stroke_degree, n_rows=rows, row_degree=min(2, rows - 1),
            row_shift_mm=row_shift_mm if self.per_row else 0.0, common_mode=self.common_mode,
            clip_gray=self.clip_gray, name=self.name,
        )


def _weighted_affine(target: np.ndarray, regressor: np.ndarray, weights: np.ndarray, axis: tuple[int, ...]):
    """Per-slice least squares target ≈ a·regressor + b over ``axis``: returns (a, b)."""
    sw = weights.sum(axis=axis)
    mean_x = (weights * regressor).sum(axis=axis) / np.maximum(sw, 1e-300)
    mean_y = (weights * target).sum(axis=axis) / np.maximum(sw, 1e-300)
    expand = tuple(a for a in axis)
    dx = regressor - np.expand_dims(mean_x, expand)
    dy = target - np.expand_dims(mean_y, expand)
    slope = (weights * dx * dy).sum(axis=axis) / np.maximum((weights * dx * dx).sum(axis=axis), 1e-300)
    return slope, mean_y - slope * mean_x


def _rough_part(values: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``values`` ``(R, n)`` minus their least-squares fit by the pixel polynomials ``(n, P+1)``."""
    coef, *_ = np.linalg.lstsq(basis, values.T, rcond=None)
    return values - (basis @ coef).T


TARGET_MAP_STEPS_PER_PIXEL = 2
TARGET_MAP_RIDGE = 1e-3


def fit_target_map(model: FourierModel, x_mm: np.ndarray, lit: np.ndarray, smooth: np.ndarray,
                   weights: np.ndarray) -> dict[str, Any]:
    """Relative reflectance m(x_w) on a grid along the target, from lit ≈ S·(1 + m(x_w)).

    Piecewise-linear (hat) basis: the normal matrix is tridiagonal, accumulated with bincount and
    solved banded. What the Fourier × polynomial part can already say (anything periodic or smooth
    along the target) is projected out, so the map holds only local defects.
    """
    step = model.pixel_pitch_mm / TARGET_MAP_STEPS_PER_PIXEL
    x_w = model.target_coordinate(x_mm)
    origin = float(x_w.min()) - step
    size = int(np.ceil((float(x_w.max()) + step - origin) / step)) + 1
    position = (x_w - origin) / step
    cell = np.floor(position).astype(np.int64).reshape(-1)
    frac = (position.reshape(-1) - cell)
    signal, w = smooth.reshape(-1), np.broadcast_to(weights, smooth.shape).reshape(-1)
    target = (lit - smooth).reshape(-1)
    left, right = signal * (1.0 - frac), signal * frac
    diag = np.bincount(cell, w * left * left, size) + np.bincount(cell + 1, w * right * right, size)
    off = np.bincount(cell, w * left * right, size)[:-1]
    rhs = np.bincount(cell, w * left * target, size) + np.bincount(cell + 1, w * right * target, size)
    ridge = TARGET_MAP_RIDGE * max(float(diag.mean()), 1e-300)
    banded = np.zeros((2, size))
    banded[0, 1:], banded[1] = off, diag + ridge
    values = solveh_banded(banded, rhs)
    grid = origin + step * np.arange(size)
    along = legendre_basis(scaled(grid, grid[0], grid[-1]), 0)[:, :, None]
    smooth_part = (along * trig_basis(TWO_PI * grid / model.period_mm, model.harmonics)[:, None, :]).reshape(size, -1)
    coef, *_ = np.linalg.lstsq(smooth_part, values, rcond=None)
    return {"target_map": values - smooth_part @ coef, "target_map_origin_mm": origin, "target_map_step_mm": step}


def fit_spec(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float, row_shift_mm: float = 0.0,
             progress: Progress | None = None, refine_geometry: bool = True, rounds: int | None = None) -> Calibration:
    """Calibrate a model of structure ``spec``; geometry starts from the given values.

    ``refine_geometry=False`` keeps τ_w and α·d as given (a per-row model still fits its row
    shift): once stroke or high-degree pixel terms exist they can trade against the geometry, and
    a geometry that wanders off its physical value helps nothing while misleading whoever reads it.
    """
    template = spec.template(period_mm, pitch_mm, data.frames.shape[-1], data.frames.shape[1], row_shift_mm)
    template = template.with_changes(stroke_range_mm=(float(data.x_mm.min()), float(data.x_mm.max())))
    raw = template.prepare(data.frames)
    weights = template.prepare(data.weights) if template.n_rows > 1 else data.weights.min(axis=1, keepdims=True)
    if spec.clip_gray is not None:
        lo, hi = spec.clip_gray
        weights = weights * ((raw > lo) & (raw < hi))
    names = (("period_mm", "pixel_pitch_mm") if refine_geometry else ()) + (
        ("row_shift_mm",) if template.n_rows > 1 else ())
    bilinear = spec.flat_field or spec.common_mode or spec.target_map
    frame_gain, frame_offset = np.ones(raw.shape[0]), np.zeros(raw.shape[0])
    pixel_gain, pixel_offset = np.ones(raw.shape[1:]), np.zeros(raw.shape[1:])
    map_factor: np.ndarray | float = 1.0
    target_map = None
    model, iterations, history = template, 0, []
    for round_index in range((rounds or ALTERNATION_ROUNDS) if bilinear else 1):
        per_frame = (raw - frame_offset[:, None, None]) / frame_gain[:, None, None]
        lit = (per_frame - pixel_offset) / pixel_gain  # the light on the target, seen through the smooth model
        if round_index == 0 and names:
            model, iterations, history = fit_geometry(model, data.x_mm, lit / map_factor, weights, names,
                                                      progress=progress)
        else:
            model, _ = fit_coefficients(model, data.x_mm, lit / map_factor, weights)
        smooth = model.predict(data.x_mm, with_response=False)
        if spec.target_map:
            target_map = fit_target_map(model, data.x_mm, lit, smooth, weights)
            map_factor = model.with_changes(coeffs=model.coeffs, **target_map).target_factor(data.x_mm)[0]
        shaded = smooth * map_factor
        if spec.flat_field:
            gain, offset = _weighted_affine(per_frame, shaded, weights, axis=(0,))
            basis = model.pixel_basis()
            pixel_gain = 1.0 + _rough_part(gain - 1.0, basis)
            pixel_offset = _rough_part(offset, basis)
        if spec.common_mode:
            frame_gain, frame_offset = _weighted_affine(raw, pixel_gain * shaded + pixel_offset, weights, axis=(1, 2))
            frame_offset = frame_offset - frame_offset.mean()
            frame_gain = frame_gain / frame_gain.mean()
        if progress and bilinear:
            progress(0.5 + 0.5 * (round_index + 1) / ALTERNATION_ROUNDS, f"alternation round {round_index + 1}")
    if spec.flat_field:
        model = model.with_changes(pixel_gain=pixel_gain, pixel_offset=pixel_offset, coeffs=model.coeffs)
    if target_map is not None:
        model = model.with_changes(coeffs=model.coeffs, **target_map)
    fitted = frame_gain[:, None, None] * model.predict(data.x_mm) + frame_offset[:, None, None]
    usable = data.weights.copy()
    if spec.clip_gray is not None:
        usable *= (data.frames > spec.clip_gray[0]) & (data.frames < spec.clip_gray[1])
    rmse = float(np.sqrt((((data.frames - fitted) ** 2) * usable).sum() / max(usable.sum(), 1.0)))
    model = model.with_changes(noise_gray=data.sigma_gray, coeffs=model.coeffs,
                               info={**model.info, "calibration_rmse_gray": rmse})
    return Calibration(model, rmse, data.sigma_gray, iterations, history)


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


def fit_spec_pitch_search(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float,
                          row_shift_mm: float = 0.0, span: float = 0.12) -> Calibration:
    """:func:`fit_spec` with α·d searched for the lowest residual.

    A target map pins features to the target coordinate x + α·d·u, so it needs α·d to a fraction
    of a defect's width across the line, far better than the smooth model alone determines it
    (the pixel polynomials absorb a pitch error, and the defects themselves bias it by 10 % and
    more). The residual has a sharp valley at the true α·d: a coarse scan with one alternation
    round (spanning the fitted and the nominal value) finds it, a bounded search refines it.
    """
    nominal = data.meta.get("pixel_pitch_mm", pitch_mm)
    lo, hi = min(pitch_mm, nominal) * (1 - span), max(pitch_mm, nominal) * (1 + span)
    grid = np.linspace(lo, hi, int(np.ceil((hi - lo) / (0.01 * pitch_mm))) + 1)

    def cost(pitch: float, rounds: int | None = None) -> float:
        return fit_spec(spec, data, period_mm, pitch, row_shift_mm, refine_geometry=False, rounds=rounds).rmse_gray

    coarse = np.array([cost(p, rounds=1) for p in grid])
    best = int(np.argmin(coarse))
    bounds = (grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)])
    refined = minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": pitch_mm * 2e-4})
    return fit_spec(spec, data, period_mm, float(refined.x), row_shift_mm, refine_geometry=False)


KIND_SPECS = {
    "ideal": ModelSpec(harmonics=1, pixel_degree=0, name="ideal"),
    "paper": ModelSpec(harmonics=5, pixel_degree=3, name="paper"),
}


def calibrate(rec: Recording, model: str = "paper", *, harmonics: int | None = None, pixel_degree: int | None = None,
              rows: RowMode = "auto", progress: Progress | None = None) -> Calibration:
    """Calibrate the ``ideal`` or ``paper`` model on a recording with a reference."""
    if model not in KIND_SPECS:
        raise CalibrationError(f"unknown model kind {model!r} (expected one of {', '.join(KIND_SPECS)})")
    spec = KIND_SPECS[model]
    if harmonics is not None:
        spec = spec.with_changes(harmonics=harmonics)
    if pixel_degree is not None:
        spec = spec.with_changes(pixel_degree=pixel_degree)
    data = calibration_data(rec)
    period, pitch, row_shift = initial_geometry(data)
    result = fit_spec(spec, data, period, pitch, progress=progress)
    n_rows = data.frames.shape[1]
    if n_rows > 1 and (rows == "each" or (rows == "auto" and rows_disagree(result.model, data))):
        geometry = result.model
        result = fit_spec(spec.with_changes(per_row=True), data, geometry.period_mm, geometry.pixel_pitch_mm,
                          row_shift, progress)
    if progress:
        progress(1.0, f"done, rms {result.rmse_gray:.3f} gray")
    return result
