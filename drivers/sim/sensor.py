"""The image sensor: fixed-pattern gain and offset, shot and read noise, gamma, saturation, bits.

Gray levels inside the simulation are "8-bit-equivalent": 255 is full scale whatever the bit depth,
so scenes and noise figures read the same for 8- and 12-bit cameras. The output is quantised to
``bit_depth`` bits (``round(gray · 2^(bits−8))``, stored as uint8/uint16), or left as float32 when
``bit_depth`` is None — the ``paper`` scenario does that, because the paper's Table 2 describes a
gray field with Gaussian noise, not a digitiser.

Order of operations follows the signal: light × PRNU → electrons (shot noise) → + DSNU and read
noise → camera gamma → clip at full scale → quantise. PRNU and DSNU belong to physical pixels of
the full sensor (a pattern fixed to the pixels, whatever the ROI and the scene).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from graytrack.drivers.sim import jpeg

FULL_SCALE_GRAY = 255.0


@dataclass
class SensorConfig:
    bit_depth: int | None = None  # None: float32 output, no quantisation
    read_noise_gray: float = 0.7  # Gaussian, per pixel per frame
    full_well_e: float | None = None  # electrons at full scale; None: no shot noise
    prnu_sigma: float = 0.0  # relative per-pixel gain spread
    dsnu_sigma_gray: float = 0.0  # per-pixel offset spread
    black_level_gray: float = 0.0
    gain: float = 1.0  # analog gain in front of the clip (saturation)
    gamma: float = 1.0  # camera output gamma
    clip: bool = False  # clip at [0, full scale] (always on when quantising)
    bad_pixels: list["BadPixel"] = field(default_factory=list)
    row_noise_gray: float = 0.0  # banding: a per-frame offset common to each row, std (gray)
    gain_hunt_depth: float = 0.0  # auto-gain hunting: relative swing of the camera gain
    gain_hunt_hz: float = 1.0  # how fast the auto gain hunts
    gain_hunt_step: float = 0.0  # the gain moves in steps of this (relative; 0: smoothly)
    gain_hunt_phase_rad: float = 0.0
    lsb_shift: int = 0  # data left-aligned in a wider word (Mono12 in 16 bits: 4); quantises at bit_depth − shift
    jpeg_quality: int = 0  # an MJPEG stream: each 8-bit frame through JPEG at this quality (0: none)


@dataclass
class BadPixel:
    """A defective pixel of the ROI (row, pixel), from time ``start_s`` on (8-bit-equivalent gray).

    ``stuck`` reads ``value`` whatever the light (255: stuck high, 0: dead); ``hot`` adds ``value``
    (a large dark-current offset); ``noisy`` adds Gaussian noise of standard deviation ``value``;
    ``telegraph`` (random telegraph signal, a charge trap) adds ``value`` while it is "up", flipping
    at the instants ``switch_s`` (a Poisson process drawn once, repeating every ``cycle_s``).
    """

    kind: str  # "stuck" | "hot" | "noisy" | "telegraph"
    row: int
    pixel: int
    value: float
    start_s: float = 0.0
    switch_s: tuple[float, ...] = ()  # telegraph: instants it flips, repeating every ``cycle_s``
    cycle_s: float = 0.0


class Sensor:
    """A sensor with its fixed patterns drawn once (from ``rng``) for the ROI's full-frame pixels."""

    def __init__(self, cfg: SensorConfig, full_r: np.ndarray, full_u: np.ndarray, full_shape: tuple[int, int],
                 rng: np.random.Generator):
        self.cfg = cfg
        rows, cols = full_r.astype(int), full_u.astype(int)
        shape = full_shape
        self.prnu = np.ones(rows.shape)
        self.dsnu = np.zeros(rows.shape)
        # patterns for the full frame, then the ROI's pixels: the same physical pixel keeps its value
        gain_pattern = rng.standard_normal(shape)
        offset_pattern = rng.standard_normal(shape)
        if cfg.prnu_sigma:
            self.prnu = 1.0 + cfg.prnu_sigma * gain_pattern[rows, cols]
        if cfg.dsnu_sigma_gray:
            self.dsnu = cfg.dsnu_sigma_gray * offset_pattern[rows, cols]

    @property
    def output_dtype(self) -> np.dtype:
        bits = self.cfg.bit_depth
        if bits is None:
            return np.dtype(np.float32)
        return np.dtype(np.uint8) if bits <= 8 else np.dtype(np.uint16)

    def expose(self, light_gray: np.ndarray, rng: np.random.Generator | None,
               t_s: np.ndarray | None = None) -> np.ndarray:
        """Frames from the light reaching each pixel ``(K, R, n)``; ``rng=None`` means noise-free.
        ``t_s`` ``(K,)`` (exposure instants) decides which bad pixels have gone bad yet.

        Works in float32 (resolution 2e-5 gray at full scale, far below any noise here): the
        noise draws and the arithmetic are what bound the render speed.
        """
        cfg = self.cfg
        signal = np.asarray(light_gray, dtype=np.float32)
        gain = (self.prnu * cfg.gain).astype(np.float32)
        signal = signal * gain if (cfg.prnu_sigma or cfg.gain != 1.0) else signal.copy()
        if cfg.gain_hunt_depth and t_s is not None:
            signal *= hunting_gain(cfg, np.asarray(t_s, dtype=np.float64)).astype(np.float32)[:, None, None]
        if rng is not None and cfg.full_well_e:
            # Poisson in electrons, Gaussian approximation: var(gray) = gray · 255 / full_well
            shot = np.sqrt(np.maximum(signal, 0.0) * np.float32(FULL_SCALE_GRAY / cfg.full_well_e))
            signal += shot * rng.standard_normal(signal.shape, dtype=np.float32)
        if cfg.dsnu_sigma_gray or cfg.black_level_gray:
            signal += (self.dsnu + cfg.black_level_gray).astype(np.float32)
        if rng is not None and cfg.read_noise_gray:
            noise = rng.standard_normal(signal.shape, dtype=np.float32)
            noise *= np.float32(cfg.read_noise_gray)
            signal += noise
        if rng is not None and cfg.row_noise_gray:
            signal += np.float32(cfg.row_noise_gray) * rng.standard_normal(signal.shape[:2] + (1,), dtype=np.float32)
        if cfg.gamma != 1.0:
            full = np.float32(FULL_SCALE_GRAY)
            signal = full * (np.maximum(signal, 0.0) / full) ** np.float32(cfg.gamma)
        for bad in cfg.bad_pixels:
            _spoil(signal, bad, rng, t_s)
        if cfg.clip or cfg.bit_depth is not None:
            np.clip(signal, 0.0, FULL_SCALE_GRAY, out=signal)
        if cfg.bit_depth is None:
            return signal
        significant = cfg.bit_depth - cfg.lsb_shift
        scale = np.float32(2.0 ** (significant - 8))
        top = 2**significant - 1
        counts = np.clip(np.rint(signal * scale), 0, top).astype(self.output_dtype)
        if cfg.jpeg_quality:
            counts = jpeg.compress(counts, cfg.jpeg_quality)
        return counts << cfg.lsb_shift if cfg.lsb_shift else counts


