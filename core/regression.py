"""Small weighted regressions shared by fitting and diagnosis."""

from __future__ import annotations

import numpy as np


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
