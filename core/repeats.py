"""Frames a driver delivered twice: the same image again, under a new timestamp and reference.

USB and GigE drivers that miss a frame sometimes hand out the last buffer once more. The image
then shows where the stage *was*, while its timestamp and grating reading say where it *is*: tracked
as a new frame it is a position error of one frame's motion, counted as motion. A camera with any
read noise never repeats an image bit for bit by chance, so an exact repeat is the driver's, not
the scene's — unless the noise is too small for the data's number format to show it (a noise-free
simulation, or a still scene on a coarse digitiser), which is why the chance is checked.
"""

from __future__ import annotations

import math

import numpy as np

CHANCE_LIMIT_LOG10 = -9.0  # an identical image whose chance under the noise is below this is a repeat


def chance_log10(n_samples: int, sigma_gray: float, step_gray: float) -> float:
    """log10 of the chance that ``n_samples`` independent noisy samples read exactly as before.

    Two readings of the same light differ by noise of σ√2; quantised in steps q they agree with
    probability ≈ q/(2σ√π) per sample when σ ≫ q (at most 1).
    """
    if not sigma_gray > 0:
        return 0.0
    per_sample = min(1.0, step_gray / (2.0 * sigma_gray * math.sqrt(math.pi)))
    return -math.inf if per_sample == 0 else n_samples * math.log10(per_sample)


def number_step(frames: np.ndarray) -> float:
    """The finest step the data's number format can show near its values (1 for integer data)."""
    if np.issubdtype(frames.dtype, np.integer):
        return 1.0
    top = float(np.max(np.abs(frames))) if frames.size else 1.0
    return float(np.spacing(frames.dtype.type(max(top, 1.0))))


def repeated(frames: np.ndarray, sigma_gray: float, before: np.ndarray | None = None) -> np.ndarray:
    """Bool ``(K,)``: frame k is bit for bit frame k−1 (``before``: the frame preceding frame 0) and
    the noise ``sigma_gray`` makes that no coincidence."""
    frames = np.asarray(frames)
    same = np.zeros(frames.shape[0], dtype=bool)
    if frames.shape[0] == 0:
        return same
    axes = tuple(range(1, frames.ndim))
    same[1:] = np.all(frames[1:] == frames[:-1], axis=axes)
    if before is not None and np.shape(before) == frames.shape[1:]:
        same[0] = bool(np.array_equal(frames[0], before))
    if same.any():  # the chance only matters for the rare identical pair (cheap for live frames)
        step = number_step(frames)
        for k in np.flatnonzero(same).tolist():
            if chance_log10(noisy_samples(frames[k]), sigma_gray, step) > CHANCE_LIMIT_LOG10:
                same[k] = False
    return same


def noisy_samples(image: np.ndarray) -> int:
    """Samples of ``image`` whose noise can show: those strictly between its lowest and highest
    value. A sample at either may be clipped (the digitiser's floor with the light off, full scale
    on a flash) and reads the same however noisy the sensor: two black frames in a row are no
    frame delivered twice, and were called one (with the driver blamed) for a light gone out."""
    low, high = image.min(), image.max()
    return int(np.count_nonzero((image > low) & (image < high)))
