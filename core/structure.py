"""Model structures: which effects a model has (:class:`ModelSpec`), and fitting one to data.

The smooth part (Fourier × polynomials) goes through the variable projection of geometry.py. The
bilinear effects (flat field, per-frame common mode, target map: core/effects/) are fitted by
alternation around it, each re-fitting its own layer in turn; that converges in a few rounds
because they live on different axes (pixels vs frames vs the target coordinate vs smooth
functions). Each effect keeps its split unique itself (the flat field holds only what the pixel
polynomials cannot, the target map only what is not periodic).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
from scipy.optimize import minimize_scalar

from graytrack.core import effects
from graytrack.core.calibration_data import CalibrationFit, CalibrationData, sensor_range
from graytrack.core.geometry import fit_geometry
from graytrack.core.linear_fit import fit_coefficients
from graytrack.core.models.fourier import FourierModel

Progress = Callable[[float, str], None]
ALTERNATION_ROUNDS = 4
PITCH_PIXEL_DEGREE = 1  # pixel polynomial degree of the model that fixes α·d


@dataclass(frozen=True)
class ModelSpec:
    """The structure of a model: what the closed loop edits, one effect at a time.

    The sizes of the smooth model are fields; every other effect keeps its setting (a flag, the
    clip limits, a grid size, a list of pixels…) under its own name in ``settings``, so a new
    effect needs no new field here (core/effects/).
    """

    harmonics: int = 5
    pixel_degree: int = 3
    stroke_degree: int = 0
    per_row: bool = False
    row_degree: int = 2  # row polynomials of a per-row model (capped at rows − 1)
    name: str = "paper"
    settings: tuple[tuple[str, Any], ...] = ()

    def with_changes(self, **changes) -> "ModelSpec":
        return replace(self, **changes)

    def get(self, effect: str, default: Any = None) -> Any:
        """The setting of ``effect`` (``default`` when the spec does not have it)."""
        return dict(self.settings).get(effect, default)

    def set(self, effect: str, setting: Any) -> "ModelSpec":
        """A copy with ``effect`` set (``None`` removes it)."""
        settings = {**dict(self.settings), effect: setting}
        return replace(self, settings=tuple((k, v) for k, v in settings.items() if v is not None))

    def smooth_only(self, **changes) -> "ModelSpec":
        """The spec without its bilinear effects: the model that fixes the geometry."""
        kept = tuple((k, v) for k, v in self.settings if not effects.registry()[k].bilinear)
        return replace(self, settings=kept, **changes)

    def template(self, period_mm: float, pitch_mm: float, n_pixels: int, n_rows: int,
                 row_shift_mm: float = 0.0) -> FourierModel:
        rows = n_rows if self.per_row else 1
        fields: dict[str, Any] = {}
        for effect, setting in effects.active(self):
            fields.update(effect.model_fields(setting))
        return FourierModel(
            period_mm, pitch_mm, n_pixels, harmonics=self.harmonics, pixel_degree=self.pixel_degree,
            stroke_degree=self.stroke_degree, n_rows=rows, row_degree=min(self.row_degree, rows - 1),
            row_shift_mm=row_shift_mm if self.per_row else 0.0, name=self.name, **fields,
        )


def fit_spec(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float, row_shift_mm: float = 0.0,
             progress: Progress | None = None, refine_geometry: bool = True, rounds: int | None = None,
             searching: bool = False) -> CalibrationFit:
    """Calibrate a model of structure ``spec``; geometry starts from the given values.

    ``refine_geometry=False`` keeps τ_w and α·d as given (a per-row model still fits its row
    shift): once stroke or high-degree pixel terms exist they can trade against the geometry, and
    a geometry that wanders off its physical value helps nothing while misleading whoever reads it.

    With refinement, α·d comes from a model at most linear in the pixel index: cubic pixel
    polynomials can turn the phase by a radian across the line and so absorb a pitch error (a
    light gradient then pulls α·d 25 % off), a linear one cannot. That model leaves a large
    residual, where Gauss–Newton steps zig-zag, so α·d is found by a scan and a bounded search
    instead. τ_w is then refined with the full model.

    τ_w is refined again in the second alternation round (the only one of a spec without bilinear
    layers), whatever ``refine_geometry`` says. The geometry a seed model fixed is pulled by every
    layer it lacked: stray light from a reflection in the lens moved a 16-row strip's τ_w 280 ppm,
    and held there, the model the loop grew around it (flat field, rows) fitted every image to its
    noise yet placed the frames at twice their bound, the stroke's ends 1.4 µm off the grating (the
    flat field was even rejected on an 8 s sweep: 0.66 → 0.77 µm; with τ_w refined, 0.43 µm).
    Only stroke terms turn the phase along the stroke as τ_w does: a spec with them keeps its τ_w.

    ``searching``: one point of a search over the geometry (:func:`fit_spec_pitch_search`), whose
    only use is its residual. The row shift is held as given (the search found it once) and the
    photon-transfer weights are not refitted: in a 16-row lab strip with its rows, flat field and
    map, those two were 75 % of a target map's trial, 11 minutes of one closed-loop step.
    """
    geometry_names: tuple[str, ...] = ("period_mm", "pixel_pitch_mm")
    if refine_geometry and spec.pixel_degree > PITCH_PIXEL_DEGREE:
        # α·d is one number for the whole strip: the row mean fixes it as well as every row does,
        # at a fraction of the cost of a per-row model inside every step of the search.
        coarse = spec.smooth_only(pixel_degree=PITCH_PIXEL_DEGREE, per_row=False)
        pitch_mm = fit_spec_pitch_search(coarse, data, period_mm, pitch_mm, row_shift_mm,
                                         grid_step=0.02).model.pixel_pitch_mm
        geometry_names = ("period_mm",)
    template = spec.template(period_mm, pitch_mm, data.frames.shape[-1], data.frames.shape[1], row_shift_mm)
    template = template.with_changes(stroke_range_mm=(float(data.x_mm.min()), float(data.x_mm.max())))
    raw = template.prepare(data.frames)
    weights = template.prepare(data.weights) if template.n_rows > 1 else data.weights.min(axis=1, keepdims=True)
    row_names: tuple[str, ...] = ()
    if template.n_rows > 1 and template.row_degree > 0:
        if not searching:
            row_shift_mm = _row_shift(spec, data, period_mm, pitch_mm, row_shift_mm)
            template = template.with_changes(row_shift_mm=row_shift_mm)
    elif template.n_rows > 1 and not searching:
        row_names = ("row_shift_mm",)
    names = (geometry_names if refine_geometry else ()) + row_names
    # τ_w once more after the first round, its layers known (see the docstring)
    late_names = ("period_mm",) if spec.stroke_degree == 0 and not searching else ()
    steps = [(effect, setting) for effect, setting in effects.active(spec) if effect.bilinear]
    state = effects.Alternation(data.x_mm, raw, weights, template, np.ones(raw.shape[0]), np.zeros(raw.shape[0]),
                                np.ones(raw.shape[1:]), np.zeros(raw.shape[1:]), found={})
    n_rounds = (rounds or ALTERNATION_ROUNDS) if steps else 1
    iterations, history = _alternate(state, steps, n_rounds, names, progress, late_names)
    model = _finished(spec, state)
    noise = data.pixel_noise
    if noise is not None and noise.signal_dependent and not searching:
        # Photon-transfer weights 1/σ²(y) at the fitted values (not the noisy samples, which would
        # bias the fit towards dark ones), normalised to mean 1, then the linear parts once more.
        fitted = state.frame_gain[:, None, None] * model.predict(data.x_mm) + state.frame_offset[:, None, None]
        inverse = weights / noise.variance(fitted)
        state.weights = inverse / max(float(inverse[weights > 0].mean()), 1e-300)
        _alternate(state, steps, n_rounds, (), None)
        model = _finished(spec, state)
    fitted = state.frame_gain[:, None, None] * model.predict(data.x_mm) + state.frame_offset[:, None, None]
    usable = (data.weights > 0) * model.seen()
    residual2 = ((data.frames - fitted) ** 2) * usable
    rmse = float(np.sqrt(residual2.sum() / max(usable.sum(), 1.0)))
    info = {**model.info, "calibration_rmse_gray": rmse,  # frames and their spread: what the scale is known from
            "calibration_frames": int(np.size(data.x_mm)), "calibration_x_std_mm": float(np.std(data.x_mm))}
    if data.meta.get("repeated_frames"):  # calibration_data left them out: the model says so
        info["repeated_frames"] = int(data.meta["repeated_frames"])
    if data.meta.get("transients"):  # samples calibration_data set aside as transients (glints)
        info["transients"] = data.meta["transients"]
    limits = sensor_range(data.meta)
    if limits is not None:  # the tracker sets aside samples stuck at a limit, whatever the model
        info["sensor_range_gray"] = list(limits)
    model = model.with_changes(noise_gray=data.sigma_gray, coeffs=model.coeffs, pixel_noise=noise, info=info)
    chi2 = float((residual2 * model.inverse_variance(fitted)).sum() / max(usable.sum(), 1.0))
    # the level a new frame's χ² is held against: a model with many numbers fitted (a map a row)
    # fits its own frames closer than it will fit any other, and every frame would look changed
    # (counted as the model sees them: a model of the rows' mean fits one sample where R were read)
    model.info["calibration_chi2"] = model.out_of_sample(chi2, float(usable.sum()) * model.n_rows / usable.shape[1])
    return CalibrationFit(model, rmse, data.sigma_gray, iterations, history)


def _row_shift(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float,
               row_shift_mm: float) -> float:
    """The row shift (the camera's tilt) of a per-row spec. Row polynomials can absorb a row shift
    as they absorb a pitch error: the shift is found with rows that differ by nothing else, then held."""
    flat_rows = spec.smooth_only(row_degree=0)
    return fit_spec(flat_rows, data, period_mm, pitch_mm, row_shift_mm, refine_geometry=False).model.row_shift_mm


def _alternate(state: effects.Alternation, steps: list[tuple[effects.Effect, Any]], n_rounds: int,
               names: tuple[str, ...], progress: Progress | None,
               late_names: tuple[str, ...] = ()) -> tuple[int, list[dict[str, float]]]:
    """Rounds of the smooth fit (geometry too in the first, when ``names`` are given, and
    ``late_names`` in the second, or the only one) and of every bilinear effect's step."""
    iterations, history = 0, []  # type: int, list[Any]
    for round_index in range(n_rounds):
        lit = state.lit / state.map_factor
        # an effect whose layer the geometry would otherwise absorb has the geometry refined again
        # once its layer is known (the second round)
        again = round_index == 1 and any(effect.refits_geometry for effect, _ in steps)
        fitted = names if round_index == 0 or again else ()
        if round_index == min(1, n_rounds - 1):
            fitted = fitted + tuple(name for name in late_names if name not in fitted)
        if fitted:
            state.model, iterations, history = fit_geometry(state.model, state.x_mm, lit, state.weights, fitted,
                                                            progress=progress)
        else:
            state.model, _ = fit_coefficients(state.model, state.x_mm, lit, state.weights)
        state.smooth = state.model.predict(state.x_mm, with_response=False)
        for effect, setting in steps:
            effect.fit_step(setting, state)
        if progress and steps:
            progress(0.5 + 0.5 * (round_index + 1) / n_rounds, f"alternation round {round_index + 1}")
    return iterations, history


def _finished(spec: ModelSpec, state: effects.Alternation) -> FourierModel:
    model = state.model
    for effect, setting in effects.active(spec):
        model = effect.finish(setting, state, model)
    return model


def fit_spec_pitch_search(spec: ModelSpec, data: CalibrationData, period_mm: float, pitch_mm: float,
                          row_shift_mm: float = 0.0, span: float = 0.12, grid_step: float = 0.01,
                          found_mm: float | None = None) -> CalibrationFit:
    """:func:`fit_spec` with α·d searched for the lowest residual.

    A target map pins features to the target coordinate x + α·d·u, so it needs α·d to a fraction
    of a defect's width across the line, far better than the smooth model alone determines it
    (the pixel polynomials absorb a pitch error, and the defects themselves bias it by 10 % and
    more). The residual has a sharp valley at the true α·d: a coarse scan with one alternation
    round (spanning the fitted and the nominal value) finds it, a bounded search refines it.

    ``found_mm``: where an earlier search with another structure found the valley (α·d is the
    optics', whatever else the model holds): the scan then spans two grid steps either side of it,
    and the whole span only if its best point is at an end.
    """
    nominal = data.meta.get("pixel_pitch_mm", pitch_mm)
    lo, hi = min(pitch_mm, nominal) * (1 - span), max(pitch_mm, nominal) * (1 + span)
    grid = np.linspace(lo, hi, int(np.ceil((hi - lo) / (grid_step * pitch_mm))) + 1)

    per_row = spec.per_row and data.frames.shape[1] > 1
    search_shift = _row_shift(spec, data, period_mm, pitch_mm, row_shift_mm) if per_row else row_shift_mm

    def cost(pitch: float, rounds: int | None = None) -> float:
        return fit_spec(spec, data, period_mm, pitch, search_shift, refine_geometry=False, rounds=rounds,
                        searching=True).rmse_gray

    scan = None
    if found_mm is not None:
        near = found_mm * (1.0 + grid_step * np.arange(-2, 3))
        costs = np.array([cost(p, rounds=1) for p in near])
        if 0 < int(np.argmin(costs)) < near.size - 1:
            scan = (near, costs)
    grid, coarse = scan if scan is not None else (grid, np.array([cost(p, rounds=1) for p in grid]))
    best = int(np.argmin(coarse))
    bounds = (grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)])
    refined = minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": pitch_mm * 2e-4})
    return fit_spec(spec, data, period_mm, float(refined.x), row_shift_mm, refine_geometry=False)
