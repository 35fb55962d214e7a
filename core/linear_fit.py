"""Least squares for the linear coefficients of a :class:`FourierModel` at fixed geometry.

The design matrix has one row per (frame, row, pixel) and one column per coefficient: 10⁵–10⁶ rows
by ~50 columns. It is never formed. Its columns are products T_a(θ)·P_l(x) × P_i(u)·P_j(r), so
the normal matrix is accumulated per (row, pixel) over frames, then contracted with the
pixel and row polynomials: O(K·R·n·(A·L)²) work, a few milliseconds for the paper's rig.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from graytrack.core import kernels
from graytrack.core.basis import trig_derivative
from graytrack.core.models.fourier import TWO_PI, FourierModel

_CHUNK_ELEMENTS = 2_000_000
_WELL_CONDITIONED = 1e-10  # smallest/largest Cholesky pivot below which the eigen route takes over


@dataclass
class LinearSystem:
    """Normal equations G c = h of the model's linear part; c is in (a, l, i, j) order.

    The factorisation is computed once and reused: variable projection solves the same G for the
    data and for each geometry direction it projects.
    """

    gram: np.ndarray
    rhs: np.ndarray
    shape_alij: tuple[int, int, int, int]
    _solver: Callable[[np.ndarray], np.ndarray] | None = field(default=None, repr=False)

    def solve(self, rhs: np.ndarray | None = None) -> np.ndarray:
        """Coefficients in the model's (a, i, j, l) layout; rank-deficient directions set to 0.

        ``rhs`` replaces the data's right-hand side (projections of other vectors on the span).
        """
        if self._solver is None:
            self._solver = self._factorise()
        solution = self._solver(self.rhs if rhs is None else rhs)
        return solution.reshape(self.shape_alij).transpose(0, 2, 3, 1)

    def _factorise(self) -> Callable[[np.ndarray], np.ndarray]:
        """Cholesky of the scaled G when it is well conditioned, else an eigen-decomposition that
        drops the directions the data do not determine."""
        scale = np.sqrt(np.maximum(np.diag(self.gram), 1e-300))
        normalised = self.gram / np.outer(scale, scale)
        try:
            factor = cho_factor(normalised, lower=True, check_finite=False)
            pivots = np.diag(factor[0]) ** 2
            if pivots.min() > pivots.max() * _WELL_CONDITIONED:
                return lambda rhs: cho_solve(factor, rhs / scale, check_finite=False) / scale
        except LinAlgError:
            pass
        values, vectors = np.linalg.eigh(normalised)
        keep = values > values.max() * 1e-12
        basis, inverse = vectors[:, keep], 1.0 / values[keep]
        return lambda rhs: (basis @ ((basis.T @ (rhs / scale)) * inverse)) / scale


def _frame_chunks(model: FourierModel, n_frames: int) -> list[slice]:
    per_frame = model.n_rows * model.n_pixels * model.n_trig * (model.stroke_degree + 1)
    size = max(1, _CHUNK_ELEMENTS // max(per_frame, 1))
    return [slice(start, min(start + size, n_frames)) for start in range(0, n_frames, size)]


def _positions(x_mm: np.ndarray, part: slice) -> np.ndarray:
    """The chunk's positions; the array itself when the chunk is everything (keeps the model's
    cached trig terms, which are keyed on the array's identity)."""
    return x_mm if part.start == 0 and part.stop == len(x_mm) else x_mm[part]


def _trig_stroke(model: FourierModel, x_mm: np.ndarray) -> np.ndarray:
    """``(K, R, n, A·L)``: trig terms times stroke polynomials, the frame-dependent factor."""
    trig = model.trig(x_mm)
    stroke, _ = model.stroke_basis(x_mm)
    if stroke.shape[1] == 1 and (stroke == 1.0).all():  # no stroke terms, P_0 = 1: the product is trig itself
        return trig  # (its callers only read it; a copy cost a pass over every sample at each fit)
    product = trig[..., :, None] * stroke[:, None, None, None, :]
    return product.reshape(trig.shape[:3] + (-1,))


