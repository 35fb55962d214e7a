"""The noise floor: per-pixel gray noise from the data itself, and the Cramér–Rao bound.

An error figure means little without the floor the same data allow, so every figure graytrack
reports stands next to this bound. σ is estimated without any model: a model's residual mixes
noise with whatever the model misses, which would make a poor model look noise-limited.
"""

from __future__ import annotations

import numpy as np

from graytrack.core.errors import GraytrackError

_MAD_TO_SIGMA = 1.4826
# Second temporal difference y[k+1] − 2 y[k] + y[k−1] of white noise has variance 6σ², a first 2σ².
_SECOND_DIFF_GAIN = np.sqrt(6.0)
_FIRST_DIFF_GAIN = np.sqrt(2.0)
# Frames whose second differences are exactly zero this often are quantised coarser than their noise.
_QUANTISED_ZERO_FRACTION = 0.2
# Share of a Gaussian's variance left after dropping its 1 % largest squares (|z| > 2.576).
_GAUSS_TRIMMED_VARIANCE = 0.9155
# Reference steps below this are a stage at rest (a grating's resolution is about 0.5 µm).
STILL_MM = 2e-3
MIN_STILL_PAIRS = 10


def estimate_sigma(frames: np.ndarray, reference: np.ndarray | None = None, period_mm: float | None = None) -> float:
    """Per-pixel gray-level noise σ of frames ``(K, n)`` or ``(K, R, n)``.

    Uses differences along time: first differences between frames taken at rest when the
    reference shows a step-and-settle sweep, otherwise second differences, where a slowly moving
    target contributes almost nothing (F''·Δx²). From each difference frame an affine function of
    the gray level is removed:
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
    still = _still_pairs(reference)
    if still is not None:  # a stage at rest: first differences of frames at one position
        second, level, gain = (flat[1:] - flat[:-1])[still], flat[:-1][still], _FIRST_DIFF_GAIN
    else:
        keep = _quiet_triples(reference, period_mm, n_frames)
        second, level, gain = (flat[2:] - 2.0 * flat[1:-1] + flat[:-2])[keep], flat[1:-1][keep], _SECOND_DIFF_GAIN
    # Remove a per-difference-frame affine function of the gray level (common-mode gain/offset).
    design = np.stack([np.ones_like(level), level - level.mean(axis=1, keepdims=True)], axis=-1)
    gram = np.einsum("kpi,kpj->kij", design, design)
    rhs = np.einsum("kpi,kp->ki", design, second)
    coef = np.linalg.solve(gram + 1e-9 * np.eye(2), rhs[..., None])[..., 0]
    cleaned = second - np.einsum("kpi,ki->kp", design, coef)
    if np.mean(second == 0.0) > _QUANTISED_ZERO_FRACTION:
        return _trimmed_sigma(cleaned) / gain
    mad = np.median(np.abs(cleaned - np.median(cleaned)))
    return float(_MAD_TO_SIGMA * mad / gain)


def _still_pairs(reference: np.ndarray | None) -> np.ndarray | None:
    """Consecutive frame pairs taken at rest (a step-and-settle sweep), when there are enough."""
    if reference is None or np.isfinite(reference).sum() < 3:
        return None
    still = np.abs(np.diff(reference)) < STILL_MM
    return still if still.sum() >= MIN_STILL_PAIRS else None


def _quiet_triples(reference: np.ndarray | None, period_mm: float | None, n_frames: int) -> np.ndarray:
    """Frame triples (k−1, k, k+1) that moved little enough for a second difference to be noise:
    less than 2 % of a period when the period is known; all of them otherwise or if too few."""
    keep = np.ones(n_frames - 2, dtype=bool)
    if reference is None or period_mm is None or np.isfinite(reference).sum() < 3:
        return keep
    step = np.abs(np.diff(reference))
    keep = ~(np.maximum(step[1:], step[:-1]) > 0.02 * period_mm)
    return keep if keep.sum() >= 3 else np.ones(n_frames - 2, dtype=bool)


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
