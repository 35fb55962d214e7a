"""Evaluating a calibrated model at trial positions, as fast as the model's structure allows.

The tracker asks for F(x) and ∂F/∂x at one or a few positions many times per frame, so the model's
coefficients are folded once into complex weights per harmonic: an evaluation is then a handful of
scalar powers times a small matrix, with no sine or cosine of a pixel array.
"""

from __future__ import annotations

import numpy as np

from graytrack.core.models.fourier import TWO_PI, FourierModel


class ClippedHarmonics:
    """Wraps an evaluator so that saturated pixels stick at the limit with zero slope."""

    def __init__(self, inner: "FastHarmonics | GeneralHarmonics", model: FourierModel):
        self.inner, self.model = inner, model

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.model.clip_with_slope(*self.inner.evaluate(x_mm))


class FastHarmonics:
    """F(x) and ∂F/∂x without a single sine of a pixel array: O(L·M·R·n) per call.

    Every pixel's Fourier series is folded into complex weights V_{l,h} (pixel offsets and flat
    field included), one set per stroke polynomial l; an evaluation is z^h (M scalars) and the
    stroke polynomials (L scalars) times V.
    """

    def __init__(self, model: FourierModel):
        weights = model.spatial_weights()  # (R, n, A, L)
        gain, offset = model.response()
        gain = np.broadcast_to(np.asarray(gain, dtype=np.float64), weights.shape[:2])
        harmonics = np.arange(1, model.harmonics + 1)
        shift = np.exp(1j * TWO_PI / model.period_mm * model.target_offset()[..., None] * harmonics)  # (R, n, M)
        sin_c, cos_c = weights[..., 1::2, :], weights[..., 2::2, :]  # (R, n, M, L)
        folded = (cos_c - 1j * sin_c) * (shift * gain[..., None])[..., None]
        n_values = weights.shape[0] * weights.shape[1]
        self.model = model
        self.period_mm = model.period_mm
        self.harmonics = harmonics
        self.offset = np.broadcast_to(np.asarray(offset, dtype=np.float64), weights.shape[:2]).reshape(-1)
        self.constants = (gain[..., None] * weights[..., 0, :]).reshape(n_values, -1).T.copy()  # (L, P)
        self.vs = folded.reshape(n_values, model.harmonics, -1).transpose(2, 1, 0).copy()  # (L, M, P)
        # The stroke-independent case, as the fast tracking path reads it:
        self.constant = self.constants[0] + self.offset
        self.v = self.vs[0]
        self.dv = self.v * (1j * TWO_PI / model.period_mm * harmonics)[:, None]

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values and slopes ``(G, P)`` at positions ``x_mm`` ``(G,)``."""
        x_mm = np.asarray(x_mm, dtype=np.float64)
        z = np.exp(1j * TWO_PI / self.period_mm * np.outer(x_mm, self.harmonics))  # (G, M)
        if self.vs.shape[0] == 1:
            return self.constant + (z @ self.v).real, (z @ self.dv).real
        stroke, dstroke = self.model.stroke_basis(x_mm)  # (G, L)
        dz = z * (1j * TWO_PI / self.period_mm * self.harmonics)
        base = self.constants[None] + np.einsum("gm,lmp->glp", z, self.vs).real
        turning = np.einsum("gm,lmp->glp", dz, self.vs).real
        values = self.offset + np.einsum("gl,glp->gp", stroke, base)
        slopes = np.einsum("gl,glp->gp", stroke, turning) + np.einsum("gl,glp->gp", dstroke, base)
        return values, slopes


class GeneralHarmonics:
    """Fallback for models with a target map: the model's own predict."""

    def __init__(self, model: FourierModel):
        self.model = model

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values, slopes = self.model.predict(np.asarray(x_mm), with_derivative=True)
        return values.reshape(len(x_mm), -1), slopes.reshape(len(x_mm), -1)


