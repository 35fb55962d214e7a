"""The noise floor: per-pixel gray noise from the data itself, and the Cramér–Rao bound.

An error figure means little without the floor the same data allow, so every figure graytrack
reports stands next to this bound. σ is estimated without any model: a model's residual mixes
noise with whatever the model misses, which would make a poor model look noise-limited.
"""

from __future__ import annotations

import numpy as np

from graytrack.core.errors import GraytrackError

_MAD_TO_SIGMA = 1.4826
# Second temporal difference y[k+1] − 2 y[k] + y[k−1] of white noise has variance 6σ².
_SECOND_DIFF_GAIN = np.sqrt(6.0)
# Frames whose second differences are exactly zero this often are quantised coarser than their noise.
_QUANTISED_ZERO_FRACTION = 0.2
# Share of a Gaussian's variance left after dropping its 1 % largest squares (|z| > 2.576).
_GAUSS_TRIMMED_VARIANCE = 0.9155


def estimate_sigma(frames: np.ndarray, reference: np.ndarray | None = None, period_mm: float | None = None) -> float:
    """Per-pixel gray-level noise σ of frames ``(K, n)`` or ``(K, R, n)``.

    Uses second differences along time, where a slowly moving target contributes almost nothing
    (F''·Δx²), after removing from each difference frame an affine function of the gray level:
    that takes out common-mode gain and offset changes (flicker, exposure drift), which are not
    pixel noise. Frames that moved more than 2 % of a period between neighbours are skipped when
    the reference allows telling. A robust (MAD) scale keeps defects and outliers from counting,
    except for coarsely quantised frames, where a trimmed variance takes over.
    """
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim == 2:
        frames = frames[:, None, :]
    if frames.shape[0] < 3:
        raise GraytrackError("need at least 3 frames to estimate the noise")
    n_frames = frames.shape[0]
    flat = frames.reshape(n_frames, -1)
    second = flat[2:] - 2.0 * flat[1:-1] + flat[:-2]
    keep = np.ones(n_frames - 2, dtype=bool)
    if reference is not None and period_mm is not None and np.isfinite(reference).sum() >= 3:
        step = np.abs(np.diff(reference))
        local = np.maximum(step[1:], step[:-1])
        keep = ~(local > 0.02 * period_mm)
        if keep.sum() < 3:
            keep[:] = True
    second, level = second[keep], flat[1:-1][keep]
    # Remove a per-difference-frame affine function of the gray level (common-mode gain/offset).
    design = np.stack([np.ones_like(level), level - level.mean(axis=1, keepdims=True)], axis=-1)
    gram = np.einsum("kpi,kpj->kij", design, design)
    rhs = np.einsum("kpi,kp->ki", design, second)
    coef = np.linalg.solve(gram + 1e-9 * np.eye(2), rhs[..., None])[..., 0]
    cleaned = second - np.einsum("kpi,ki->kp", design, coef)
    if np.mean(second == 0.0) > _QUANTISED_ZERO_FRACTION:
        return _trimmed_sigma(cleaned) / _SECOND_DIFF_GAIN
    mad = np.median(np.abs(cleaned - np.median(cleaned)))
    return float(_MAD_TO_SIGMA * mad / _SECOND_DIFF_GAIN)


def _trimmed_sigma(values: np.ndarray) -> float:
    """Standard deviation from the mean square below the 99th percentile, rescaled for a Gaussian.

    The fallback for coarsely quantised frames, whose differences take few distinct values: there
    the median of |d| sits on a quantisation step and says little, while the variance (noise plus
    quantisation, Δ²/12) is still well estimated.
    """
    squares = np.square(values - np.mean(values)).reshape(-1)
    keep = squares <= np.percentile(squares, 99.0)
    return float(np.sqrt(squares[keep].mean() / _GAUSS_TRIMMED_VARIANCE))


def crlb_mm(slope: np.ndarray, sigma_gray: float, nuisance: np.ndarray | None = None) -> np.ndarray:
    """Cramér–Rao bound on each frame's position: σ / sqrt(Σ (∂F/∂x)²).

    ``slope`` is ∂F/∂x with shape ``(K, …pixels)``. ``nuisance`` (``(K, …pixels, m)``) holds the
    derivatives of other per-frame unknowns solved together with x (gain, offset); they cost
    information, so the bound uses the Schur complement of the Fisher matrix.
    """
    slope = np.asarray(slope, dtype=np.float64)
    n_frames = slope.shape[0]
    d_x = slope.reshape(n_frames, -1)
    info = np.einsum("kp,kp->k", d_x, d_x)
    if nuisance is not None:
        d_n = np.asarray(nuisance, dtype=np.float64).reshape(n_frames, d_x.shape[1], -1)
        cross = np.einsum("kp,kpm->km", d_x, d_n)
        gram = np.einsum("kpm,kpq->kmq", d_n, d_n)
        info = info - np.einsum("km,km->k", cross, np.linalg.solve(gram, cross[..., None])[..., 0])
    return sigma_gray / np.sqrt(np.maximum(info, 1e-300))


def reference_resolution_mm(reference: np.ndarray) -> float:
    """The grating readout's step when its values sit on a grid (0 when they do not).

    A quantised reference adds its own error, step/√12, to every comparison against it: the error
    a perfect sensor shows against such a reference cannot fall below that.
    """
    values = np.unique(np.asarray(reference, dtype=np.float64)[np.isfinite(reference)])
    steps = np.diff(values)
    steps = steps[steps > 1e-9]
    if steps.size < 3:
        return 0.0
    smallest = float(steps.min())
    for divisor in range(1, 11):  # neighbouring readings may be several steps apart
        step = smallest / divisor
        multiples = (values - values[0]) / step
        if np.allclose(multiples, np.round(multiples), atol=0.02):
            return step
    return 0.0