def project_columns(model: FourierModel, x_mm: np.ndarray, values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Φᵀ·W·v for data-shaped arrays ``values`` ``(K, R, n, m)``: ``(m, A·L·I·J)``."""
    pixel, row = model.pixel_basis(), model.row_basis()
    acc = np.zeros(())  # the chunks' sums add onto it (broadcast to the first one's shape)
    for part in _frame_chunks(model, len(x_mm)):
        frame_factor = _trig_stroke(model, _positions(x_mm, part))
        acc = acc + np.einsum("krup,krum,kru->rupm", frame_factor, values[part], weights[part], optimize=True)
    return np.einsum("rupm,ui,rj->mpij", acc, pixel, row, optimize=True).reshape(values.shape[-1], -1)


def normal_equations(model: FourierModel, x_mm: np.ndarray, data: np.ndarray, weights: np.ndarray) -> LinearSystem:
    """Accumulate G and h for data ``(K, R, n)`` (already divided by any response) with weights.

    Per (row, pixel), the frames are summed (:func:`_frame_sums`); the pixel and row polynomials
    then enter through one more product with their outer products.
    """
    n_al = model.n_trig * (model.stroke_degree + 1)
    gram_ru = np.zeros((model.n_rows, model.n_pixels, n_al, n_al))
    rhs_ru = np.zeros((model.n_rows, model.n_pixels, n_al))
    gram_p, rhs_p = gram_ru.reshape(-1, n_al, n_al), rhs_ru.reshape(-1, n_al)  # views, one sample a row
    for part in _frame_chunks(model, len(x_mm)):
        frame_factor = _trig_stroke(model, _positions(x_mm, part))
        n_frames = frame_factor.shape[0]
        _frame_sums(frame_factor.reshape(n_frames, -1, n_al), weights[part].reshape(n_frames, -1),
                    np.asarray(data[part], dtype=np.float64).reshape(n_frames, -1), gram_p, rhs_p)
    spatial = np.einsum("ui,rj->ruij", model.pixel_basis(), model.row_basis()).reshape(model.n_rows, model.n_pixels, -1)
    n_ij = spatial.shape[-1]
    outer = np.einsum("rua,rub->ruab", spatial, spatial).reshape(-1, n_ij * n_ij)  # (R·n, IJ·IJ)
    gram = (gram_ru.reshape(-1, n_al * n_al).T @ outer).reshape(n_al, n_al, n_ij, n_ij)
    gram = gram.transpose(0, 2, 1, 3).reshape(n_al * n_ij, n_al * n_ij)
    rhs = np.einsum("rup,rua->pa", rhs_ru, spatial).reshape(-1)
    shape_alij = (model.n_trig, model.stroke_degree + 1, model.pixel_degree + 1, model.row_degree + 1)
    return LinearSystem(gram, rhs, shape_alij)


# Samples (pixels of one frame) whose sums the compiled frame sums keep together: (A·L)² · 64 doubles, ~60 KB for
# the paper's 11 terms, stay in the second-level cache while the frames pass, and the pixel loop is vectorised.
SUM_BLOCK = 64


def _frame_sums_loop(factor: np.ndarray, weights: np.ndarray, data: np.ndarray, gram: np.ndarray,
                     rhs: np.ndarray) -> None:
    """``gram[p] += Σ_k w f fᵀ`` and ``rhs[p] += Σ_k w f d`` for the samples p, over the frames k of ``factor``
    ``(K, P, A·L)`` (``weights``, ``data`` ``(K, P)``): frame after frame over a block of samples, the upper
    triangle summed and mirrored."""
    n_frames, n_samples, n_terms = factor.shape
    acc = np.empty((n_terms, n_terms, SUM_BLOCK))
    acc_rhs = np.empty((n_terms, SUM_BLOCK))
    weighted = np.empty((n_terms, SUM_BLOCK))
    for start in range(0, n_samples, SUM_BLOCK):
        size = min(SUM_BLOCK, n_samples - start)
        acc[:] = 0.0
        acc_rhs[:] = 0.0
        for k in range(n_frames):
            for a in range(n_terms):
                for q in range(size):
                    weighted[a, q] = factor[k, start + q, a] * weights[k, start + q]
            for a in range(n_terms):
                for q in range(size):
                    acc_rhs[a, q] += weighted[a, q] * data[k, start + q]
                for b in range(a, n_terms):
                    for q in range(size):
                        acc[a, b, q] += weighted[a, q] * factor[k, start + q, b]
        for q in range(size):
            for a in range(n_terms):
                rhs[start + q, a] += acc_rhs[a, q]
                for b in range(a, n_terms):
                    gram[start + q, a, b] += acc[a, b, q]
                    if b != a:
                        gram[start + q, b, a] += acc[a, b, q]


def _frame_sums_numpy(factor: np.ndarray, weights: np.ndarray, data: np.ndarray, gram: np.ndarray,
                      rhs: np.ndarray) -> None:
    """:func:`_frame_sums_loop` by numpy's batched matrix products (without numba, or with
    ``GRAYTRACK_KERNEL=numpy``); the same sums to rounding (tests/core/test_linear_fit.py)."""
    per_sample = np.moveaxis(factor, 0, 1)  # (P, K, A·L)
    weighted = per_sample * weights.T[..., None]
    gram += np.matmul(np.swapaxes(weighted, -1, -2), per_sample)
    rhs += np.matmul(np.swapaxes(weighted, -1, -2), data.T[..., None])[..., 0]


# The sums over the frames compiled (cached on disk next to this file), for the trig terms as the model keeps them
# (term-major: each term contiguous over the samples), which numpy's products cannot hand to BLAS: 3x faster there
# (41 against 125 ms for 300 frames of 1,600 samples and 11 terms). With stroke terms the factor is a product with
# the terms contiguous, which BLAS takes faster than the loop (122 against 260 ms with 33 terms): numpy's products.
_compiled_frame_sums = kernels.numba.njit(cache=True, nogil=True)(_frame_sums_loop) if kernels.COMPILED else None


def _frame_sums(factor: np.ndarray, weights: np.ndarray, data: np.ndarray, gram: np.ndarray, rhs: np.ndarray) -> None:
    """:func:`_frame_sums_loop` compiled on term-major factors, numpy's products on the others."""
    if _compiled_frame_sums is not None and factor.strides[-1] != factor.itemsize:
        _compiled_frame_sums(factor, weights, data, gram, rhs)
    else:
        _frame_sums_numpy(factor, weights, data, gram, rhs)


