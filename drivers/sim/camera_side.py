"""The camera's side of the rig: what changes during a run in front of the sensor, fixed to its pixels.

Dust on the print (target.py) rides past the camera with the stage. Whatever sits on the camera's
side does not: a speck of dust on the window in front of the sensor (its cover glass, or a
protective window before the lens), a veil on that window, the lens's own vignetting. Each stays on
the same pixels whatever the stage does. That is the one thing that tells such a mark from the
print's texture, and only motion shows it: while the stage stands still a speck on the window and
one on the print look the same.

- **Window dust.** The window is far out of focus, so a speck there is no sharp dot but a soft
  shadow of the light cone each pixel receives: a Gaussian blob over rows and pixels, a pixel or
  two wide, that takes a share (its depth) of the light at its centre. Specks land at random
  instants and stay to the end of the run. With ``at_rest`` a speck lands only on a frame taken
  while the stage stands still (:data:`REST_SPEED_MM_S`): the first such frame at or after its own
  instant. Which frames those are depends on the motion the rig is asked to render, so the landing
  instants are decided as frames are rendered, in the rig's order (a rig is deterministic under its
  seed in the order it renders, as its noise is); once decided they never change.
- **Veil.** Condensation on a cold window, or a film of oil: it arrives over ``rise_s`` and stays.
  Over the pixels it covers it takes a share of the light (its depth) and scatters some of the
  lamp's light into them (an additive gray, so it dims and flickers with the lamp), with a soft
  edge (the window is out of focus).
- **A vignetting change.** The lens's aperture knocked or a lamp on the camera moved after
  calibration: each pixel's gain changes by ``−delta·ρ²`` (ρ: the radius over the sensor's
  half-width, as for ``vignetting``), ramped in and then kept.

All three act on the light reaching the sensor, before the lamp's flicker and level change scale
it (:meth:`CameraSide.apply`): the rig's batch render and the live camera's one-frame render call
the same method, so their frames agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graytrack.drivers.sim.illumination import ramp_share

# Below this speed the stage stands still: a settled servo's residual ring decays within
# milliseconds to far less, while any commanded move (µm/s and up) or a vibration is far above it.
REST_SPEED_MM_S = 1e-3
SPECK_REACH_SIGMAS = 6.0  # a speck's blob is evaluated this far from its centre (beyond: 1.5e-8 of its depth)
MARKED_SHARE = 0.01  # the truth names a pixel marked by a speck when it loses this share of the speck's depth
MAP_CACHE = 64  # distinct sets of landed specks whose gain maps are kept (a run sees count + 1 of them)


@dataclass
class WindowSpeck:
    """A speck of dust on the camera's window: centre at (``row``, ``pixel``) as fractions of the ROI's
    height and width (so the ROI's shape may be set after it), Gaussian ``sigma_px`` pixels, taking
    ``depth`` of the light at its centre, landing from ``from_s`` on (see ``at_rest``)."""

    row: float
    pixel: float
    sigma_px: float
    depth: float
    from_s: float


@dataclass
class VeilConfig:
    """A veil on the window over the ``cover`` share of the line at one end (``side`` 0: from pixel 0,
    1: from the last pixel), arriving at ``start_s`` over ``rise_s``; depth 0 and no scatter: none."""

    depth: float = 0.0  # share of the light it takes where it covers
    scatter_gray: float = 0.0  # the lamp's light it scatters into the pixels it covers, gray
    cover: float = 0.0  # share of the line's pixels under it, 0..1
    side: int = 1
    edge_px: float = 0.0  # width of its soft edge (a cosine taper), pixels
    start_s: float = 0.0
    rise_s: float = 0.0

    @property
    def active(self) -> bool:
        return self.cover > 0.0 and (self.depth != 0.0 or self.scatter_gray != 0.0)

    def mask(self, n_pixels: int) -> np.ndarray:
        """``(n,)`` how much of the veil each pixel is under, 0..1 (0.5 at its edge's middle)."""
        u = np.arange(n_pixels, dtype=np.float64)
        if self.side:
            u = u[::-1]
        inside = self.cover * n_pixels - 0.5 - u  # pixels inside the edge, > 0 under the veil
        if self.edge_px <= 0.0:
            return (inside >= 0.0).astype(np.float64)
        z = np.clip(inside / self.edge_px, -0.5, 0.5)
        return 0.5 + 0.5 * np.sin(math.pi * z)


@dataclass
class CameraSideConfig:
    """What changes on the camera's side during a run (module docstring); empty: nothing."""

    specks: list[WindowSpeck] = field(default_factory=list)
    at_rest: bool = False  # specks land only on frames taken while the stage stands still
    veil: VeilConfig = field(default_factory=VeilConfig)
    vignetting_delta: float = 0.0  # change of the gain at the sensor's half-width (−delta·ρ²)
    vignetting_start_s: float = 0.0
    vignetting_ramp_s: float = 0.0

    @property
    def active(self) -> bool:
        return bool(self.specks) or self.veil.active or self.vignetting_delta != 0.0


def stage_speed(xs: np.ndarray, exposure_s: float) -> np.ndarray:
    """``(K,)`` the stage's largest speed (mm/s) between the positions sampled evenly over each
    exposure, ``xs`` ``(K, S)``; one sample (or no exposure): the caller's still stage, 0."""
    if xs.shape[1] < 2 or not exposure_s > 0:
        return np.zeros(xs.shape[0])
    return np.abs(np.diff(xs, axis=1)).max(axis=1) * (xs.shape[1] - 1) / exposure_s


class CameraSide:
    """The camera-side changes of one rig (``R × n`` pixels), with the landing state of its specks."""

    def __init__(self, cfg: CameraSideConfig, n_rows: int, n_pixels: int, radius2: np.ndarray) -> None:
        self.cfg = cfg
        self.shape = (n_rows, n_pixels)
        specks = cfg.specks
        self.centres = [(-0.5 + s.row * n_rows, -0.5 + s.pixel * n_pixels) for s in specks]
        self.landed_s = np.array([np.nan if cfg.at_rest else s.from_s for s in specks], dtype=np.float64)
        self._from = np.array([s.from_s for s in specks], dtype=np.float64)
        self._blobs = [self._blob(s, centre) for s, centre in zip(specks, self.centres)]
        self._maps: dict[bytes, np.ndarray] = {}
        self._veil = cfg.veil.mask(n_pixels) if cfg.veil.active else None
        self._radius2 = np.asarray(radius2, dtype=np.float64)

    def _blob(self, speck: WindowSpeck, centre: tuple[float, float]) -> tuple[slice, np.ndarray]:
        """(the pixels it reaches, the share of the light it takes from each of them, ``(R, width)``)."""
        row, pixel = centre
        reach = SPECK_REACH_SIGMAS * speck.sigma_px
        lo, hi = max(0, math.floor(pixel - reach)), min(self.shape[1], math.ceil(pixel + reach) + 1)
        r = np.arange(self.shape[0], dtype=np.float64)[:, None] - row
        u = np.arange(lo, hi, dtype=np.float64)[None, :] - pixel
        return slice(lo, hi), speck.depth * np.exp(-(r * r + u * u) / (2.0 * speck.sigma_px ** 2))

    def _land(self, t: np.ndarray, rest: np.ndarray) -> None:
        """Specks waiting for a rest land on the earliest frame at rest at or after their instant."""
        waiting = np.flatnonzero(np.isnan(self.landed_s))
        still = t[rest]
        for j in waiting:
            later = still[still >= self._from[j]]
            if later.size:
                self.landed_s[j] = later.min()

    def _speck_gain(self, landed: np.ndarray) -> np.ndarray:
        """``(R, n)`` the light let through by the landed specks (a boolean per speck)."""
        key = np.packbits(landed).tobytes()
        gain = self._maps.get(key)
        if gain is None:
            gain = np.ones(self.shape)
            for j in np.flatnonzero(landed):
                cols, taken = self._blobs[j]
                gain[:, cols] *= 1.0 - taken
            if len(self._maps) >= MAP_CACHE:
                self._maps.clear()
            self._maps[key] = gain
        return gain

    def apply(self, light: np.ndarray, t_s: np.ndarray, xs: np.ndarray, exposure_s: float) -> None:
        """Darken (and veil) ``light`` ``(K, R, n)`` in place for frames at mid-exposure ``t_s`` ``(K,)``
        whose stage positions over the exposure are ``xs`` ``(K, S)``."""
        cfg = self.cfg
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if cfg.vignetting_delta:
            share = ramp_share(t, cfg.vignetting_start_s, cfg.vignetting_ramp_s)
            light *= np.maximum(1.0 - cfg.vignetting_delta * share[:, None, None] * self._radius2, 0.0)
        if self._blobs:
            if cfg.at_rest:
                self._land(t, stage_speed(xs, exposure_s) < REST_SPEED_MM_S)
            landed = self.landed_s[None, :] <= t[:, None]  # (K, count); not landed (NaN): False
            for k in range(t.size):
                if landed[k].any():
                    light[k] *= self._speck_gain(landed[k])
        if self._veil is not None:
            veil = cfg.veil
            share = ramp_share(t, veil.start_s, veil.rise_s)[:, None, None] * self._veil
            light *= 1.0 - veil.depth * share
            light += veil.scatter_gray * share

    def truth(self) -> dict[str, Any]:
        """What a scorer needs to know which pixels were marked when (JSON): per speck its centre in
        (row, pixel) coordinates of the ROI, σ, depth, the instant it could land from, the instant it
        landed (None: not yet) and the rows and pixels (first, last) it darkens by more than ``MARKED_SHARE``
        of its depth;
        the veil's covered pixels and when it began."""
        specks = []
        for speck, (row, pixel), landed in zip(self.cfg.specks, self.centres, self.landed_s):
            reach = speck.sigma_px * math.sqrt(-2.0 * math.log(MARKED_SHARE))
            span = [[max(0, math.ceil(c - reach)), min(size - 1, math.floor(c + reach))]
                    for c, size in zip((row, pixel), self.shape)]
            specks.append({"row": row, "pixel": pixel, "sigma_px": speck.sigma_px, "depth": speck.depth,
                           "from_s": speck.from_s, "landed_s": None if math.isnan(landed) else float(landed),
                           "rows": span[0], "pixels": span[1]})
        out: dict[str, Any] = {"window_specks": specks, "at_rest": self.cfg.at_rest}
        if self._veil is not None:
            covered = np.flatnonzero(self._veil > MARKED_SHARE)
            out["veil"] = {"pixels": [int(covered.min()), int(covered.max())] if covered.size else None,
                           "start_s": self.cfg.veil.start_s, "rise_s": self.cfg.veil.rise_s}
        return out
