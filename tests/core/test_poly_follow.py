"""The trim's follower bends with a drift that comes and goes (core/poly_follow.py): a line over 20
frames lags a curve by twice its curvature times its memory squared; where its own predictions say
the drift curves, a quadratic follows instead, and a steady run or a ramp keeps the line."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.poly_follow import ChosenFollower, PolyFollower
from graytrack.core.reference_monitor import ReferenceMonitor, follow
from graytrack.core.trim_follow import Follower

BOUND_MM = 0.4e-3  # a 16-row strip's frame


def _slide(n: int, seed: int, kind: str):
    """The stage to and fro; camera − grating sliding as a lens's magnification does with its axis off
    the ROI: ±15 µm through a 300-frame temperature cycle, or 30 µm over a 500-frame ramp, or not."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    ref = 5.0 + 4.0 * np.sin(k / 60.0)
    slide_um = {"cycle": 15.0 * (1.0 - np.cos(2 * np.pi * k / 300.0)), "ramp": 30.0 * k / 500.0,
                "steady": np.zeros(n)}[kind]
    return ref + (slide_um + rng.normal(0.0, BOUND_MM * 1e3, n)) * 1e-3, ref


@pytest.mark.parametrize("seed", [0, 1])
def test_a_temperature_cycle_is_followed_at_the_bound_and_its_bound_is_not_widened(seed):
    """The line follower left 1.4 µm rms (3.5 bounds) over such a cycle, the trim's σ ~1 µm."""
    x, ref = _slide(600, seed, "cycle")
    followed = follow(ReferenceMonitor(5.0, 5.0), x, ref, np.full(x.size, BOUND_MM), trim=True)
    late = slice(100, None)
    error_um = (followed.x_mm - ref)[late] * 1e3
    bound_um = np.hypot(BOUND_MM * 1e3, followed.trim_sigma_um[late])
    assert np.sqrt(np.mean(error_um ** 2)) < 1.3 * BOUND_MM * 1e3
    assert np.sqrt(np.mean(bound_um ** 2)) < 1.5 * BOUND_MM * 1e3  # what the trim adds: its own, not the line's
    assert np.mean(np.abs(error_um) > 4.0 * bound_um) <= 0.005


@pytest.mark.parametrize("kind", ["ramp", "steady"])
def test_a_ramp_or_a_steady_run_keeps_the_line(kind):
    """The quadratic is noisier where nothing curves: its predictions err more, and the line answers
    (the same numbers as the line alone)."""
    x, ref = _slide(500, 2, kind)
    chosen, line = ChosenFollower(), Follower()
    for k in range(x.size):
        residual = (x[k] - ref[k]) * 1e3
        for follower in (chosen, line):
            follower.tick()
            follower.add(residual, (BOUND_MM * 1e3) ** 2)
        assert abs(chosen.now().correction_um - line.now().correction_um) < 1e-6 or chosen.chosen == 1
    assert chosen.chosen == 0


def test_the_polynomial_restates_its_evidence_when_the_trim_moves():
    follower = PolyFollower(2, 10.0)
    for _ in range(200):
        follower.tick()
        follower.add(2.0, 1.0)
    before = follower.estimate()[0]
    follower.shift(1.5)
    assert abs(before - 2.0) < 1e-9 and abs(follower.estimate()[0] - 0.5) < 1e-9
