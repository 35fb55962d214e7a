"""The noise floor: per-pixel gray noise from the data itself, and the Cramér–Rao bound.

An error figure means little without the floor the same data allow, so every figure graytrack
reports stands next to this bound. σ is estimated without any model: a model's residual mixes
noise with whatever the model misses, which would make a poor model look noise-limited.
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core.errors import GraytrackError
from graytrack.core.pixel_noise import PixelNoise

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
# A reference whose values are evenly spaced by more than this is a sweep's stops, not a readout.
MAX_REGULAR_READOUT_STEP_MM = 0.02
_NOISE_BINS = 12  # gray-level bins of the photon-transfer curve
_MIN_BIN_SAMPLES = 200
_SLOPE_Z = 5.0  # the shot-noise slope must stand this many standard errors above zero …
_MIN_SIGNAL_SHARE = 0.1  # … and add this share of the read variance over the gray range seen


def estimate_sigma(frames: np.ndarray, reference: np.ndarray | None = None, period_mm: float | None = None,
                   exclude: np.ndarray | None = None) -> float:
    """Per-pixel gray-level noise σ of frames ``(K, n)`` or ``(K, R, n)``.

    Uses differences along time: first differences between frames taken at rest when the
    reference shows a step-and-settle sweep, otherwise second differences, where a slowly moving
    target contributes almost nothing (F''·Δx²). From each difference frame an affine function of
    the gray level is removed:
    that takes out common-mode gain and offset changes (flicker, exposure drift), which are not
    pixel noise. Frames that moved more than 2 % of a period between neighbours are skipped when
    the reference allows telling. A robust (MAD) scale keeps defects and outliers from counting,
    except for coarsely quantised frames, where a trimmed variance takes over. ``exclude`` (bool,
    like ``frames``) marks samples to leave out (transients, core/transients.py).
    """
    cleaned, _, gain, quantised = temporal_differences(frames, reference, period_mm, exclude)
    if exclude is not None:
        cleaned = cleaned[np.isfinite(cleaned)]
    if quantised:
        return _trimmed_sigma(cleaned) / gain
    mad = np.median(np.abs(cleaned - np.median(cleaned)))
    return float(_MAD_TO_SIGMA * mad / gain)


def temporal_differences(frames: np.ndarray, reference: np.ndarray | None = None,
                         period_mm: float | None = None,
                         exclude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Noise samples along time, model-free: (differences ``(D, P)`` with the common mode removed,
    the gray level each was taken at ``(D, P)``, the factor from difference to sample σ, whether
    the frames are quantised coarser than their noise). Differences that touch a sample marked in
    ``exclude`` (bool, like ``frames``: a glint's) are NaN and take no part in the common mode:
    a glint in one frame would otherwise tilt the gain fitted to its whole difference frame."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim == 2:
        frames = frames[:, None, :]
    if frames.shape[0] < 3:
        raise GraytrackError("need at least 3 frames to estimate the noise")
    n_frames = frames.shape[0]
    flat = frames.reshape(n_frames, -1)
    still = _still_pairs(reference)
    # The level of a difference is the mean of the frames in it: uncorrelated with the difference
    # itself (the middle frame alone is not), so binning by level does not bias the variance.
    spoiled = None if exclude is None else np.asarray(exclude, dtype=bool).reshape(n_frames, -1)
    if still is not None:  # a stage at rest: first differences of frames at one position
        second, gain = (flat[1:] - flat[:-1])[still], _FIRST_DIFF_GAIN
        level = (0.5 * (flat[1:] + flat[:-1]))[still]
        touched = None if spoiled is None else (spoiled[1:] | spoiled[:-1])[still]
    else:
        keep = _quiet_triples(reference, period_mm, n_frames)
        second, gain = (flat[2:] - 2.0 * flat[1:-1] + flat[:-2])[keep], _SECOND_DIFF_GAIN
        level = ((flat[2:] + flat[1:-1] + flat[:-2]) / 3.0)[keep]
        touched = None if spoiled is None else (spoiled[2:] | spoiled[1:-1] | spoiled[:-2])[keep]
    # Remove from each difference frame an offset per row and a gain common to the frame: a change
    # of the light or exposure (flicker, drift) and a readout offset that differs from row to row
    # (row banding) are common to many pixels, not pixel noise — left in, they would inflate σ and
    # with it the bound every error is compared with.
    rows = frames.shape[1]
    by_row = second.reshape(second.shape[0], rows, -1)
    level_by_row = level.reshape(by_row.shape)
    if touched is None:
        centred = by_row - by_row.mean(axis=2, keepdims=True)
        level_centred = level_by_row - level_by_row.mean(axis=2, keepdims=True)
        slope = np.einsum("krp,krp->k", centred, level_centred) / (
            np.einsum("krp,krp->k", level_centred, level_centred) + 1e-9)
        cleaned = (centred - slope[:, None, None] * level_centred).reshape(second.shape)
        return cleaned, level, float(gain), bool(np.mean(second == 0.0) > _QUANTISED_ZERO_FRACTION)
    used = (~touched).reshape(by_row.shape).astype(np.float64)
    count = np.maximum(used.sum(axis=2, keepdims=True), 1.0)
    centred = by_row - (by_row * used).sum(axis=2, keepdims=True) / count
    level_centred = level_by_row - (level_by_row * used).sum(axis=2, keepdims=True) / count
    slope = np.einsum("krp,krp->k", centred * used, level_centred) / (
        np.einsum("krp,krp->k", level_centred * used, level_centred) + 1e-9)
    cleaned = (centred - slope[:, None, None] * level_centred).reshape(second.shape)
    cleaned[touched] = np.nan
    return cleaned, level, float(gain), bool(np.mean(second[~touched] == 0.0) > _QUANTISED_ZERO_FRACTION)


def estimate_pixel_noise(frames: np.ndarray, reference: np.ndarray | None = None, period_mm: float | None = None,
                         bit_depth: int | None = None, usable: np.ndarray | None = None,
                         exclude: np.ndarray | None = None) -> PixelNoise:
    """The photon-transfer curve σ²(y) of the frames, model-free (EMVA 1288 from the data itself).

    The temporal differences of :func:`temporal_differences`, binned by gray level; a trimmed
    variance per bin; a weighted straight line var = a + K·y through the bins. Quantisation
    (Δ = 1 count, Δ²/12) is split off the intercept when the bit depth is known. Without dark
    frames a black level b cannot be told from read noise (σ² = read − K·b + K·y): the curve is
    referred to gray 0, which describes every level seen exactly. When the slope is not significant (or not positive)
    the constant-σ model is returned: a curve that the data do not support would only add noise to
    the weights. ``usable`` ``(R, n)`` leaves out pixels found bad, ``exclude`` (like ``frames``)
    samples set aside as transients.
    """
    cleaned, level, gain, _ = temporal_differences(frames, reference, period_mm, exclude)
    if usable is not None:
        keep = np.asarray(usable, dtype=bool).reshape(-1)
        cleaned, level = cleaned[:, keep], level[:, keep]
    variance_samples, levels = (cleaned / gain).reshape(-1), level.reshape(-1)
    if exclude is not None:
        finite = np.isfinite(variance_samples)
        variance_samples, levels = variance_samples[finite], levels[finite]
    quant_var = 1.0 / 12.0 if isinstance(bit_depth, int) and bit_depth > 0 else 0.0
    sigma = float(np.sqrt(_trimmed_variance(variance_samples)))
    edges = np.unique(np.percentile(levels, np.linspace(0.0, 100.0, _NOISE_BINS + 1)))
    which = np.clip(np.searchsorted(edges, levels, side="right") - 1, 0, edges.size - 2)
    centres, variances, counts = [], [], []
    for b in range(edges.size - 1):
        inside = which == b
        if inside.sum() >= _MIN_BIN_SAMPLES:
            centres.append(float(levels[inside].mean()))
            variances.append(_trimmed_variance(variance_samples[inside]))
            counts.append(float(inside.sum()))
    if len(centres) < 3:
        return PixelNoise.constant(sigma)
    x, y, w = np.array(centres), np.array(variances), np.array(counts)
    # var of a variance estimate ∝ var²/n: weight each bin by n / var².
    weights = w / np.maximum(y, 1e-12) ** 2
    design = np.stack([np.ones_like(x), x], axis=1)
    normal = design.T @ (weights[:, None] * design)
    (intercept, slope) = np.linalg.solve(normal, design.T @ (weights * y))
    slope_sd = float(np.sqrt(np.linalg.inv(normal)[1, 1] * _chi2_scale(design, weights, y, intercept, slope)))
    spread = float(x.max() - x.min())
    significant = slope > _SLOPE_Z * slope_sd and slope * spread > _MIN_SIGNAL_SHARE * max(intercept, 1e-12)
    if not significant:
        return PixelNoise.constant(sigma)
    read_var = float(intercept) - quant_var
    if read_var >= 0.0:
        return PixelNoise(read_var=read_var, shot_gain=float(slope), quant_var=quant_var)
    # The line meets the quantisation floor above gray 0 (a black level the data cannot separate
    # from read noise): start the shot noise there, the same curve over every level seen.
    return PixelNoise(read_var=0.0, shot_gain=float(slope), dark_gray=-read_var / float(slope), quant_var=quant_var)


def _chi2_scale(design: np.ndarray, weights: np.ndarray, y: np.ndarray, intercept: float, slope: float) -> float:
    """Reduced χ² of the line through the bins (≥ 1): bins scatter more than their counts say
    when the pixels of one bin differ among themselves."""
    residual = y - design @ np.array([intercept, slope])
    dof = max(y.size - 2, 1)
    return max(float((weights * residual**2).sum()) / dof, 1.0)


def _trimmed_variance(values: np.ndarray) -> float:
    return _trimmed_sigma(values) ** 2


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


def crlb_mm(slope: np.ndarray, sigma_gray: float, nuisance: np.ndarray | None = None,
            variance: np.ndarray | None = None) -> np.ndarray:
    """Cramér–Rao bound on each frame's position: 1 / sqrt(Σ (∂F/∂x)² / σ²).

    ``slope`` is ∂F/∂x with shape ``(K, …pixels)``. ``variance`` (broadcastable to it) is each
    sample's σ² when the noise depends on the gray level (photon transfer); without it every
    sample has ``sigma_gray``. ``nuisance`` (``(K, …pixels, m)``) holds the derivatives of other
    per-frame unknowns solved together with x (gain, offset); they cost information, so the bound
    uses the Schur complement of the Fisher matrix.
    """
    slope = np.asarray(slope, dtype=np.float64)
    n_frames = slope.shape[0]
    if variance is None:
        scale = np.full(slope.shape, 1.0 / sigma_gray)
    else:
        scale = 1.0 / np.sqrt(np.broadcast_to(np.asarray(variance, dtype=np.float64), slope.shape))
    d_x = (slope * scale).reshape(n_frames, -1)
    info = np.einsum("kp,kp->k", d_x, d_x)
    if nuisance is not None:
        d_n = np.asarray(nuisance, dtype=np.float64).reshape(n_frames, d_x.shape[1], -1)
        d_n = d_n * scale.reshape(n_frames, -1, 1)
        cross = np.einsum("kp,kpm->km", d_x, d_n)
        gram = np.einsum("kpm,kpq->kmq", d_n, d_n)
        info = info - np.einsum("km,km->k", cross, np.linalg.solve(gram, cross[..., None])[..., 0])
    return 1.0 / np.sqrt(np.maximum(info, 1e-300))


def pooled_bound(bounds: np.ndarray) -> float:
    """The error spread a set of frames would show if each sat at its own bound: the root mean
    square of the per-frame bounds (NaN when none is finite).

    This, not the median, is what an error std over the same frames compares with: where the bound
    varies along the stroke (dust in view on some frames, a glint masked on others) the frames
    with a poor bound dominate the spread, and a median swings with which positions happened to
    be held out (a 2.6× swing between runs of one rig, seen on the daemon's scan)."""
    values = np.asarray(bounds, dtype=np.float64)
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(np.square(finite)))) if finite.size else float("nan")


