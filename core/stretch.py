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
            offsets_mm: np.ndarray, curvature: np.ndarray | None = None) -> tuple[float, float]:
    """(m, its standard error), dimensionless, from one frame: the model's ``values`` and ``slopes``
    (∂F/∂x, gray/mm) at the solved position, the frame's ``residual`` and information ``weights``
    (1/σ², 0 for a sample set aside), and each sample's target offset ``offsets_mm``; with its
    ``curvature`` (∂²F/∂x²) a change of focus is fitted too (a blur spreads as ½Δσ²·F'', which on
    a line shorter than a period partly looks like a stretch: a focus drift of half a pixel read as
    a steady stretch on a quarter of its frames). (nan, inf) when the frame cannot tell."""
    # a sample far beyond its noise (a pixel gone bad that the solve kept, a glint's edge) is no stretch:
    # one stuck pixel off the centre, the same on every frame, read as a steady 300 ppm on a 16-row strip
    w = np.where(residual * residual * weights > OUTLIER_Z * OUTLIER_Z, 0.0, weights)
    total = w.sum()
    if not total > 0:
        return math.nan, math.inf
    centred = offsets_mm - float(w @ offsets_mm) / total
    columns = [slopes * centred, slopes, values, np.ones_like(values)]
    if curvature is not None:
        columns.append(curvature)
    shapes = np.stack(columns)  # (4 or 5, P)
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
    weights = batch.weights(k)
    if solution.rejected_mask is not None:
        weights = weights * ~solution.rejected_mask
    residual = batch.residuals(k, solution.x_mm, solution.gain, solution.offset)
    offsets = tracker.model.target_offset().reshape(-1)
    if not math.isfinite(solution.focus_sigma):  # the focus held: the stretch alone (its full power)
        values, slopes = tracker.evaluator.evaluate(np.array([solution.x_mm]))
        return stretch(values[0], slopes[0], residual, weights, offsets)
    # the tracker solved a change of focus for this frame: the stretch beside it (the curvature by the
    # slopes a thousandth of a period apart)
    step = tracker.model.period_mm * 1e-3
    values, slopes = tracker.evaluator.evaluate(np.array([solution.x_mm - step, solution.x_mm, solution.x_mm + step]))
    return stretch(values[1], slopes[1], residual, weights, offsets, (slopes[2] - slopes[0]) / (2.0 * step))