def hunting_gain(cfg: SensorConfig, t_s: np.ndarray) -> np.ndarray:
    """Per-frame camera gain of an auto-gain loop that hunts: ``1 + depth·sin(2π f t + φ)``, moved in
    steps of ``gain_hunt_step`` when the camera's gain register is coarse (a real loop overshoots in
    discrete gain steps, frame after frame)."""
    gain = 1.0 + cfg.gain_hunt_depth * np.sin(2 * np.pi * cfg.gain_hunt_hz * t_s + cfg.gain_hunt_phase_rad)
    if cfg.gain_hunt_step > 0:
        gain = 1.0 + cfg.gain_hunt_step * np.round((gain - 1.0) / cfg.gain_hunt_step)
    return gain


def _spoil(signal: np.ndarray, bad: BadPixel, rng: np.random.Generator | None, t_s: np.ndarray | None) -> None:
    """Apply one bad pixel in place to frames ``(K, R, n)`` exposed at ``t_s``."""
    frames = np.ones(signal.shape[0], dtype=bool) if t_s is None else np.asarray(t_s) >= bad.start_s
    if not frames.any():
        return
    column = signal[:, bad.row, bad.pixel]
    if bad.kind == "stuck":
        column[frames] = bad.value
    elif bad.kind == "hot":
        column[frames] += np.float32(bad.value)
    elif bad.kind == "telegraph":
        t = np.zeros(signal.shape[0]) if t_s is None else np.asarray(t_s, dtype=np.float64)
        flips = np.searchsorted(np.asarray(bad.switch_s), np.mod(t, bad.cycle_s) if bad.cycle_s > 0 else t)
        column[frames & (flips % 2 == 1)] += np.float32(bad.value)
    elif rng is not None:  # noisy
        column[frames] += np.float32(bad.value) * rng.standard_normal(int(frames.sum()), dtype=np.float32)
    signal[:, bad.row, bad.pixel] = column
