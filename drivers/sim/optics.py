"""Optics: which target point each pixel sees, and how sharply.

Pixel ``(r, u)`` of the ROI sees target coordinate ``x_w = x_stage + s[r, u]``. With a perfect lens
``s = x_offset + α·d·u`` (the paper's model). A real camera adds:

* radial distortion about the optical axis (the full sensor's centre, not the ROI's):
  positions scale by ``1 + k1·ρ²`` with ρ the radius over the sensor half-width — the pixel
  footprint changes across the line, so the imaged period does too;
* tilt of the sensor rows against the axis of motion by an angle ψ: row r is displaced along x by
  ``−r·α·d·sin ψ`` — every row sees the same profile at a phase shifted linearly with its row;
* defocus: a Gaussian blur of standard deviation σ on the target, which multiplies harmonic i of
  the profile by ``exp(−2π² σ² (i/τ)²)`` and widens local defects;
* a mirrored readout (the camera mounted the other way round, or its ReverseX on): the sensor's
  columns are read out in reverse, so increasing ROI column u sees *decreasing* target x. What the
  paper's field attaches to the readout column (its pixel polynomials) stays with u.
* magnification drift: the footprint α·d scaling by 1 + m(t) about the optical axis (well off the
  ROI, where the lens's centre is): pixel u then sees ``s_u + m(t)·(s_u − s_axis)``, an image that
  stretches across the line and slides as a whole by ``m(t)·(s_centre − s_axis)`` while the stage
  stands;
* focus drift: σ changing during a run, σ(t) = max(σ₀ + Δσ·ramp(t), 0), or coming and going
  (a temperature cycle: ramp(t) = (1 − cos 2πt/T)/2). The change is on σ (what a
  person turning a focus ring sees), so a sharper image (Δσ < 0) needs a rig that had a blur to
  lose: from a sharp rig it clips at σ = 0 and nothing changes.

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
    mirrored: bool = False  # columns read out in reverse: u grows against the target coordinate
    magnification_error: float = 0.0  # true α·d = nominal · (1 + this): a lens refocused, a mount moved
    off_target_cols: int = 0  # ROI columns, from its far end, that see no print (a plain surface)
    off_target_rows: int = 0  # ROI rows, from its first, that see no print
    background_gray: float = 200.0  # what those pixels see instead (before the sensor)
    # Focus drifting during a run (a lens mount warming up): the blur σ moves from defocus_sigma_mm
    # by focus_drift_mm, ramping in linearly from focus_start_s over focus_ramp_s (0: a step).
    focus_drift_mm: float = 0.0
    focus_start_s: float = 0.0
    focus_ramp_s: float = 0.0
    # ... or coming and going (a lens mount warming and cooling): the change follows (1 − cos)/2 over
    # cycles of focus_cycle_s from focus_start_s (0: no cycle, the ramp above).
    focus_cycle_s: float = 0.0
    # Magnification drifting during a run (the lens warming up): the footprint of every pixel scales by
    # 1 + m(t) about the optical axis, which sits magnification_axis_mm (on the target) from the ROI's
    # centre; m(t) ramps or cycles to magnification_drift (magnification_change below).
    magnification_drift: float = 0.0
    magnification_axis_mm: float = 0.0
    magnification_start_s: float = 0.0
    magnification_ramp_s: float = 0.0
    magnification_cycle_s: float = 0.0
    # The camera knocked on its mount at knock_s: from then on every pixel sees the target knock_mm further
    # along the axis and the rows turned by knock_rad about the ROI's centre (a row y_mm across the line
    # sees it shifted by −y·sin knock_rad), for the rest of the run.
    knock_mm: float = 0.0
    knock_rad: float = 0.0
    knock_s: float = 0.0

    @property
    def moves(self) -> bool:
        """Whether what a pixel sees of the target changes during a run (each frame's offsets then)."""
        return bool(self.magnification_drift or self.knock_mm or self.knock_rad)

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
    if cfg.mirrored:  # the physical column behind readout column u is the one across the centre
        du = -du
    radius2 = (du * du + dr * dr) / (half * half)
    stretch = 1.0 + cfg.distortion_k1 * radius2
    # distorted positions, relative to the ROI origin's (undistorted) position
    pu = uc + du * stretch - cfg.roi_x
    pr = rc + dr * stretch - cfg.roi_y
    c, s = math.cos(cfg.tilt_rad), math.sin(cfg.tilt_rad)
    pitch = cfg.pixel_pitch_mm * (1.0 + cfg.magnification_error)
    x = cfg.x_offset_mm + pitch * (pu * c - pr * s)
    y = pitch * (pu * s + pr * c)
    return PixelGeometry(x, y, radius2, cols, full_u, full_r)


def off_target(cfg: OpticsConfig) -> np.ndarray:
    """``(R, n)`` True where the ROI looks past the print's edge (sees the plain background)."""
    mask = np.zeros((cfg.n_rows, cfg.n_pixels), dtype=bool)
    if cfg.off_target_cols:
        mask[:, cfg.n_pixels - cfg.off_target_cols:] = True
    mask[: cfg.off_target_rows] = True
    return mask


def defocus_attenuation(cfg: OpticsConfig, orders: np.ndarray, period_mm: float) -> np.ndarray:
    """Gain of Fourier order(s) ``orders`` of a profile of period ``period_mm`` under defocus."""
    f = np.asarray(orders, dtype=float) / period_mm
    return np.exp(-2 * math.pi**2 * cfg.defocus_sigma_mm**2 * f * f)


def blur_sigma_mm(cfg: OpticsConfig, t_s: np.ndarray) -> np.ndarray:
    """Blur σ on the target (mm) at frame times ``t_s`` ``(K,)``: the base defocus, moved by the focus drift."""
    t = np.asarray(t_s, dtype=np.float64)
    if cfg.focus_cycle_s > 0:
        turn = 2.0 * math.pi * np.maximum(t - cfg.focus_start_s, 0.0) / cfg.focus_cycle_s
        share = 0.5 * (1.0 - np.cos(turn))
    elif cfg.focus_ramp_s > 0:
        share = np.clip((t - cfg.focus_start_s) / cfg.focus_ramp_s, 0.0, 1.0)
    else:
        share = (t >= cfg.focus_start_s).astype(np.float64)
    return np.maximum(cfg.defocus_sigma_mm + cfg.focus_drift_mm * share, 0.0)


def focus_attenuation(cfg: OpticsConfig, orders: np.ndarray, period_mm: float, t_s: np.ndarray) -> np.ndarray | None:
    """``(K, orders)`` gain of each Fourier order at each frame relative to the base defocus (which
    the rig's coefficients already carry); None when the focus does not drift. A Gaussian blur's
    variances add, so the change is exp(−2π² (σ(t)² − σ₀²) (i/τ)²): above 1 when the image sharpens."""
    if cfg.focus_drift_mm == 0.0:
        return None
    change = blur_sigma_mm(cfg, t_s) ** 2 - cfg.defocus_sigma_mm**2
    f = np.asarray(orders, dtype=float) / period_mm
    return np.exp(-2 * math.pi**2 * change[:, None] * (f * f)[None, :])


def magnification_change(cfg: OpticsConfig, t_s: np.ndarray) -> np.ndarray:
    """m(t) ``(K,)``: the relative change of the footprint at frame times ``t_s``. A ramp reaches
    ``magnification_drift`` linearly over ``magnification_ramp_s`` from ``magnification_start_s`` (0:
    a step); with ``magnification_cycle_s`` > 0 it comes and goes instead (a temperature cycle):
    ``drift·(1 − cos(2π(t − start)/cycle))/2`` from the start on."""
    t = np.asarray(t_s, dtype=np.float64)
    since = t - cfg.magnification_start_s
    if cfg.magnification_cycle_s > 0:
        share = np.where(since >= 0, 0.5 * (1.0 - np.cos(2 * math.pi * since / cfg.magnification_cycle_s)), 0.0)
    elif cfg.magnification_ramp_s > 0:
        share = np.clip(since / cfg.magnification_ramp_s, 0.0, 1.0)
    else:
        share = (since >= 0).astype(np.float64)
    return cfg.magnification_drift * share


def drifted_offsets(cfg: OpticsConfig, x_mm: np.ndarray, t_s: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """``(K, R, n)``: the target offsets ``x_mm`` ``(R, n)`` each pixel sees at frame times ``t_s``
    under the magnification drift (the footprint scaled about the optical axis) and after a knock
    (``y_mm`` ``(R, n)``: each pixel's place across the line, about which the rows turn)."""
    t = np.asarray(t_s, dtype=np.float64)
    axis = float(np.mean(x_mm)) + cfg.magnification_axis_mm
    m = magnification_change(cfg, t)
    offsets = x_mm[None] + m[:, None, None] * (x_mm - axis)[None]
    if cfg.knock_mm or cfg.knock_rad:
        knocked = (t >= cfg.knock_s).astype(np.float64)[:, None, None]
        across = y_mm - float(np.mean(y_mm))
        offsets = offsets + knocked * (cfg.knock_mm - across * math.sin(cfg.knock_rad))[None]
    return offsets
