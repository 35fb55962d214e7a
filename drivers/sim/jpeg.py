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

from graytrack.core.compression import BLOCK, DCT, quantisation_table


def compress(frames: np.ndarray, quality: float) -> np.ndarray:
    """Frames ``(K, R, n)`` of 8-bit codes through JPEG at ``quality`` and back, as uint8.

    Blocks start at row 0 and pixel 0 of the ROI (an ROI on the 8-pixel grid of the sensor, as
    cameras place them); a partial block at the edge is padded by repeating its last row or
    column, as encoders do.
    """
    codes = np.asarray(frames, dtype=np.float64)
    k, rows, width = codes.shape
    pad_r, pad_c = -rows % BLOCK, -width % BLOCK
    padded = np.pad(codes, ((0, 0), (0, pad_r), (0, pad_c)), mode="edge") - 128.0
    blocks = padded.reshape(k, padded.shape[1] // BLOCK, BLOCK, padded.shape[2] // BLOCK, BLOCK)
    coefficients = np.einsum("ij,kajbl,ml->kaibm", DCT, blocks, DCT)  # (K, by, 8, bx, 8)
    table = quantisation_table(quality)[None, None, :, None, :]
    restored = np.einsum("ji,kajbl,lm->kaibm", DCT, np.rint(coefficients / table) * table, DCT)
    image = restored.reshape(padded.shape)[:, :rows, :width] + 128.0
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
