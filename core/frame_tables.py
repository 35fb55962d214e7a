"""What the per-frame solve reads of a calibrated model, as tables built once when it is installed.

Every model the closed loop can produce is, pixel by pixel, the same expression:

    F_p(x) = clip( Σ_l P_l(s(x)) · Re Σ_h c_{l,h,p} zʰ · (1 + m(x + t_p)) + o_p ),   z = e^{iωx}

with the pixel's phase, its flat-field gain and its mask folded into the complex coefficients c,
the stroke drift as Legendre polynomials P_l of the scaled stage position, a target map m
(piecewise linear along the target, 0 where the map ends; one for all rows or one per row), a per-pixel offset o and
the sensor's clipping limits. Each effect states which of these tables it fills (``Effect.frame_part``), so a
new effect either fits this expression or is refused by the effect registry's test instead of
falling to a slow general path.

:class:`FrameTables` holds the tables and evaluates them with numpy (many positions at once, and
the reference the compiled kernel in :mod:`graytrack.core.kernels` is tested against).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graytrack.core.models.fourier import TWO_PI, FourierModel, map_lookup

FRAME_PARTS = {
    "coefficients": "per-pixel Fourier coefficients (pixel and row polynomials, harmonics, geometry)",
    "stroke": "Legendre polynomials of the stage position multiplying the coefficients",
    "target map": "a piecewise-linear reflectance table along the target (one, or one per row), read at each "
                  "pixel's target coordinate",
    "response": "per-pixel gain and offset (flat field) folded into the coefficients",
    "mask": "per-pixel weights: masked pixels carry no information",
    "clip": "the sensor's limits: saturated samples stick at the limit with no slope",
    "per-frame unknowns": "gain and offset solved per frame alongside x (profiled out of the moments)",
    "calibration only": "changes the data calibration fits, nothing in the tracked model",
}


@dataclass(frozen=True)
class FrameTables:
    """The tables of the expression above, flattened over the model's pixels ``P = R·n``."""

    omega: float  # 2π / period, rad/mm
    coefficients: np.ndarray  # (M+1, L, P) complex: Re Σ_h c zʰ per stroke polynomial
    offset: np.ndarray  # (P,)
    stroke_range_mm: tuple[float, float]  # the span the stroke polynomials are scaled over
    target_map: np.ndarray  # (rows·S,) relative reflectance on the map's grid, row after row; empty without a map
    map_size: int  # S: nodes of one map row
    map_base: np.ndarray  # (P,) int64: where each pixel's map row starts in ``target_map`` (0: one shared map)
    map_origin_mm: float
    map_step_mm: float
    target_offset_mm: np.ndarray  # (P,) where on the target each pixel looks, relative to x
    clip_gray: tuple[float, float]  # (−∞, ∞) without clipping

    @classmethod
    def of(cls, model: FourierModel) -> "FrameTables":
        weights = model.spatial_weights()  # (R, n, A, L)
        gain, offset = model.response()
        gain = np.broadcast_to(np.asarray(gain, dtype=np.float64), weights.shape[:2])
        harmonics = np.arange(1, model.harmonics + 1)
        omega = TWO_PI / model.period_mm
        target_offset = model.target_offset()  # (R, n)
        shift = np.exp(1j * omega * target_offset[..., None] * harmonics)  # (R, n, M)
        n_values = weights.shape[0] * weights.shape[1]
        coefficients = np.empty((model.harmonics + 1, weights.shape[-1], n_values), dtype=complex)
        coefficients[0] = (gain[..., None] * weights[..., 0, :]).reshape(n_values, -1).T
        sin_c, cos_c = weights[..., 1::2, :], weights[..., 2::2, :]  # (R, n, M, L)
        folded = (cos_c - 1j * sin_c) * (shift * gain[..., None])[..., None]
        coefficients[1:] = folded.reshape(n_values, model.harmonics, -1).transpose(1, 2, 0)
        target_map = model.target_map
        map_rows = model.map_rows
        map_size = target_map.shape[1] if target_map is not None else 0
        map_row = np.arange(model.n_rows) if map_rows > 1 else np.zeros(model.n_rows, dtype=np.int64)
        return cls(
            omega=omega,
            coefficients=np.ascontiguousarray(coefficients),
            # (a copy: a broadcast view is read-only, and the compiled kernels take a read-only array as another
            # type, compiled again for it, ~10 s a fresh process, where the warm-up's model had a writable one)
            offset=np.array(np.broadcast_to(np.asarray(offset, dtype=np.float64), weights.shape[:2]).reshape(-1)),
            stroke_range_mm=(float(model.stroke_range_mm[0]), float(model.stroke_range_mm[1])),
            target_map=np.array(target_map.reshape(-1) if target_map is not None else np.zeros(0), dtype=np.float64),
            map_size=map_size,
            map_base=np.repeat(map_row.astype(np.int64) * map_size, model.n_pixels),
            map_origin_mm=float(model.target_map_origin_mm) if target_map is not None else 0.0,
            map_step_mm=float(model.target_map_step_mm) if target_map is not None else 1.0,
            target_offset_mm=np.ascontiguousarray(target_offset.reshape(-1), dtype=np.float64),
            clip_gray=(-np.inf, np.inf) if model.clip_gray is None else (float(model.clip_gray[0]),
                                                                        float(model.clip_gray[1])))

    @property
    def n_values(self) -> int:
        return self.coefficients.shape[2]

    @property
    def trig_polynomial(self) -> bool:
        """Every pixel is a trig polynomial in x: no stroke drift, target map or clipping."""
        return self.stroke_degree == 0 and self.target_map.size == 0 and not np.isfinite(self.clip_gray).any()

    @property
    def stroke_degree(self) -> int:
        return self.coefficients.shape[1] - 1

    def stroke(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(G, L)`` Legendre polynomials of the scaled position and their d/dx (by recurrence, as the kernel)."""
        lo, hi = self.stroke_range_mm
        scale = 2.0 / (hi - lo) if hi > lo else 0.0
        s = (2.0 * x_mm - (lo + hi)) * (1.0 / (hi - lo)) if hi > lo else np.zeros_like(x_mm)
        values = np.ones((x_mm.size, self.stroke_degree + 1))
        slopes = np.zeros_like(values)
        if self.stroke_degree >= 1:
            values[:, 1], slopes[:, 1] = s, 1.0
        for n in range(2, self.stroke_degree + 1):
            values[:, n] = ((2 * n - 1) * s * values[:, n - 1] - (n - 1) * values[:, n - 2]) / n
            slopes[:, n] = n * values[:, n - 1] + s * slopes[:, n - 1]
        return values, slopes * scale

    def map_factor(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(G, P)``: 1 + m at each pixel's target coordinate and its d/dx (1 and 0 off the map)."""
        if self.target_map.size == 0:
            return np.ones((1, 1)), np.zeros((1, 1))
        position = (x_mm[:, None] + self.target_offset_mm[None] - self.map_origin_mm) / self.map_step_mm
        table = self.target_map.reshape(-1, self.map_size)
        factor, rise = map_lookup(table, self.map_base // self.map_size, position)
        return factor, rise / self.map_step_mm

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values and slopes ``(G, P)`` at positions ``x_mm`` ``(G,)``."""
        x_mm = np.atleast_1d(np.asarray(x_mm, dtype=np.float64))
        n_orders, n_stroke, n_values = self.coefficients.shape
        orders = np.arange(n_orders)
        z = np.exp(1j * self.omega * np.outer(x_mm, orders))  # (G, M+1)
        dz = z * (1j * self.omega * orders)
        flat = self.coefficients.reshape(n_orders, -1)
        series = (z @ flat).real.reshape(x_mm.size, n_stroke, n_values)
        turning = (dz @ flat).real.reshape(series.shape)
        if n_stroke == 1:
            smooth, slope = series[:, 0], turning[:, 0]
        else:
            stroke, dstroke = self.stroke(x_mm)
            smooth = np.einsum("gl,glp->gp", stroke, series)
            slope = np.einsum("gl,glp->gp", stroke, turning) + np.einsum("gl,glp->gp", dstroke, series)
        factor, dfactor = self.map_factor(x_mm)
        values = smooth * factor + self.offset
        slopes = slope * factor + smooth * dfactor
        lo, hi = self.clip_gray
        if np.isfinite(lo) or np.isfinite(hi):
            inside = (values > lo) & (values < hi)
            values, slopes = np.clip(values, lo, hi), np.where(inside, slopes, 0.0)
        return values, slopes

    def moments(self, x_mm: float, y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``(7,)``: Σw·F², Σw·F′F, Σw·F′², Σw·F, Σw·F′, Σw·y·F, Σw·y·F′ at ``x_mm`` (the solver's moments)."""
        values, slopes = self.evaluate(np.array([x_mm]))
        wv, ws = values[0] * w, slopes[0] * w
        return np.array([wv @ values[0], ws @ values[0], ws @ slopes[0], wv.sum(), ws.sum(), wv @ y, ws @ y])
