"""Measurement helpers for the virtual rig's signature tests (noise-free renders of a pure sine)."""

from __future__ import annotations

import math

import numpy as np

from graytrack.drivers.sim.rig import VirtualRig
from graytrack.drivers.sim.scenarios import build_rig


def quiet_rig(scenario: str = "clean", effects=(), seed: int = 0) -> VirtualRig:
    """A rig without read noise, so that a test sees the effect alone."""
    return build_rig(scenario, ["read_noise:gray=0", *effects], seed=seed)


def light(rig: VirtualRig, x_mm, t_s=None) -> np.ndarray:
    """Noise-free light ``(K, R, n)`` with the stage still at each position."""
    x = np.atleast_1d(np.asarray(x_mm, dtype=float))
    t = np.zeros_like(x) if t_s is None else np.atleast_1d(np.asarray(t_s, dtype=float))
    return rig.render_light(x, t)


def pixel_phase(rig: VirtualRig, x_mm: float, amplitude: float = 80.0, offset: float = 128.0) -> np.ndarray:
    """Unwrapped target phase θ seen by each pixel ``(R, n)`` of a pure-sine rig at stage ``x_mm``.

    sin θ = (L − D)/A from the value; the sign of cos θ from the slope along the stage (which does
    not depend on how fast the phase advances, so a chirped print is measured correctly too).
    """
    h = 1e-5
    values = light(rig, [x_mm - h, x_mm, x_mm + h])
    sine = np.clip((values[1] - offset) / amplitude, -1.0, 1.0)
    cosine = np.sign(values[2] - values[0]) * np.sqrt(1.0 - sine * sine)
    theta = np.arctan2(sine, cosine)
    return np.unwrap(theta, axis=-1)


def sine_fit(samples: np.ndarray, phase: np.ndarray) -> tuple[float, float, float]:
    """Least-squares ``y = a sin φ + b cos φ + d``: returns (amplitude, phase offset, offset)."""
    design = np.stack([np.sin(phase), np.cos(phase), np.ones_like(phase)], axis=-1)
    (a, b, d), *_ = np.linalg.lstsq(design, samples, rcond=None)
    return float(math.hypot(a, b)), float(math.atan2(b, a)), float(d)


def harmonic_amplitudes(profile: np.ndarray) -> np.ndarray:
    """Amplitudes of orders 0..N/2 of a profile sampled evenly over exactly one period."""
    spectrum = np.fft.rfft(profile) / profile.size
    amps = 2 * np.abs(spectrum)
    amps[0] /= 2
    return amps


def one_period(rig: VirtualRig, n: int = 128, pixel: int = 0, x0: float = 1.0) -> np.ndarray:
    """Light of one pixel over exactly one true period of stage motion."""
    tau = rig.config.target.true_period_mm
    x = x0 + tau * np.arange(n) / n
    return light(rig, x)[:, 0, pixel]
