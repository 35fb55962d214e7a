"""The gray-level model: Fourier series in the target phase with coefficients smooth in pixel, row
and stroke position, times a per-pixel response, times a per-frame common mode.

    x_w[k, r, u]  = x_k + p·u + q·(r − r_c)                      where the pixel looks on the target
    θ[k, r, u]    = 2π·x_w / τ
    S[k, r, u]    = Σ_a T_a(θ) · W_a(u, r, x_k)                  T = [1, sin θ, cos θ, …, sin Mθ, cos Mθ]
    W_a(u, r, x)  = Σ_ijl C[a, i, j, l] · P_i(s_u) · P_j(s_r) · P_l(s_x)    (Legendre, scaled coordinates)
    Y[k, r, u]    = g_k · (gain[r, u] · S + offset[r, u]) + o_k

With M = 5, cubic in u, nothing along r or x and unit response, this is exactly the seed paper's
model (eq. 11); with M = 1 and degree 0 it is the ideal sine (A, τ_w, α·d, φ, D). Every other
term is something the closed loop may add when the data ask for it:
- ``stroke_degree`` > 0: coefficients that drift along the stroke (illumination fixed to the
  target, print density, pitch chirp seen as a slow phase drift);
- ``n_rows`` > 1 with ``row_shift_mm``: rows that see a shifted target (camera tilt), with
  ``row_degree`` for row-dependent shading;
- ``pixel_gain`` / ``pixel_offset``: a flat field (PRNU/DSNU), rough from pixel to pixel;
- ``common_mode``: a gain and offset per frame (flicker, exposure drift), solved with x;
- ``clip_gray``: the sensor's floor and ceiling; a clipped pixel says nothing about x;
- ``target_map``: a relative reflectance change fixed to the target, on a fine grid along it
  (dust, scratches, print defects): S·(1 + m(x_w)), neither periodic nor smooth; one map for all
  rows, or one per row of a per-row model (a dust spot is round: rows a few pixels apart see it
  differently, and a map shared by the rows holds their mean, wrong on every row).

Two fields say how much each sample is worth rather than what it should read:
- ``pixel_weight`` ``(R, n)``: 0 for a pixel found bad (stuck, dead, hot, noisy), 1 otherwise;
- ``pixel_noise``: σ² as a function of gray level (photon transfer, core/pixel_noise.py); without
  it every sample has σ = ``noise_gray``.

The model is linear in C given (τ, p, q): calibration exploits that (variable projection).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Literal, overload

import numpy as np

from graytrack.core.basis import legendre_basis, scaled, trig_basis, trig_derivative
from graytrack.core.errors import ModelError, TrackingError
from graytrack.core.pixel_noise import PixelNoise

TWO_PI = 2.0 * math.pi
_GEOMETRY_FIELDS = {"period_mm", "pixel_pitch_mm", "row_shift_mm", "n_rows", "n_pixels", "harmonics"}
_TRIG_CACHE_ELEMENTS = 2_000_000


def _positions(x_mm: Any) -> np.ndarray:
    """Positions as a 1-D float64 array; an array that already is one is returned as itself, so
    that caches keyed on its identity keep working."""
    if isinstance(x_mm, np.ndarray) and x_mm.ndim == 1 and x_mm.dtype == np.float64:
        return x_mm
    return np.asarray(x_mm, dtype=np.float64).reshape(-1)


def map_lookup(table: np.ndarray, map_row: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """1 + m and dm per grid step at ``position`` (in grid steps from the map's origin) on row
    ``map_row`` of a piecewise-linear map ``(rows, S)``; 1 and 0 off the map. The compiled kernel
    (core/kernels.py) reads the map by the same rule, node for node."""
    last = table.shape[1] - 1
    cell = np.floor(position).astype(np.int64)
    inside = (cell >= 0) & (cell < last)
    at = np.clip(cell, 0, last - 1)
    low = table[map_row, at]
    rise = table[map_row, at + 1] - low
    factor = np.where(inside, low + (position - at) * rise, 0.0)
    factor = np.where(position == last, table[map_row, last], factor)  # the map's last node itself
    return 1.0 + factor, np.where(inside, rise, 0.0)


@dataclass
class FourierModel:
    """Calibrated (or to-be-calibrated) gray-level model of one pixel line or strip."""

    period_mm: float
    pixel_pitch_mm: float
    n_pixels: int
    harmonics: int = 5
    pixel_degree: int = 3
    stroke_degree: int = 0
    stroke_range_mm: tuple[float, float] = (0.0, 1.0)
    n_rows: int = 1
    row_degree: int = 0
    row_shift_mm: float = 0.0
    coeffs: np.ndarray | None = None
    pixel_gain: np.ndarray | None = None
    pixel_offset: np.ndarray | None = None
    common_mode: bool = False
    clip_gray: tuple[float, float] | None = None
    target_map: np.ndarray | None = None
    target_map_origin_mm: float = 0.0
    target_map_step_mm: float = 0.0
    noise_gray: float | None = None
    pixel_weight: np.ndarray | None = None
    pixel_noise: PixelNoise | None = None
    name: str = "paper"
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.period_mm > 0 and self.pixel_pitch_mm > 0 and self.n_pixels >= 2):
            raise ModelError(
                f"model geometry must be positive: period {self.period_mm}, pitch {self.pixel_pitch_mm}, pixels "
                f"{self.n_pixels}"
            )
        for label, value in (("harmonics", self.harmonics), ("pixel_degree", self.pixel_degree),
                             ("stroke_degree", self.stroke_degree), ("row_degree", self.row_degree)):
            if value < 0 or int(value) != value:
                raise ModelError(f"{label} must be a non-negative integer, got {value}")
        if self.harmonics < 1:
            raise ModelError("harmonics must be at least 1")
        if self.clip_gray is not None:
            low, high = (float(v) for v in self.clip_gray)
            if not low < high:  # NaN fails too; an infinite side means "never clips there"
                raise ModelError(f"clip_gray must be [floor, ceiling] with floor < ceiling, got {list(self.clip_gray)}")
        if self.coeffs is not None:
            self.coeffs = np.asarray(self.coeffs, dtype=np.float64)
            if self.coeffs.shape != self.coeff_shape:
                raise ModelError(f"coefficients have shape {self.coeffs.shape}, the model needs {self.coeff_shape}")
        if self.target_map is not None:
            self.target_map = np.atleast_2d(np.asarray(self.target_map, dtype=np.float64))
            if self.target_map.ndim != 2 or self.target_map.shape[1] < 2 or not self.target_map_step_mm > 0:
                raise ModelError("target_map needs at least 2 values a row and a positive step")
            if self.target_map.shape[0] not in (1, self.n_rows):
                raise ModelError(f"target_map has {self.target_map.shape[0]} rows; the model has {self.n_rows} "
                                 "(one map for all rows, or one per row)")
        for label in ("pixel_gain", "pixel_offset", "pixel_weight"):
            given = getattr(self, label)
            if given is not None:
                table = np.asarray(given, dtype=np.float64)
                if table.shape != (self.n_rows, self.n_pixels):
                    raise ModelError(f"{label} has shape {table.shape}, the model needs {(self.n_rows, self.n_pixels)}")
                setattr(self, label, table)
        self._cache: dict[str, Any] = {}

    # ----------------------------------------------------------------- structure
    @property
    def n_trig(self) -> int:
        return 2 * self.harmonics + 1

    @property
    def coeff_shape(self) -> tuple[int, int, int, int]:
        return (self.n_trig, self.pixel_degree + 1, self.row_degree + 1, self.stroke_degree + 1)

    @property
    def n_coeffs(self) -> int:
        return int(np.prod(self.coeff_shape))

    @property
    def is_calibrated(self) -> bool:
        return self.coeffs is not None

    def with_changes(self, **changes: Any) -> "FourierModel":
        """A copy with some fields changed (coefficients dropped unless given: they no longer fit).

        A copy with the same geometry keeps the cached target-phase terms: variable projection
        evaluates many coefficient sets at one geometry.
        """
        changes.setdefault("coeffs", None if set(changes) - {"noise_gray", "info", "name"} else self.coeffs)
        copy = replace(self, **changes)
        if not set(changes) & _GEOMETRY_FIELDS and "trig" in self._cache:
            copy._cache["trig"] = self._cache["trig"]
        return copy

    def derived(self, key: str, make: Callable[[], Any]) -> Any:
        """``make()``, computed once for this model and kept with it: what is derived from the model alone (its
        trackers' watches ask for the same figures for every run it tracks). A model is never changed in place;
        a changed one is a copy (:meth:`with_changes`) that derives its own."""
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    # ----------------------------------------------------------------- bases
    def pixel_basis(self) -> np.ndarray:
        """``(n, P+1)`` Legendre polynomials of the scaled pixel index."""
        if "pixel" not in self._cache:
            u = np.arange(self.n_pixels, dtype=np.float64)
            self._cache["pixel"] = legendre_basis(scaled(u, 0, self.n_pixels - 1), self.pixel_degree)
        return self._cache["pixel"]

    def row_basis(self) -> np.ndarray:
        """``(R, J+1)`` Legendre polynomials of the scaled row index."""
        if "row" not in self._cache:
            r = np.arange(self.n_rows, dtype=np.float64)
            self._cache["row"] = legendre_basis(scaled(r, 0, self.n_rows - 1), self.row_degree)
        return self._cache["row"]

    def stroke_basis(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(K, L+1)`` Legendre polynomials of the scaled stroke position, and their d/dx."""
        lo, hi = self.stroke_range_mm
        s = scaled(x_mm, lo, hi)
        values = legendre_basis(s, self.stroke_degree)
        if self.stroke_degree == 0:
            return values, np.zeros_like(values)
        dvalues = np.polynomial.legendre.legder(np.eye(self.stroke_degree + 1), axis=0)  # (L, L+1)
        slopes = legendre_basis(s, self.stroke_degree - 1) @ dvalues * (2.0 / (hi - lo))
        return values, slopes

    def target_offset(self) -> np.ndarray:
        """``(R, n)``: target coordinate seen by each pixel relative to pixel 0 of the centre row."""
        if "offset" not in self._cache:
            u = np.arange(self.n_pixels, dtype=np.float64)
            r = np.arange(self.n_rows, dtype=np.float64) - (self.n_rows - 1) / 2.0
            self._cache["offset"] = self.pixel_pitch_mm * u[None, :] + self.row_shift_mm * r[:, None]
        return self._cache["offset"]

    def phase(self, x_mm: np.ndarray) -> np.ndarray:
        """``(K, R, n)`` target phase θ seen by each pixel at frame positions ``x_mm``."""
        x_mm = _positions(x_mm)
        return (TWO_PI / self.period_mm) * (x_mm[:, None, None] + self.target_offset()[None])

    def trig(self, x_mm: np.ndarray) -> np.ndarray:
        """``(K, R, n, 2M+1)`` trig terms of the target phase at ``x_mm``.

        Cached for the last position array (held by reference, compared by identity) when small
        enough: fitting evaluates them again and again for the same frames and geometry.
        """
        cached = self._cache.get("trig")
        if cached is not None and cached[0] is x_mm:
            return cached[1]
        values = trig_basis(self.phase(x_mm), self.harmonics)
        if values.size <= _TRIG_CACHE_ELEMENTS:
            self._cache["trig"] = (x_mm, values)
        return values

    # ----------------------------------------------------------------- evaluation
    def _require_coeffs(self) -> np.ndarray:
        if self.coeffs is None:
            raise ModelError("the model has no coefficients yet: calibrate it first")
        return self.coeffs

    def spatial_weights(self) -> np.ndarray:
        """``(R, n, A, L+1)``: coefficient of trig term a and stroke polynomial l at each pixel."""
        if "weights" not in self._cache:
            coeffs = self._require_coeffs()
            self._cache["weights"] = np.einsum("aijl,ui,rj->rual", coeffs, self.pixel_basis(), self.row_basis())
        return self._cache["weights"]

    def noise(self) -> PixelNoise:
        """The sample noise model: the fitted photon-transfer curve, else one σ for every sample."""
        return self.pixel_noise if self.pixel_noise is not None else PixelNoise.constant(self.noise_gray or 1.0)

    def inverse_variance(self, gray: np.ndarray) -> np.ndarray:
        """1/σ² (gray⁻²) of samples ``(…, R, n)`` whose expected values are ``gray``, zero on masked pixels."""
        weights = 1.0 / self.noise().variance(gray)
        return weights if self.pixel_weight is None else weights * self.pixel_weight

    def seen(self) -> np.ndarray | float:
        """``(R, n)`` 1 where the model describes the pixel, 0 where it is masked (1.0: no mask).
        A shared (row-averaged) model masks a bad pixel's whole column."""
        return 1.0 if self.pixel_weight is None else (self.pixel_weight > 0).astype(np.float64)

    def response(self) -> tuple[np.ndarray | float, np.ndarray | float]:
        """Per-pixel gain and offset. A masked pixel (``pixel_weight`` 0) has both 0: it reads 0
        with no slope, as :meth:`prepare` makes its frames read, so every solver, weighted or
        not, sees it carry no position and no residual."""
        gain = self.pixel_gain if self.pixel_gain is not None else 1.0
        offset = self.pixel_offset if self.pixel_offset is not None else 0.0
        if self.pixel_weight is not None:
            gain, offset = gain * self.seen(), offset * self.seen()
        return gain, offset

    def frame_weights(self, stroke: np.ndarray) -> np.ndarray:
        """W_a(u, r, x_k) at the frames whose stroke polynomials are ``stroke`` ``(K, L+1)``: ``(K, R, n, A)``, or
        ``(R, n, A)`` when they are the same on every frame (no stroke terms, P_0 = 1): the pixels' own, summed
        against directly by :meth:`sum_terms` rather than copied for each frame (the same products and sums,
        the same bits, a fifth of the time on a 16-row strip's 300 frames)."""
        if stroke.shape[1] == 1 and (stroke == 1.0).all():
            return self.spatial_weights()[..., 0]
        return np.einsum("rual,kl->krua", self.spatial_weights(), stroke)

    @staticmethod
    def sum_terms(terms: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """``(K, R, n)``: Σ_a terms[k, r, u, a] · weights (:meth:`frame_weights`)."""
        return np.einsum("krua,rua->kru" if weights.ndim == 3 else "krua,krua->kru", terms, weights)

    @overload
    def predict(self, x_mm: np.ndarray, with_derivative: Literal[False] = False,
                with_response: bool = True) -> np.ndarray: ...

    @overload
    def predict(self, x_mm: np.ndarray, with_derivative: Literal[True],
                with_response: bool = True) -> tuple[np.ndarray, np.ndarray]: ...

    def predict(self, x_mm: np.ndarray, with_derivative: bool = False,
                with_response: bool = True) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Gray values ``(K, R, n)`` at positions ``x_mm`` (and ∂Y/∂x when asked), unit common mode.

        ``with_response=False`` gives the smooth part S alone, before the per-pixel flat field.
        """
        x_mm = _positions(x_mm)
        trig = self.trig(x_mm)  # (K, R, n, A)
        stroke, dstroke = self.stroke_basis(x_mm)  # (K, L+1)
        gain, offset = self.response() if with_response else (1.0, 0.0)
        weights = self.frame_weights(stroke)
        smooth = self.sum_terms(trig, weights)
        use_map = with_response and self.target_map is not None
        factor, dfactor = self.target_factor(x_mm) if use_map else (1.0, 0.0)
        values = smooth * factor * gain + offset
        if not with_derivative:
            return self.clip(values) if with_response else values
        dtrig = trig_derivative(trig, self.harmonics) * (TWO_PI / self.period_mm)
        slope = self.sum_terms(dtrig, weights)
        if self.stroke_degree:
            slope += np.einsum("krua,rual,kl->kru", trig, self.spatial_weights(), dstroke)
        if use_map:
            slope = slope * factor + smooth * dfactor
        if with_response and self.clip_gray is not None:
            return self.clip_with_slope(values, slope * gain)
        return values, slope * gain

    def target_coordinate(self, x_mm: np.ndarray) -> np.ndarray:
        """``(K, R, n)``: where on the target each pixel looks at frame positions ``x_mm``."""
        return _positions(x_mm)[:, None, None] + self.target_offset()[None]

    def target_factor(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(K, R, n)``: 1 + m(x_w) and its derivative along x (piecewise linear; 1 outside the mapped range)."""
        target_map = self.target_map
        if target_map is None:
            raise ValueError("the model has no target map: its factor is 1 everywhere")
        position = (self.target_coordinate(x_mm) - self.target_map_origin_mm) / self.target_map_step_mm
        map_row = np.arange(target_map.shape[0])[:, None]  # (R|1, 1): a row's own map, or the one map
        factor, rise = map_lookup(target_map, map_row, position)
        return factor, rise / self.target_map_step_mm

    @property
    def fitted_parameters(self) -> int:
        """Numbers the calibration fitted once for all frames (coefficients, flat field, target map):
        what a calibration's in-sample χ² is lowered by, and a new frame's χ² is not."""
        count = self.n_coeffs
        if self.pixel_gain is not None:
            count += 2 * self.n_rows * self.n_pixels
        if self.target_map is not None:
            count += self.target_map.size
        return count

    def out_of_sample(self, chi2: float, n_samples: float) -> float:
        """The χ² a new frame shows where the calibration's own frames showed ``chi2`` over
        ``n_samples``: least squares leaves σ²(1 − p/N) on the data it fitted and its estimate errs by
        σ²·p/N on new data, so the level is (1 + p/N)/(1 − p/N) higher (3 % for a 16-row map of a lab
        strip, 0.15 % for the seed paper's model on 600 frames)."""
        share = min(self.fitted_parameters / max(float(n_samples), 1.0), 0.5)
        return float(chi2) * (1.0 + share) / (1.0 - share)

    @property
    def map_rows(self) -> int:
        """Rows of the target map: 1 (shared by the rows), ``n_rows`` (one per row), 0 without a map."""
        return 0 if self.target_map is None else self.target_map.shape[0]

    def clip(self, values: np.ndarray) -> np.ndarray:
        return values if self.clip_gray is None else np.clip(values, *self.clip_gray)

    def clip_with_slope(self, values: np.ndarray, slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Saturated pixels: the value sticks at the limit and carries no slope."""
        if self.clip_gray is None:
            return values, slopes
        lo, hi = self.clip_gray
        inside = (values > lo) & (values < hi)
        return np.clip(values, lo, hi), np.where(inside, slopes, 0.0)

    def prepare(self, frames: np.ndarray) -> np.ndarray:
        """Frames ``(K, n)`` or ``(K, R, n)`` as float64 ``(K, R_model, n)``.

        A model that describes the rows jointly (``n_rows`` = 1) sees the row mean: for rows that
        agree, averaging is the sufficient statistic and costs R times less than fitting every row.
        """
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim == 2:
            frames = frames[:, None, :]
        if frames.ndim != 3 or frames.shape[-1] != self.n_pixels:
            raise TrackingError(
                f"frames have shape {frames.shape}; the model was calibrated for {self.n_pixels} pixels"
            )
        if self.n_rows == 1:  # (one row needs no averaging: live tracking prepares frames one at a time)
            frames = frames if frames.shape[1] == 1 else frames.mean(axis=1, keepdims=True)
        elif frames.shape[1] != self.n_rows:
            raise TrackingError(f"frames have {frames.shape[1]} rows; the model was calibrated for {self.n_rows}")
        return frames if self.pixel_weight is None else frames * self.seen()

    def rows_averaged(self, frames_rows: int) -> int:
        """How many raw rows feed each model row (noise drops by its square root)."""
        return frames_rows if self.n_rows == 1 else 1

    # ----------------------------------------------------------------- reporting
    def describe(self) -> str:
        parts = [f"M={self.harmonics}", f"P={self.pixel_degree}"]
        if self.stroke_degree:
            parts.append(f"stroke degree {self.stroke_degree}")
        if self.n_rows > 1:
            parts.append(f"{self.n_rows} rows, shift {self.row_shift_mm * 1e3:.2f} µm/row")
        if self.pixel_gain is not None:
            parts.append("flat field")
        if self.common_mode:
            parts.append("per-frame gain/offset")
        if self.target_map is not None:
            per_row = f"{self.map_rows} rows × " if self.map_rows > 1 else ""
            parts.append(f"target map {per_row}{self.target_map.shape[1]} × {self.target_map_step_mm * 1e3:.0f} µm")
        if self.pixel_weight is not None and (self.pixel_weight == 0).any():
            parts.append(f"{int((self.pixel_weight == 0).sum())} pixel(s) masked")
        if self.clip_gray is not None:
            parts.append(f"clipped at {self.clip_gray[0]:g}..{self.clip_gray[1]:g}")
        if self.info.get("repeated_frames"):
            parts.append(f"{self.info['repeated_frames']} repeated image(s) left out of calibration")
        if self.info.get("row_offset_gray"):  # (core/adequacy.py row_offset_gray)
            parts.append(f"row banding {float(self.info['row_offset_gray']):.2f} gray taken out")
        if self.info.get("frame_offset_gray"):  # (core/adequacy.py frame_offset_gray)
            parts.append(f"an offset of {float(self.info['frame_offset_gray']):.2f} gray drawn each frame taken out")
        if self.info.get("light_profile"):  # (core/adequacy.py light_profile)
            gain = [float(g) for g in self.info["light_profile"]["gain"]]
            parts.append(f"the light along the stroke within {100 * (max(gain) - min(gain)):.1f} %")
        if (mapped := (self.info.get("estimator_error_profile") or {}).get("map")):  # (estimator/filter.py error_map)
            parts.append(f"the image's place mapped along the stroke within "
                         f"{1e3 * (max(mapped['error_mm']) - min(mapped['error_mm'])):.1f} µm")
        if self.info.get("frame_gain_rate"):  # (core/adequacy.py frame_gain_rate)
            parts.append(f"the gain walking {100 * float(self.info['frame_gain_rate']):.1f} %/√s from frame to frame")
        if float(self.info.get("frame_chi2_spread") or 1.0) > 1.0:  # (core/chi2_curve.py frame_spread)
            parts.append(f"noise shared between samples: χ² spread {float(self.info['frame_chi2_spread']):.1f}x")
        return f"{self.name} ({', '.join(parts)}; τ={self.period_mm:.4f} mm, α·d={self.pixel_pitch_mm:.5f} mm)"

    def ideal_parameters(self) -> dict[str, float]:
        """A, φ, D of the fundamental at pixel 0 (the ideal model's own parameters)."""
        coeffs = self._require_coeffs()
        weights = self.spatial_weights()[(self.n_rows - 1) // 2, 0, :, 0]
        a1, b1 = weights[1], weights[2]
        return {"A": float(math.hypot(a1, b1)), "phi": float(math.atan2(b1, a1)), "D": float(weights[0]),
                "tau_w": self.period_mm, "alpha_d": self.pixel_pitch_mm, "n_coeffs": int(coeffs.size)}
