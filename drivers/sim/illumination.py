"""Illumination: a field fixed to the target, a field fixed to the camera, and flicker in time.

Three physically different things, told apart by what they follow:

* A lamp mounted beside the target lights it unevenly along the stroke. That field is fixed to the
  *target*: a pixel sees it change as the stage moves, but it does not repeat with the print's
  period, so a model periodic in the target phase cannot absorb it.
* Vignetting (and a lamp riding on the camera) is fixed to the *camera*: each pixel keeps its own
  gain whatever the stage position — it looks just like pixel response non-uniformity.
* Lamps on AC mains flicker at twice the mains frequency. The camera integrates the flicker over
  its exposure, so each frame gets one common-mode gain, attenuated by ``sinc(2 f_mains T)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from graytrack.drivers.sim.shadow import ShadowConfig


@dataclass
class IlluminationConfig:
    """Relative (dimensionless) gains; 0 everywhere means perfectly even, steady light."""

    gradient_per_mm: float = 0.0  # linear slope of the target-fixed field, relative gain per mm
    gradient_curvature_per_mm2: float = 0.0  # quadratic term (a lamp's hot spot)
    gradient_center_mm: float = 8.0  # target coordinate where the field's gain is 1
    vignetting: float = 0.0  # relative gain loss at the sensor's half-width (cos⁴-like, quadratic in radius)
    flicker_depth: float = 0.0  # relative modulation of the light at 2·mains
    mains_hz: float = 50.0
    flicker_phase_rad: float = 0.0
    level_gain: float = 1.0  # the lamp's light relative to the start of the run, once changed
    ambient_gray: float = 0.0  # stray light added evenly over the field once changed (gray)
    level_start_s: float = 0.0  # when the light changes
    level_ramp_s: float = 0.0  # how long the change takes (0: a step)
    glare_gray: float = 0.0  # stray light of a bright blob fixed to the camera, at its centre (gray)
    glare_center: tuple[float, float] = (0.5, 0.5)  # (pixel, row) of its centre, as fractions of the ROI
    glare_sigma_px: float = 10.0  # its size, pixels
    shadow: ShadowConfig = field(default_factory=ShadowConfig)  # a shadow sweeping across the field (shadow.py)

    @property
    def has_target_field(self) -> bool:
        return self.gradient_per_mm != 0.0 or self.gradient_curvature_per_mm2 != 0.0


def target_field_gain(cfg: IlluminationConfig, x_w: np.ndarray) -> np.ndarray:
    """Gain of the light falling on target coordinate ``x_w`` (non-periodic, smooth)."""
    dx = np.asarray(x_w, dtype=np.float64) - cfg.gradient_center_mm
    return 1.0 + cfg.gradient_per_mm * dx + cfg.gradient_curvature_per_mm2 * dx * dx


def camera_field_gain(cfg: IlluminationConfig, radius2: np.ndarray) -> np.ndarray:
    """Vignetting gain from each pixel's squared radius (normalised to the sensor half-width)."""
    return 1.0 - cfg.vignetting * np.asarray(radius2, dtype=np.float64)


def glare(cfg: IlluminationConfig, n_rows: int, n_pixels: int) -> np.ndarray:
    """Stray light ``(R, n)`` of a glare fixed to the camera (a reflection in the lens or window):
    it adds to the image whatever the stage position, so unlike the print it does not move."""
    if cfg.glare_gray == 0.0:
        return np.zeros((n_rows, n_pixels))
    u = np.arange(n_pixels) - cfg.glare_center[0] * (n_pixels - 1)
    r = np.arange(n_rows) - cfg.glare_center[1] * (n_rows - 1)
    d2 = r[:, None] ** 2 + u[None, :] ** 2
    return cfg.glare_gray * np.exp(-d2 / (2 * cfg.glare_sigma_px**2))


def level_change(cfg: IlluminationConfig, t_mid_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame (gain, ambient gray) of a light that changes during the run: someone switches on the
    room light or a lamp ages. Before ``level_start_s`` nothing changes; then the change ramps in
    linearly over ``level_ramp_s`` (a step when 0)."""
    share = ramp_share(t_mid_s, cfg.level_start_s, cfg.level_ramp_s)
    return 1.0 + (cfg.level_gain - 1.0) * share, cfg.ambient_gray * share


def ramp_share(t_s: np.ndarray, start_s: float, ramp_s: float) -> np.ndarray:
    """How far a change that begins at ``start_s`` and ramps in linearly over ``ramp_s`` (0: a step)
    has come at each instant, 0..1."""
    t = np.asarray(t_s, dtype=np.float64)
    if ramp_s > 0:
        return np.clip((t - start_s) / ramp_s, 0.0, 1.0)
    return (t >= start_s).astype(np.float64)


def flicker_gain(cfg: IlluminationConfig, t_mid_s: np.ndarray, exposure_s: float) -> np.ndarray:
    """Exposure-averaged light gain per frame: ``1 + m·sinc(2 f T)·cos(2π·2f·t + φ)``."""
    t = np.asarray(t_mid_s, dtype=np.float64)
    if cfg.flicker_depth == 0.0:
        return np.ones_like(t)
    f_light = 2.0 * cfg.mains_hz
    return 1.0 + cfg.flicker_depth * np.sinc(f_light * exposure_s) * np.cos(
        2 * math.pi * f_light * t + cfg.flicker_phase_rad
    )
