"""A stage resting after the daemon's quick calibration (21 stops of 3 frames, the paper model): the
model's own stretch at the place it rests (core/stretch_place.py) is no magnification; a lens that
really changes while it rests still is. Both tracked as the daemon tracks (its scale watch carries
the magnification watch: service/daemon/trim.py), from the same rig's later run (fresh noise)."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.core.tracking import LiveTracker
from graytrack.core.watches.scale import ScaleWatch
from graytrack.drivers.sim.scenarios import build_rig

FRAME_RATE_HZ = 20.0
REST_MM = (1.0, 5.0)  # places where the model's own stretch reads ±800-1300 ppm, 4-5 σ of a 50-frame mean's noise


def at_rest(rig, x_mm: float, n: int) -> np.ndarray:
    return rig.render(np.full(n, x_mm), np.arange(n) / FRAME_RATE_HZ)


@pytest.fixture(scope="module")
def model():
    rig = build_rig("paper", seed=0)
    x = np.repeat(np.linspace(0.1, 10.36, 21), 3)
    t = np.arange(x.size) / FRAME_RATE_HZ
    step = rig.config.grating.resolution_mm
    recording = Recording(rig.render(x, t)[:, 0, :], t,
                          np.round(x / step) * step, rig.meta())
    return calibrate(recording, "paper").model


def reasons(model, rig, x_mm: float, n: int) -> collections.Counter:
    tracker = LiveTracker(model, x_mm, watches=[ScaleWatch.for_model(model)])
    frames = at_rest(rig, x_mm, n)
    return collections.Counter(fix.stale_reason for fix in (tracker.update(frame, x_mm) for frame in frames))


@pytest.mark.parametrize("x_mm", REST_MM)
def test_a_steady_stage_at_rest_is_not_flagged(model, x_mm):
    seen = reasons(model, build_rig("paper", seed=0, run=1), x_mm, 200)
    assert seen[None] == 200, seen  # before: magnification on 165 and 54 of these 200 frames


def test_a_lens_changing_while_the_stage_rests_is_still_named(model):
    rig = build_rig("paper", "magnification_drift:ppm=8000:ramp_s=4:axis_px=0", seed=0, run=1)
    seen = reasons(model, rig, 5.0, 200)
    assert seen["magnification"] > 60, seen
