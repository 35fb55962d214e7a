"""Lossy frame compression as a camera's MJPEG stream does it (baseline JPEG, luminance only).

USB and IP cameras that only stream MJPEG hand out frames that went through the 8×8 DCT, a
quantisation of each coefficient by the standard luminance table scaled for the quality setting,
and back. What that leaves is not noise: within a block, the loss depends on the image (fine
detail and the sine's curvature go first), blocks have edges at fixed pixels, and the camera's own
noise is partly smoothed away. The entropy coding around it is lossless and not modelled.

The quality scaling is the Independent JPEG Group's (quality 50 is the table as printed in the
standard, T.81 Annex K; 75 is the usual camera default).
"""

from __future__ import annotations

import numpy as np

from graytrack.core.compression import quantisation_table, round_trip


def compress(frames: np.ndarray, quality: float) -> np.ndarray:
    """Frames ``(K, R, n)`` of 8-bit codes through JPEG at ``quality`` and back, as uint8.

    Blocks start at row 0 and pixel 0 of the ROI (an ROI on the 8-pixel grid of the sensor, as
    cameras place them); a partial block at the edge is padded by repeating its last row or
    column, as encoders do (core/compression.py's round trip, which calibration also replays).
    """
    return round_trip(frames, quantisation_table(quality)).astype(np.uint8)
