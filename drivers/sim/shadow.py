"""A moving shadow: a cable (or an arm, a hand) between the lamp and the print, swinging across the field.

The shadow lies on the print's plane but is fixed to neither the print nor the camera: the cable
hangs in the room, so its shadow stays where the lamp casts it while the print slides underneath,
and it moves when the cable swings. A pixel looking at lab position s (the target offset it sees
from the stage position, ``PixelGeometry.x_mm``) gets the gain::

    g(s, t) = 1 − depth · B(s − c(t)),   B(d) = ½ [erf((d + w/2)/(√2 e)) − erf((d − w/2)/(√2 e))]

a band of width w whose edges are soft over e (the penumbra: the lamp is not a point, so the
cable's shadow is blurred over the lamp's angular size × the cable's distance to the print).
Each pass carries the band's centre c(t) at constant speed from beyond one edge of the field to
beyond the other in ``pass_s``; successive passes swing back the other way (a hanging cable).
Between passes the band is out of view (gain 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erf

MARGIN_EDGES = 5.0  # a pass starts and ends this many edge widths beyond the field: out of view (3e-7 of the depth)


@dataclass
class ShadowConfig:
    """A band of shadow sweeping across the field; depth 0 means none."""

    depth: float = 0.0  # relative light lost in the band's core
    width_mm: float = 3.0  # the band's width on the print plane (between its half-depth points)
    edge_mm: float = 1.0  # softness of each edge (Gaussian σ of the penumbra)
    pass_s: float = 1.0  # the time one pass takes, from out of view on one side to out of view on the other
    passes: int = 3
    period_s: float = 4.0  # time between the starts of successive passes
    start_s: float = 1.0  # when the first pass begins

    @property
    def active(self) -> bool:
        return self.depth != 0.0 and self.passes > 0

    def centre(self, t_s: np.ndarray, lo_mm: float, hi_mm: float) -> np.ndarray:
        """The band's centre (lab mm, the pixels' ``x_mm`` frame) at each instant; NaN out of a pass."""
        t = np.asarray(t_s, dtype=np.float64)
        since = t - self.start_s
        index = np.floor(since / self.period_s)
        into = (since - index * self.period_s) / self.pass_s  # 0..1 during a pass
        during = (index >= 0) & (index < self.passes) & (into >= 0.0) & (into <= 1.0)
        reach = 0.5 * self.width_mm + MARGIN_EDGES * self.edge_mm
        start, end = lo_mm - reach, hi_mm + reach
        forward = np.mod(index, 2) == 0  # every other pass swings back
        share = np.where(forward, into, 1.0 - into)
        return np.where(during, start + share * (end - start), np.nan)

    def gain(self, t_s: np.ndarray, pixel_x_mm: np.ndarray) -> np.ndarray:
        """Gain ``(K, *pixels.shape)`` of the light reaching each pixel at each instant ``(K,)``."""
        pixels = np.asarray(pixel_x_mm, dtype=np.float64)
        centre = self.centre(t_s, float(pixels.min()), float(pixels.max()))
        out = np.ones((centre.size,) + pixels.shape)
        shown = np.isfinite(centre)
        if not shown.any():
            return out
        d = pixels[None] - centre[shown].reshape((-1,) + (1,) * pixels.ndim)
        half, scale = 0.5 * self.width_mm, math.sqrt(2.0) * self.edge_mm
        band = 0.5 * (erf((d + half) / scale) - erf((d - half) / scale))
        out[shown] = 1.0 - self.depth * band
        return out

    def in_view(self, t_s: np.ndarray, pixel_x_mm: np.ndarray, share: float = 0.01) -> np.ndarray:
        """Which instants have the shadow darkening some pixel by more than ``share`` of the depth."""
        if not self.active:
            return np.zeros(np.shape(t_s), dtype=bool)
        lost = 1.0 - self.gain(t_s, pixel_x_mm)
        return lost.reshape(lost.shape[0], -1).max(axis=1) > share * abs(self.depth)