def fit_coefficients(model: FourierModel, x_mm: np.ndarray, data: np.ndarray,
                     weights: np.ndarray) -> tuple[FourierModel, LinearSystem]:
    """The model with its least-squares coefficients for ``data`` at ``x_mm``, and its normal equations."""
    system = normal_equations(model, x_mm, data, weights)
    return model.with_changes(coeffs=system.solve()), system


def phase_slope(model: FourierModel, x_mm: np.ndarray) -> np.ndarray:
    """∂S/∂θ at the model's coefficients, ``(K, R, n)``: the direction every phase parameter moves."""
    trig = model.trig(x_mm)
    stroke, _ = model.stroke_basis(x_mm)
    return model.sum_terms(trig_derivative(trig, model.harmonics), model.frame_weights(stroke))


def geometry_sensitivities(model: FourierModel, x_mm: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """∂S/∂(geometry parameter) at fixed coefficients, ``(K, R, n, len(names))``."""
    dphase = phase_slope(model, x_mm)
    out = []
    for name in names:
        if name == "period_mm":
            factor = -model.phase(x_mm) / model.period_mm
        elif name == "pixel_pitch_mm":
            factor = (TWO_PI / model.period_mm) * np.arange(model.n_pixels, dtype=np.float64)[None, None, :]
        elif name == "row_shift_mm":
            rows = np.arange(model.n_rows, dtype=np.float64) - (model.n_rows - 1) / 2.0
            factor = (TWO_PI / model.period_mm) * rows[None, :, None]
        else:
            raise ValueError(f"unknown geometry parameter {name}")
        out.append(dphase * factor)
    return np.stack(out, axis=-1)
