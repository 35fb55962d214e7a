"""The watches' compiled loops (core/watches/_kernels.py) against their Python ``step``, frame by
frame: the same flags and the same state, bit for bit."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from graytrack.core.reference_monitor import Line, ReferenceMonitor, follow
from graytrack.core.watches import _kernels

pytestmark = pytest.mark.skipif(not _kernels.COMPILED, reason="numba missing: the watches step in Python")


def drifting_run(n: int, seed: int, resolution_mm: float = 0.0):
    """Positions against a grating: noise, a scale drift from mid-run, outliers, a jump, gaps."""
    rng = np.random.default_rng(seed)
    reference = 5.0 + 4.0 * np.sin(np.linspace(0.0, 6.0, n))
    if resolution_mm:
        reference = np.round(reference / resolution_mm) * resolution_mm
    bound = 1e-4 * (1.0 + rng.random(n))
    drift = np.where(np.arange(n) > n // 2, 400e-6 * (reference - 5.0), 0.0)
    x = reference + rng.normal(size=n) * bound + drift
    x[rng.random(n) < 0.01] += 0.05  # outliers
    x[int(0.7 * n):int(0.7 * n) + 40] += 0.003  # a jump for a while: the window restarts
    reference[rng.random(n) < 0.02] = np.nan
    bound[rng.random(n) < 0.01] = 0.0
    feed = rng.random(n) < 0.95
    return x, reference, bound, feed


MONITORS = {
    "plain": lambda: ReferenceMonitor(5.0, 4.0),
    "small window": lambda: ReferenceMonitor(5.0, 4.0, window=60, min_frames=30, floor_um=0.05),
    "calibrated": lambda: ReferenceMonitor(5.0, 4.0, reference_sigma_mm=1e-3 / 12 ** 0.5, resolution_mm=1e-3,
                                           calibration_frames=300, calibration_x_std_mm=2.0,
                                           calibration_structure_um=0.1,
                                           calibration=Line(0.1, 20.0, (0.01, 0.001, 100.0), 5.0, 300, 5.2)),
    "trimmed": lambda: ReferenceMonitor(5.0, 4.0, calibration_frames=2, baseline=Line(-0.2, -50.0, (0.02, 0.0, 50.0), 5.0)),
}


def state(monitor: ReferenceMonitor) -> dict:
    return copy.deepcopy({f.name: getattr(monitor, f.name) for f in dataclasses.fields(monitor)})


@pytest.mark.parametrize("name", MONITORS)
@pytest.mark.parametrize("n", [5, 3000, 9000])
def test_reference_monitor_many_frames_at_once_as_frame_by_frame(monkeypatch, name, n):
    x, reference, bound, feed = drifting_run(n, n, resolution_mm=1e-3 if name == "calibrated" else 0.0)
    compiled, stepped = MONITORS[name](), MONITORS[name]()
    rises_compiled, rises_stepped = [], []
    flags = compiled.observe_many(x, reference, bound, feed, on_rise=lambda k: rises_compiled.append((k, state(compiled))))
    monkeypatch.setattr(_kernels, "COMPILED", False)
    expected = stepped.observe_many(x, reference, bound, feed, on_rise=lambda k: rises_stepped.append((k, state(stepped))))
    assert np.array_equal(flags, expected)
    assert state(compiled) == state(stepped)
    assert [k for k, _ in rises_compiled] == [k for k, _ in rises_stepped]
    assert all(a == b for (_, a), (_, b) in zip(rises_compiled, rises_stepped))
    if n == 9000 and name in ("plain", "small window"):
        assert flags.any()  # the drift was seen: the comparison covered flagged frames


def test_follow_without_trim_as_frame_by_frame(monkeypatch):
    x, reference, bound, feed = drifting_run(4000, 7)
    fast = follow(ReferenceMonitor(5.0, 4.0), x, reference, bound, feed)
    monkeypatch.setattr(_kernels, "COMPILED", False)
    slow = follow(ReferenceMonitor(5.0, 4.0), x, reference, bound, feed)
    assert fast.events and fast.events == slow.events
    assert fast.final == slow.final
    for name in ("stale", "x_mm", "trim_um", "trim_sigma_um"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name))
