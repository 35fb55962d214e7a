"""The ``magnification`` watch: the image stretching across the pixels since calibration.

A lens warming up changes its magnification by parts per thousand; with the optical axis off the
ROI the image then also slides, tens of µm while the stage stands, which the tracker takes for a
position and no image can tell from one. The stretch that comes with it can be told: each frame's
residual has the shape ``m·F'_u·(s_u − s_c)`` (core/stretch.py), one frame of a 16-row strip knows m
to ~400 ppm, and an exponentially weighted mean over :data:`MEMORY` frames to ~60. The watch blames
``magnification`` while that mean is beyond :data:`Z_ON` of its standard error (the frames' noise,
scaled up by their own scatter, and :data:`STRUCTURE_PPM`: a model's own error along the stroke
reads as a stretch of up to ~150 ppm over a stretch of 50 frames on a steady strip), until it falls
below :data:`Z_OFF`. It needs no grating: a rig tracked without one is named, not silently off.
"""

from __future__ import annotations

import math

MEMORY = 50  # frames: the mean's time constant
MIN_FRAMES = 10  # frames (effective) before the mean says anything
Z_ON, Z_OFF = 4.0, 2.5
STRUCTURE_PPM = 40.0  # what a calibrated model's own structure reads as a stretch, in a mean of MEMORY frames


class MagnificationWatch:
    """``step(placed, stretch) -> "magnification" | None`` from each placed frame's stretch."""

    family = "magnification"
    reads = ("placed", "stretch")

    def __init__(self) -> None:
        self._decay = math.exp(-1.0 / MEMORY)
        self._sums = [0.0] * 5  # see _add
        self.flagged = False
        self.mean_ppm = 0.0
        self.sigma_ppm = math.inf

    def observe(self, sign) -> str | None:
        return self.step(sign.placed, sign.stretch)

    def step(self, placed: bool, stretch) -> str | None:
        if placed and stretch is not None:
            m, sigma = stretch()
            if math.isfinite(m) and 0 < sigma < math.inf:
                self._add(m * 1e6, sigma * 1e6)
        return self.family if self.flagged else None

    def _add(self, m_ppm: float, sigma_ppm: float) -> None:
        d, s = self._decay, self._sums
        w = 1.0 / (sigma_ppm * sigma_ppm)
        s[0] = d * s[0] + w  # Σ dᵃ·w (a: the frame's age)
        s[1] = d * s[1] + w * m_ppm
        s[2] = d * s[2] + w * m_ppm * m_ppm
        s[3] = d * d * s[3] + w  # Σ d²ᵃ·w: the mean's noise is Σ d²ᵃ·w / (Σ dᵃ·w)²
        s[4] = d * s[4] + 1.0  # frames, decayed
        if s[4] < MIN_FRAMES:
            return
        mean = s[1] / s[0]
        scatter = max((s[2] - mean * s[1]) / max(s[4] - 1.0, 1.0), 1.0)  # χ² per frame about the mean
        self.mean_ppm = mean
        self.sigma_ppm = math.sqrt(s[3] / (s[0] * s[0]) * scatter + STRUCTURE_PPM ** 2)
        self.flagged = abs(mean) >= (Z_OFF if self.flagged else Z_ON) * self.sigma_ppm


def make(tracker) -> MagnificationWatch:
    """Every tracker's: the stretch is in the frames, with a grating or without."""
    return MagnificationWatch()
