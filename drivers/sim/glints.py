"""Specular glints: bright, short-lived blobs pinned to a spot of the print.

A glossy fibre or a toner grain on the print catches the lamp for a moment and mirrors it into
the lens: the image gets a bright blob a few pixels wide, on a few rows of a strip, for 1 to 4
frames, then it is gone. While it lasts it sits on its spot of the *target*, so in the image it
slides with the stage like the print does. Its light is the lamp's (it dims and flickers with
it) and adds to the print's; a bright one saturates the sensor.

Events are a Poisson process in time whose rate gives the requested share ``p`` of frames with a
glint; each event has a duration (1..4 frame periods), a peak (uniform in ``gray``), a size
(``sigma_px`` ± 30 %), a row and a place along the line where it appears first. Where it first
appears fixes its spot on the target for the rest of its life. The events are drawn once for a
cycle of time and repeat after it (no recording is long enough to notice), from a stream of
their own per rig session: another run of the same rig glints at other instants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_EVENTS = 100_000  # events drawn per cycle: bounds memory on fast cameras
CYCLE_S = 600.0


@dataclass
class GlintConfig:
    probability: float = 0.0  # share of frames with a glint (0: none)
    gray_min: float = 80.0  # peak light added, gray (8-bit equivalent)
    gray_max: float = 200.0
    sigma_px: float = 1.5  # blob size (Gaussian σ) in pixels, each event ±30 %
    max_frames: int = 4  # an event lasts 1..max_frames frame periods
    seed: int = 0  # drawn from the rig's effect stream; the session (run) is mixed in by the rig


class Glints:
    """The glint events of one rig session and the light they add to frames."""

    def __init__(self, cfg: GlintConfig, rng: np.random.Generator, frame_rate_hz: float, n_rows: int):
        self.cfg = cfg
        frame_s = 1.0 / frame_rate_hz
        mean_s = 0.5 * (1 + cfg.max_frames) * frame_s
        # share of frames covered by a Poisson process of events of mean length mean_s: 1 − e^{−λ·mean_s}
        rate = -math.log(1.0 - min(cfg.probability, 0.999)) / mean_s
        self.cycle_s = min(CYCLE_S, MAX_EVENTS / rate)
        count = int(rng.poisson(rate * self.cycle_s))
        self.start_s = np.sort(rng.uniform(0.0, self.cycle_s, count))
        self.end_s = self.start_s + rng.integers(1, cfg.max_frames + 1, count) * frame_s
        self.peak = rng.uniform(cfg.gray_min, cfg.gray_max, count)
        self.sigma = cfg.sigma_px * rng.uniform(0.7, 1.3, count)
        self.row = rng.uniform(0.0, n_rows - 1, count) if n_rows > 1 else np.zeros(count)
        self.place = rng.uniform(0.0, 1.0, count)  # along the line, where it first shows
        self.longest_s = cfg.max_frames * frame_s
        self.spot_mm: dict[tuple[int, int], float] = {}  # (cycle, event) → its target coordinate, once shown

    def active(self, t_s: float) -> tuple[int, np.ndarray]:
        """(cycle number, indices of the events lit at instant ``t_s``)."""
        cycle, t = divmod(t_s, self.cycle_s)
        lo = np.searchsorted(self.start_s, t - self.longest_s, side="right")
        hi = np.searchsorted(self.start_s, t, side="right")
        candidates = np.arange(lo, hi)
        return int(cycle), candidates[self.end_s[candidates] > t]

    def _forget_before(self, t_s: float) -> None:
        """Drop the spots of events long over (a daemon renders for hours)."""
        if len(self.spot_mm) > 256:
            self.spot_mm = {key: spot for key, spot in self.spot_mm.items()
                            if key[0] * self.cycle_s + self.end_s[key[1]] > t_s - 1.0}

    def add_light(self, light: np.ndarray, t_s: np.ndarray, x_mm: np.ndarray, pixel_x_mm: np.ndarray,
                  pitch_mm: float) -> None:
        """Add the glints lit at each frame's instant to ``light`` ``(K, R, n)`` in place; ``x_mm``
        ``(K,)`` is the stage during each exposure, ``pixel_x_mm`` ``(R, n)`` what target offset each
        pixel sees."""
        rows = np.arange(light.shape[1])[:, None]
        n_pixels = light.shape[2]
        for k, (t, x) in enumerate(zip(np.asarray(t_s, dtype=np.float64), np.asarray(x_mm, dtype=np.float64))):
            cycle, lit = self.active(float(t))
            for event in lit.tolist():
                spot = self.spot_mm.get((cycle, event))
                if spot is None:  # first seen now: pinned to the print where it shows
                    self._forget_before(float(t))
                    r = int(round(self.row[event]))
                    spot = self.spot_mm[(cycle, event)] = x + float(np.interp(self.place[event] * (n_pixels - 1),
                                                                     np.arange(n_pixels), pixel_x_mm[r]))
                across = (x + pixel_x_mm - spot) / pitch_mm
                d2 = across**2 + (rows - self.row[event]) ** 2
                light[k] += self.peak[event] * np.exp(-0.5 * d2 / self.sigma[event] ** 2)
