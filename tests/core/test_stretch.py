"""A frame's stretch across the pixels (a magnification change), with an honest standard error,
and the watch that names ``magnification`` from it."""

from __future__ import annotations

import math

import numpy as np

from graytrack.core.stretch import stretch
from graytrack.core.validity import FAMILIES, FrameSign
from graytrack.core.watches.magnification import MagnificationWatch

PERIOD, PITCH, NOISE = 8.62, 0.062, 0.7
OFFSETS = PITCH * np.arange(100.0)


def _frame(x: float, m: float, rng: np.random.Generator):
    """The model's values and slopes at x, and a frame whose image is stretched by m about the axis
    20 mm off (so it slides too: the solve's position takes that)."""
    phase = 2 * math.pi / PERIOD
    values = 128.0 + 80.0 * np.sin(phase * (x + OFFSETS))
    slopes = 80.0 * phase * np.cos(phase * (x + OFFSETS))
    seen = x + OFFSETS + m * (OFFSETS - 20.0)
    frame = 128.0 + 80.0 * np.sin(phase * seen) + rng.normal(0.0, NOISE, OFFSETS.size)
    return values, slopes, frame - values


def test_the_stretch_is_recovered_within_its_stated_standard_error():
    rng = np.random.default_rng(1)
    weights = np.full(OFFSETS.size, NOISE ** -2)
    pulls, sigmas = [], []
    for x in rng.uniform(0.0, 50.0, 300):
        values, slopes, residual = _frame(x, 0.0, rng)
        m, sigma = stretch(values, slopes, residual, weights, OFFSETS)
        pulls.append(m / sigma)
        sigmas.append(sigma)
    assert abs(np.mean(pulls)) < 0.2 and 0.85 < np.std(pulls) < 1.15
    stretched = []
    for x in rng.uniform(0.0, 50.0, 300):
        values, slopes, residual = _frame(x, 2000e-6, rng)
        stretched.append(stretch(values, slopes, residual, weights, OFFSETS))
    m, sigma = np.array(stretched).T
    mean = np.sum(m / sigma ** 2) / np.sum(sigma ** -2)
    assert abs(mean - 2000e-6) < 4.0 / math.sqrt(np.sum(sigma ** -2)) + 50e-6  # the linearisation's own error


def test_the_watch_names_magnification_on_a_drift_and_stays_quiet_on_a_steady_run():
    assert "magnification" in FAMILIES
    rng = np.random.default_rng(2)
    weights = np.full(OFFSETS.size, NOISE ** -2)

    def run(m_of_k, n: int) -> list[str | None]:
        watch = MagnificationWatch(PERIOD)
        verdicts = []
        for k in range(n):
            x = float(rng.uniform(0, 50))
            values, slopes, residual = _frame(x, m_of_k(k), rng)
            measured = stretch(values, slopes, residual, weights, OFFSETS)
            verdicts.append(watch.observe(FrameSign(k, x_mm=x, stretch=lambda: measured)))
        return verdicts

    assert not any(run(lambda k: 0.0, 600))
    ramp = run(lambda k: 3000e-6 * k / 400, 400)
    assert set(ramp[200:]) == {"magnification"} and not any(ramp[:20])
