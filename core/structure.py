"""Model structures: which effects a model has (:class:`ModelSpec`), and fitting one to data.

The smooth part (Fourier × polynomials) goes through the variable projection of geometry.py. The
bilinear parts (flat field, per-frame common mode, target map) are fitted by alternation around
it, which converges in a few rounds because they live on different axes (pixels vs frames vs
the target coordinate vs smooth functions). To keep the split unique, the flat field holds only
what the pixel polynomials cannot, and the target map only what is not periodic.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
from scipy.linalg import solveh_banded
from scipy.optimize import minimize_scalar

from graytrack.core.basis import trig_basis
from graytrack.core.calibration_data import Calibration, CalibrationData
from graytrack.core.geometry import fit_geometry
from graytrack.core.linear_fit import fit_coefficients
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.regression import weighted_affine

Progress = Callable[[float, str], None]
ALTERNATION_ROUNDS = 4
PITCH_PIXEL_DEGREE = 1  # pixel polynomial degree of the model that fixes α·d


@dataclass(frozen=True)
class ModelSpec:
    """The structure of a model: what the closed loop edits, one effect at a time."""

    harmonics: int = 5
    pixel_degree: int = 3
    stroke_degree: int = 0
    per_row: bool = False
    row_degree: int = 2  # row polynomials of a per-row model (capped at rows − 1)
    flat_field: bool = False
    common_mode: bool = False
    clip_gray: tuple[float, float] | None = None
    target_map: int = 0  # grid steps per pixel footprint of a target map (0: none)
    reference_skew_s: float = 0.0  # grating latched this long after mid-exposure (a data correction)
    name: str = "paper"

    def with_changes(self, **changes) -> "ModelSpec":
        return replace(self, **changes)

    def template(self, period_mm: float, pitch_mm: float, n_pixels: int, n_rows: int,
                 row_shift_mm: float = 0.0) -> FourierModel:
        rows = n_rows if self.per_row else 1
        return FourierModel(
            period_mm, pitch_mm, n_pixels, harmonics=self.harmonics, pixel_degree=self.pixel_degree,
            stroke_degree=self.stroke_degree, n_rows=rows, row_degree=min(self.row_degree, rows - 1),
            row_shift_mm=row_shift_mm if self.per_row else 0.0, common_mode=self.common_mode,
            clip_gray=self.clip_gray, name=self.name,
        )


def _rough_part(values: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``values`` ``(R, n)`` minus their least-squares fit by the pixel polynomials ``(n, P+1)``."""
    coef, *_ = np.linalg.lstsq(basis, values.T, rcond=None)
    return values - (basis @ coef).T


DEFAULT_MAP_STEPS = 2  # half a pixel footprint: finer grids are noisier, coarser ones blur dust
MAX_MAP_STEPS = 4  # a quarter of a pixel footprint, for defects narrower than a pixel (scratches)
TARGET_MAP_RIDGE = 1e-3


def fit_target_map(model: FourierModel, x_mm: np.ndarray, lit: np.ndarray, smooth: np.ndarray,
                   weights: np.ndarray, steps_per_pixel: int = DEFAULT_MAP_STEPS) -> dict[str, Any]:
    """Relative reflectance m(x_w) on a grid along the target, from lit ≈ S·(1 + m(x_w)).

    Piecewise-linear (hat) basis: the normal matrix is tridiagonal, accumulated with bincount and
    solved banded. What the Fourier × polynomial part can already say (anything periodic or smooth
    along the target) is projected out, so the map holds only local defects.
    """
    step = model.pixel_pitch_mm / steps_per_pixel
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
    periodic = trig_basis(TWO_PI * grid / model.period_mm, model.harmonics)
    coef, *_ = np.linalg.lstsq(periodic, values, rcond=None)
    return {"target_map": values - periodic @ coef, "target_map_origin_mm": origin, "target_map_step_mm": step}


