"""Small weighted regressions shared by fitting and diagnosis."""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve


def weighted_affine(target: np.ndarray, regressor: np.ndarray, weights: np.ndarray,
                    axis: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Per-slice weighted least squares target ≈ a·regressor + b over ``axis``: returns (a, b).

    One gain and offset per pixel (summing over frames) or per frame (summing over pixels): the
    flat field, the common mode, and the probes that look for them.
    """
    sw = weights.sum(axis=axis)
    mean_x = (weights * regressor).sum(axis=axis) / np.maximum(sw, 1e-300)
    mean_y = (weights * target).sum(axis=axis) / np.maximum(sw, 1e-300)
    dx = regressor - np.expand_dims(mean_x, axis)
    dy = target - np.expand_dims(mean_y, axis)
    slope = (weights * dx * dy).sum(axis=axis) / np.maximum((weights * dx * dx).sum(axis=axis), 1e-300)
    return slope, mean_y - slope * mean_x


# Largest condition number of the scaled Gram matrix (columns to unit norm) for which tall_least_squares solves
# the normal equations: their coefficients then differ from an orthogonal factorisation's by at most about this
# times the double rounding (1e4 · 2.2e-16 ≈ 2e-12, relative); a worse-conditioned basis goes to numpy's lstsq.
NORMAL_EQUATIONS_COND = 1e4


def tall_least_squares(basis: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The coefficients c minimising ‖basis·c − values‖ for a tall ``basis`` ``(N, p)``, N ≫ p.

    ``numpy.linalg.lstsq`` factorises the whole basis (a QR, then an SVD): on the closed loop's probes, 480,000
    samples by 12-33 columns, ~0.1-0.4 s a call. Their bases are near-orthogonal once their columns are scaled
    (conditions 1.5-35): then the normal equations, one product of the basis with itself and a p×p Cholesky, give
    the same coefficients (to ~1e-14 on those probes) in a fifth to a tenth of the time. A basis with a zero or
    nearly dependent column is left to lstsq (its minimum-norm answer)."""
    gram = basis.T @ basis
    scale = np.sqrt(np.diag(gram))
    if scale.size and scale.min() > 0.0 and np.isfinite(gram).all():
        normalised = gram / np.outer(scale, scale)
        eigenvalues = np.linalg.eigvalsh(normalised)
        if eigenvalues[0] > eigenvalues[-1] / NORMAL_EQUATIONS_COND:
            factor = cho_factor(normalised, lower=True, check_finite=False)
            per_row = scale.reshape((-1,) + (1,) * (np.ndim(values) - 1))  # one value or several right-hand sides
            return cho_solve(factor, (basis.T @ values) / per_row, check_finite=False) / per_row
    coef, *_ = np.linalg.lstsq(basis, values, rcond=None)
    return coef
