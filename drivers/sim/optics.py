"""Optics: which target point each pixel sees, and how sharply.

Pixel ``(r, u)`` of the ROI sees target coordinate ``x_w = x_stage + s[r, u]``. With a perfect lens
``s = x_offset + α·d·u`` (the paper's model). A real camera adds:

* radial distortion about the optical axis (the full sensor's centre, not the ROI's):
  positions scale by ``1 + k1·ρ²`` with ρ the radius over the sensor half-width — the pixel
  footprint changes across the line, so the imaged period does too;
* tilt of the sensor rows against the axis of motion by an angle ψ: row r is displaced along x by
  ``−r·α·d·sin ψ`` — every row sees the same profile at a phase shifted linearly with its row;
* defocus: a Gaussian blur of standard deviation σ on the target, which multiplies harmonic i of
  the profile by ``exp(−2π² σ² (i/τ)²)`` and widens local defects.

Motion blur is not here: it comes from integrating the moving scene over the exposure (rig.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class OpticsConfig:
    """Imaging geometry. ``pixel_pitch_mm`` is α·d, the footprint of one pixel on the target."""

    pixel_pitch_mm: float = 0.062
    n_pixels: int = 100
    n_rows: int = 1
    sensor_width: int | None = None  # full frame in pixels; None: the ROI is the whole sensor
    sensor_height: int | None = None
    roi_x: int = 0  # ROI origin on the full frame
    roi_y: int = 0
    x_offset_mm: float = 0.0  # target coordinate of ROI pixel (0, 0) with the stage at 0
    distortion_k1: float = 0.0  # relative radial stretch at the sensor half-width
    tilt_rad: float = 0.0
    defocus_sigma_mm: float = 0.0

    @property
    def full_width(self) -> int:
        return self.sensor_width if self.sensor_width is not None else self.roi_x + self.n_pixels

    @property
    def full_height(self) -> int:
        return self.sensor_height if self.sensor_height is not None else self.roi_y + self.n_rows


@dataclass
class PixelGeometry:
    """Per-pixel geometry of the ROI, each array ``(R, n)``."""

    x_mm: np.ndarray  # target x offset from the stage position
    y_mm: np.ndarray  # target y (across the motion)
    radius2: np.ndarray  # squared radius from the optical axis over the sensor half-width
    u: np.ndarray  # ROI column index (what the paper's polynomials take)
    full_u: np.ndarray  # full-frame column / row (what fixed-pattern noise belongs to)
    full_r: np.ndarray


def pixel_geometry(cfg: OpticsConfig) -> PixelGeometry:
    """Where each ROI pixel looks on the target (see the module docstring)."""
    if cfg.roi_x + cfg.n_pixels > cfg.full_width or cfg.roi_y + cfg.n_rows > cfg.full_height:
        raise ValueError("ROI does not fit in the sensor")
    rows, cols = np.meshgrid(np.arange(cfg.n_rows, dtype=float), np.arange(cfg.n_pixels, dtype=float), indexing="ij")
    full_u, full_r = cols + cfg.roi_x, rows + cfg.roi_y
    uc, rc = (cfg.full_width - 1) / 2.0, (cfg.full_height - 1) / 2.0
    half = max(cfg.full_width / 2.0, 1.0)
    du, dr = full_u - uc, full_r - rc
    radius2 = (du * du + dr * dr) / (half * half)
    stretch = 1.0 + cfg.distortion_k1 * radius2
    # distorted positions, relative to the ROI origin's (undistorted) position
    pu = uc + du * stretch - cfg.roi_x
    pr = rc + dr * stretch - cfg.roi_y
    c, s = math.cos(cfg.tilt_rad), math.sin(cfg.tilt_rad)
    x = cfg.x_offset_mm + cfg.pixel_pitch_mm * (pu * c - pr * s)
    y = cfg.pixel_pitch_mm * (pu * s + pr * c)
    return PixelGeometry(x, y, radius2, cols, full_u, full_r)


def defocus_attenuation(cfg: OpticsConfig, orders: np.ndarray, period_mm: float) -> np.ndarray:
    """Gain of Fourier order(s) ``orders`` of a profile of period ``period_mm`` under defocus."""
    f = np.asarray(orders, dtype=float) / period_mm
    return np.exp(-2 * math.pi**2 * cfg.defocus_sigma_mm**2 * f * f)