def fit_spec(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float, row_shift_mm: float = 0.0,
             progress: Progress | None = None, refine_geometry: bool = True, rounds: int | None = None) -> Calibration:
    """Calibrate a model of structure ``spec``; geometry starts from the given values.

    ``refine_geometry=False`` keeps τ_w and α·d as given (a per-row model still fits its row
    shift): once stroke or high-degree pixel terms exist they can trade against the geometry, and
    a geometry that wanders off its physical value helps nothing while misleading whoever reads it.

    With refinement, α·d comes from a model at most linear in the pixel index: cubic pixel
    polynomials can turn the phase by a radian across the line and so absorb a pitch error (a
    light gradient then pulls α·d 25 % off), a linear one cannot. That model leaves a large
    residual, where Gauss–Newton steps zig-zag, so α·d is found by a scan and a bounded search
    instead. τ_w is then refined with the full model.
    """
    geometry_names = ("period_mm", "pixel_pitch_mm")
    if refine_geometry and spec.pixel_degree > PITCH_PIXEL_DEGREE:
        coarse = spec.with_changes(pixel_degree=PITCH_PIXEL_DEGREE, flat_field=False, common_mode=False,
                                   target_map=0)
        pitch_mm = fit_spec_pitch_search(coarse, data, period_mm, pitch_mm, row_shift_mm,
                                         grid_step=0.02).model.pixel_pitch_mm
        geometry_names = ("period_mm",)
    template = spec.template(period_mm, pitch_mm, data.frames.shape[-1], data.frames.shape[1], row_shift_mm)
    template = template.with_changes(stroke_range_mm=(float(data.x_mm.min()), float(data.x_mm.max())))
    raw = template.prepare(data.frames)
    weights = template.prepare(data.weights) if template.n_rows > 1 else data.weights.min(axis=1, keepdims=True)
    if spec.clip_gray is not None:
        lo, hi = spec.clip_gray
        weights = weights * ((raw > lo) & (raw < hi))
    row_names: tuple[str, ...] = ()
    if template.n_rows > 1 and template.row_degree > 0:
        # Row polynomials can absorb a row shift as they absorb a pitch error: the shift (the
        # camera's tilt) is found with rows that differ by nothing else, then held.
        flat_rows = spec.with_changes(row_degree=0, flat_field=False, common_mode=False, target_map=0)
        row_shift_mm = fit_spec(flat_rows, data, period_mm, pitch_mm, row_shift_mm,
                                refine_geometry=False).model.row_shift_mm
        template = template.with_changes(row_shift_mm=row_shift_mm)
    elif template.n_rows > 1:
        row_names = ("row_shift_mm",)
    names = (geometry_names if refine_geometry else ()) + row_names
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
            target_map = fit_target_map(model, data.x_mm, lit, smooth, weights, spec.target_map)
            map_factor = model.with_changes(coeffs=model.coeffs, **target_map).target_factor(data.x_mm)[0]
        shaded = smooth * map_factor
        if spec.flat_field:
            gain, offset = weighted_affine(per_frame, shaded, weights, axis=(0,))
            basis = model.pixel_basis()
            pixel_gain = 1.0 + _rough_part(gain - 1.0, basis)
            pixel_offset = _rough_part(offset, basis)
        if spec.common_mode:
            frame_gain, frame_offset = weighted_affine(raw, pixel_gain * shaded + pixel_offset, weights, axis=(1, 2))
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


def fit_spec_pitch_search(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float,
                          row_shift_mm: float = 0.0, span: float = 0.12, grid_step: float = 0.01) -> Calibration:
    """:func:`fit_spec` with α·d searched for the lowest residual.

    A target map pins features to the target coordinate x + α·d·u, so it needs α·d to a fraction
    of a defect's width across the line, far better than the smooth model alone determines it
    (the pixel polynomials absorb a pitch error, and the defects themselves bias it by 10 % and
    more). The residual has a sharp valley at the true α·d: a coarse scan with one alternation
    round (spanning the fitted and the nominal value) finds it, a bounded search refines it.
    """
    nominal = data.meta.get("pixel_pitch_mm", pitch_mm)
    lo, hi = min(pitch_mm, nominal) * (1 - span), max(pitch_mm, nominal) * (1 + span)
    grid = np.linspace(lo, hi, int(np.ceil((hi - lo) / (grid_step * pitch_mm))) + 1)

    def cost(pitch: float, rounds: int | None = None) -> float:
        return fit_spec(spec, data, period_mm, pitch, row_shift_mm, refine_geometry=False, rounds=rounds).rmse_gray

    coarse = np.array([cost(p, rounds=1) for p in grid])
    best = int(np.argmin(coarse))
    bounds = (grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)])
    refined = minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": pitch_mm * 2e-4})
    return fit_spec(spec, data, period_mm, float(refined.x), row_shift_mm, refine_geometry=False)
