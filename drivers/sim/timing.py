"""Frame timing: the frame clock, the exposure window, jitter, skew and dropped frames.

Four instants matter per frame and the simulation keeps them apart:

* the nominal frame clock ``k / f`` (what triggers the camera and latches the grating),
* the true exposure mid-point (nominal + trigger jitter) — what the image shows,
* the grating latch (nominal + a fixed skew) — what the reference shows,
* the recorded timestamp (true mid-exposure + timestamp noise) — what ``t`` in the file says.

With everything ideal all four coincide. Trigger jitter or skew make the image and the reference
describe different instants, so the reference error is ``v·Δt``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class TimingConfig:
    frame_rate_hz: float = 50.0
    exposure_s: float = 0.001
    t0_s: float = 0.0
    trigger_jitter_s: float = 0.0  # std of the exposure instant about the frame clock
    timestamp_jitter_s: float = 0.0  # std of the recorded timestamp about the true exposure
    latch_skew_s: float = 0.0  # grating latch minus exposure mid-point (constant)
    drop_probability: float = 0.0  # chance that a frame never arrives
    duplicate_probability: float = 0.0  # chance that the driver delivers the previous image again
    clock_ppm: float = 0.0  # the camera's clock runs fast by this against the reference's
    line_time_s: float = 0.0  # a rolling shutter: each row exposed this much after the one above


@dataclass
class FrameClock:
    """Per-frame instants ``(K,)`` of one recording (K counts dropped frames too)."""

    nominal: np.ndarray
    exposure_mid: np.ndarray
    latch: np.ndarray
    stamp: np.ndarray
    kept: np.ndarray  # bool: frame delivered


def frame_clock(cfg: TimingConfig, seconds: float, rng: np.random.Generator) -> FrameClock:
    """All the instants of a recording of ``seconds`` (at least one frame)."""
    n = max(int(round(seconds * cfg.frame_rate_hz)), 1)
    nominal = cfg.t0_s + np.arange(n) / cfg.frame_rate_hz
    # always draw, so that switching one effect on does not reshuffle the others' randomness
    trig, stamp_noise, drops = rng.standard_normal(n), rng.standard_normal(n), rng.random(n)
    # A camera's frames never swap places: offsets stay within half a period either side (a
    # no-op for any jitter small against the period), so recorded times always increase.
    half = 0.49 / cfg.frame_rate_hz
    exposure_mid = nominal + np.clip(cfg.trigger_jitter_s * trig, -half, half)
    stamp = nominal + np.clip(exposure_mid - nominal + cfg.timestamp_jitter_s * stamp_noise, -half, half)
    # A free-running camera on its own clock: its frames fall ever later (or earlier) against the
    # reference's clock, which latches the grating; its timestamps count its own clock.
    exposure_mid = exposure_mid + cfg.clock_ppm * 1e-6 * (nominal - cfg.t0_s)
    kept = drops >= cfg.drop_probability
    if not kept.any():
        kept[0] = True
    return FrameClock(
        nominal=nominal,
        exposure_mid=exposure_mid,
        latch=nominal + cfg.latch_skew_s,
        stamp=stamp,
        kept=kept,
    )
