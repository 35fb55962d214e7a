"""The stretch of the image across the pixels, measured from one frame: a magnification change.

A lens whose magnification moves by m (warming up, a temperature cycle) scales every pixel's
footprint on the target about the optical axis: the pixel that saw target offset ``s_u`` sees
``s_u + m·(s_u − s_axis)``. Part of that is a shift of the whole image (``m·(s_c − s_axis)``, the
line's centre against the axis): the tracker takes it for a position and cannot tell it from one.
The rest is a stretch about the line's centre, ``m·(s_u − s_c)``, which leaves in the frame's
residual the shape ``m·F'_u·(s_u − s_c)``: the frame's slope at each sample times its place along
the line. Fitted by weighted least squares with the shapes the solve already had (the position's
slope, the light's gain and offset), so what they explain is not taken for a stretch, it gives m
and its standard error from the frame's own noise. One frame of a 16-row strip of 100 px knows m
to ~250 ppm; a run's frames together, to a few ppm (core/watches/magnification.py).
"""

from __future__ import annotations

import math

import numpy as np

OUTLIER_Z = 4.0  # a sample this many of its σ off the model is left out of the stretch


def stretch(values: np.ndarray, slopes: np.ndarray, residual: np.ndarray, weights: np.ndarray,
            offsets_mm: np.ndarray) -> tuple[float, float]:
    """(m, its standard error), dimensionless, from one frame: the model's ``values`` and ``slopes``
    (∂F/∂x, gray/mm) at the solved position, the frame's ``residual`` and information ``weights``
    (1/σ², 0 for a sample set aside), and each sample's target offset ``offsets_mm``. (nan, inf)
    when the frame cannot tell (too few samples, a stretch its other shapes explain)."""
    # a sample far beyond its noise (a pixel gone bad that the solve kept, a glint's edge) is no stretch:
    # one stuck pixel off the centre, the same on every frame, read as a steady 300 ppm on a 16-row strip
    w = np.where(residual * residual * weights > OUTLIER_Z * OUTLIER_Z, 0.0, weights)
    total = w.sum()
    if not total > 0:
        return math.nan, math.inf
    centred = offsets_mm - float(w @ offsets_mm) / total
    shapes = np.stack([slopes * centred, slopes, values, np.ones_like(values)])  # (4, P)
    weighted = shapes * w
    normal = weighted @ shapes.T
    try:
        covariance = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return math.nan, math.inf
    variance = covariance[0, 0]
    if not variance > 0:
        return math.nan, math.inf
    m = float(covariance[0] @ (weighted @ residual))
    return m, math.sqrt(variance)


def frame_stretch(tracker, batch, k: int, solution) -> tuple[float, float]:
    """:func:`stretch` of batch frame ``k`` at its solution (one evaluation of the model there)."""
    values, slopes = tracker.evaluator.evaluate(np.array([solution.x_mm]))
    weights = batch.weights(k)
    if solution.rejected_mask is not None:
        weights = weights * ~solution.rejected_mask
    residual = batch.residuals(k, solution.x_mm, solution.gain, solution.offset)
    return stretch(values[0], slopes[0], residual, weights, tracker.model.target_offset().reshape(-1))