def reference_resolution_mm(reference: np.ndarray) -> float:
    """The grating readout's step when its values sit on a grid (0 when the data do not show one).

    A quantised reference adds its own error, step/√12, to every comparison against it: the error
    a perfect sensor shows against such a reference cannot fall below that.

    A step-and-settle sweep reads the grating once per stop, so its values are the stops, and
    their spacing is no readout step: the grid shows only where gaps between neighbouring values
    differ from one another (stops of 250 and 300 µm on a 50 µm readout) or where the smallest gap
    is several steps of a common divisor. When every gap is a whole number of the smallest gap
    (every gap the same, or some stops left out, as in a held-out subset of the stops), the
    readout step is not resolved by the data, unless that gap is small enough to be a readout step
    itself.
    """
    values = np.unique(np.asarray(reference, dtype=np.float64)[np.isfinite(reference)])
    gaps = np.diff(values)
    gaps = gaps[gaps > 1e-9]
    if gaps.size < 3:
        return 0.0
    smallest = float(gaps.min())
    variations = np.diff(np.unique(np.round(gaps, 7)))  # gap sizes to 0.1 nm: float noise is not a step
    variations = variations[variations > 1e-6]
    regular = variations.size == 0
    base = smallest if regular else min(smallest, float(variations.min()))
    for divisor in range(1, 11):  # neighbouring readings may be several steps apart
        step = base / divisor
        multiples = (values - values[0]) / step
        if np.allclose(multiples, np.round(multiples), rtol=0.0, atol=0.02):
            if divisor == 1 and step > MAX_REGULAR_READOUT_STEP_MM and math.isclose(step, smallest, rel_tol=1e-6):
                return 0.0  # the values' own spacing, far coarser than a readout: the stops of a sweep
            return step
    return 0.0
