"""The seed paper's rig as a gray-level field: Table 2 of Lei et al. (2022), rebuilt in NOTES.md.

Table 2 describes a real rig's imaged gray level completely: five Fourier orders in the target
coordinate whose coefficients are cubics in the raw pixel index u = 0..99. Rendered with
alpha*d = 0.062 mm/pixel and Gaussian noise of about 0.7 gray it reproduces the paper's Table 1
and Fig. 5 when fitted with the ideal sine, which makes it the reference scenario ("paper").
"""

from __future__ import annotations

import numpy as np

PERIOD_MM = 8.62
PIXEL_PITCH_MM = 0.062
N_PIXELS = 100
NOISE_GRAY = 0.7
STROKE_MM = 10.46

# Rows: harmonic i = 1..5; columns: coefficient of u**0 .. u**3 (raw pixel index).
SIN_COEFFS = np.array(
    [
        [81.0, 0.04654, -0.0002637, 9.085e-07],
        [-6.692, 0.01142, 1.84e-06, -2.256e-07],
        [-0.6056, -0.001703, -1.555e-05, 2.462e-07],
        [-0.1802, 0.006175, -0.0001946, 1.323e-06],
        [-0.2038, -7.2e-05, 0.0001074, -8.738e-07],
    ]
)
COS_COEFFS = np.array(
    [
        [-24.01, 0.04984, -0.0002796, 1.659e-06],
        [-9.865, -0.01589, 0.000121, -4.206e-07],
        [0.5337, 0.004793, -0.0002089, 1.421e-06],
        [0.08277, 0.004726, -3.146e-05, 1.808e-07],
        [0.301, 0.003075, -0.0001482, 1.122e-06],
    ]
)
OFFSET_COEFFS = np.array([129.2, 0.04099, -0.0004571, 2.644e-06])


def paper_gray(x_target_mm: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Noise-free gray level of pixel(s) ``u`` looking at target coordinate(s) ``x_target_mm``.

    Arguments broadcast against each other; ``u`` is the raw pixel index (0..99 in the paper).
    """
    x_w = np.asarray(x_target_mm, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    powers = np.stack([np.ones_like(u), u, u**2, u**3], axis=-1)  # (..., 4)
    sin_c = powers @ SIN_COEFFS.T  # (..., 5): a_i(u)
    cos_c = powers @ COS_COEFFS.T
    offset = powers @ OFFSET_COEFFS
    harmonics = np.arange(1, 6)
    phase = 2 * np.pi * x_w[..., None] * harmonics / PERIOD_MM
    return (sin_c * np.sin(phase) + cos_c * np.cos(phase)).sum(axis=-1) + offset


def paper_frames(x_mm: np.ndarray, n_rows: int = 1, n_pixels: int = N_PIXELS,
                 pixel_pitch_mm: float = PIXEL_PITCH_MM, noise_gray: float = NOISE_GRAY,
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """Frames ``(K, R, n)`` of the paper rig at positions ``x_mm`` with independent Gaussian noise.

    This is the bare Table-2 field, for tests of the core; the virtual rig layers optics, sensor
    and timing effects on top of it.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    u = np.arange(n_pixels, dtype=np.float64)
    clean = paper_gray(np.asarray(x_mm)[:, None] + pixel_pitch_mm * u[None, :], u[None, :])
    noise = rng.normal(0.0, noise_gray, size=(len(x_mm), n_rows, n_pixels))
    return clean[:, None, :] + noise