class TrigTables:
    """Model-level tables of the fast tracking path: per pixel, F_p, F_p² and F′_p² as trig
    polynomials in x of degree 2M (coefficients of z^0..z^2M, z = exp(iωx)).

    A weighted moment Σ_p w_p·F_p(x)² is then (w @ table) evaluated at z: per-frame weights cost
    one matrix product, the same reduction as the frame itself. Derivatives in x multiply the
    coefficient of z^m by iωm, so F′·F, F′·1 and y·F′ need no table of their own.
    """

    def __init__(self, fast: FastHarmonics, model: FourierModel):
        self.fast = fast
        self.degree = 2 * model.harmonics
        n_pixels = fast.constant.size
        width = self.degree + 1
        self.phase_orders = 1j * (TWO_PI / model.period_mm) * np.arange(width)  # iωm: z^m = exp(iωm·x)
        line = np.zeros((n_pixels, width), dtype=complex)
        line[:, 0] = fast.constant
        line[:, 1:model.harmonics + 1] = fast.v.T
        self._line, self._harmonics = line, model.harmonics
        # y·F's coefficients of z^0..z^M and a column of ones for y·1: one real product per frame,
        # stored as interleaved (re, im) pairs so that the product views as complex without a copy.
        # F has no power of z beyond M and y·F′ is y·F times iωm (:meth:`linear_rows`): the product
        # reads 2(M+2) numbers a pixel, not the 4(2M+1)+2 of all seven rows' columns (a 16 × 100
        # frame: 18 -> 9 µs, its table then fits the second-level cache).
        linear = np.concatenate([line[:, :model.harmonics + 1], np.ones((n_pixels, 1))], axis=1)
        self.linear = np.ascontiguousarray(linear).view(np.float64)
        n_samples = 2 * self.degree + 4
        x = np.arange(n_samples) * model.period_mm / n_samples
        values, slopes = fast.evaluate(x)  # (N, P)
        squares = [_trig_coefficients(sampled, self.degree) for sampled in (values**2, slopes**2)]
        self._gram = np.concatenate([squares[0], squares[1], line], axis=1)  # (P, 3·(D+1))
        # The same table as real and imaginary parts, one row each: real weights fold in by a real
        # product over contiguous rows (a complex one would first turn the weights complex and do
        # 4x the work; 59 -> 35 µs a 16 x 128 frame, rows contiguous 24 µs).
        self._gram_rows = np.ascontiguousarray(np.ascontiguousarray(self._gram).view(np.float64).T)  # (6·(D+1), P)

    def linear_rows(self, products: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The y·F and y·F′ rows ``(K, 2, D+1)`` of the moments from ``products`` ``(K, M+2)``
        (complex: weighted frames times :attr:`linear`; its last column is y·1). ``out``: rows to
        write into, zero beyond z^M (written once, never touched here)."""
        used = self._harmonics + 1
        if out is None:
            out = np.zeros((products.shape[0], 2, self.degree + 1), dtype=complex)
        out[:, 0, :used] = products[:, :used]
        np.multiply(products[:, :used], self.phase_orders[:used], out=out[:, 1, :used])
        return out

    def values_at(self, x_mm: float, pixels: np.ndarray | None = None) -> np.ndarray:
        """F(x) at one position, of every pixel ``(P,)`` or of ``pixels``: M powers of z times the
        folded weights."""
        line = self._line if pixels is None else self._line[pixels]
        return line[:, 0].real + (line[:, 1:self._harmonics + 1] @ np.exp(
            self.phase_orders[1:self._harmonics + 1] * x_mm)).real

    def line_coefficients(self, pixels: np.ndarray) -> list[list[complex]]:
        """F of each of ``pixels`` as Python coefficients of z^0..z^M (Re Σ c_h z^h): for
        evaluating a few pixels in scalar code."""
        return self._line[pixels, : self._harmonics + 1].tolist()

    def weighted_gram(self, weights: np.ndarray) -> np.ndarray:
        """``(K, 5, D+1)``: coefficients of F·F, F′·F, F′·F′, F·1, F′·1 under weights ``(K, P)``."""
        width = self.degree + 1
        parts = self._gram_rows @ np.asarray(weights, dtype=np.float64).T  # (6·(D+1), K)
        folded = np.ascontiguousarray(parts.T).view(complex).reshape(weights.shape[0], 3, width)
        out = np.empty((weights.shape[0], 5, width), dtype=complex)
        out[:, 0] = folded[:, 0]
        out[:, 1] = 0.5 * folded[:, 0] * self.phase_orders  # F′·F = ½ d(F·F)/dx
        out[:, 2] = folded[:, 1]
        out[:, 3] = folded[:, 2]
        out[:, 4] = folded[:, 2] * self.phase_orders
        return out


def _trig_coefficients(sampled: np.ndarray, degree: int) -> np.ndarray:
    """``(P, degree+1)`` coefficients c_m with f(x) = Re Σ c_m z^m, from samples ``(N, P)`` over one period."""
    spectrum = np.fft.fft(sampled, axis=0) / sampled.shape[0]
    coeffs = 2.0 * spectrum[: degree + 1]
    coeffs[0] = spectrum[0].real
    return coeffs.T.copy()
