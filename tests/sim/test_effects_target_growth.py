"""Signature of the growing print: the printed phase stretched about a fixed point, in time, grating untouched."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.drivers.sim.effects import EffectError
from graytrack.drivers.sim.scenarios import build_rig

from .helpers import quiet_rig


def _phase_seen(rig, x_mm: float, t_s: float) -> np.ndarray:
    """The clean rig's target phase at every pixel (sin and cos from the pixel's value and slope)."""
    h = 1e-5
    values = rig.render_light(np.array([x_mm - h, x_mm, x_mm + h]), np.full(3, t_s))[:, 0, :]
    sine = np.clip((values[1] - 128.0) / 80.0, -1.0, 1.0)
    cosine = np.sign(values[2] - values[0]) * np.sqrt(1.0 - sine * sine)
    return np.unwrap(np.arctan2(sine, cosine))


def test_growth_stretches_the_print_about_its_point_from_its_start_over_its_ramp():
    ppm, start, ramp = 5000.0, 1.0, 2.0
    rig = quiet_rig(effects=[f"target_growth:ppm={ppm}:at=0.25:start_s={start}:ramp_s={ramp}"])
    still = quiet_rig()
    growth = rig.config.target.growths[0]
    tau = rig.config.target.true_period_mm
    x_w = 3.0 + rig.geometry.x_mm[0]
    for t, g in ((0.5, 0.0), (2.0, 0.5 * ppm * 1e-6), (9.0, ppm * 1e-6)):
        expected = 2 * math.pi * (growth.center_mm + (x_w - growth.center_mm) / (1 + g)) / tau
        seen = _phase_seen(rig, 3.0, t)
        offset = np.round((expected[0] - seen[0]) / (2 * math.pi)) * 2 * math.pi
        np.testing.assert_allclose(seen + offset, expected, atol=2e-6)
    # before its start the print is the one calibrated; after, it differs by ppm·(x − c) of phase
    np.testing.assert_allclose(rig.render_light(np.array([3.0]), np.array([0.5])),
                               still.render_light(np.array([3.0]), np.array([0.5])), atol=1e-9)


def test_growth_leaves_the_grating_alone_and_composes_with_a_second_session():
    rec0, truth0 = build_rig("paper", ["target_growth:ppm=250"], seed=3).record(2.0)
    rec1, truth1 = build_rig("paper", ["target_growth:ppm=250", "vibration:um=2"], seed=3, run=1).record(2.0)
    plain, _ = build_rig("paper", seed=3).record(2.0)
    np.testing.assert_array_equal(rec0.reference, plain.reference)  # the stage's scale never sees the print
    assert not np.array_equal(rec0.frames, plain.frames)
    assert not np.array_equal(rec1.frames[:5], rec0.frames[:5])
    assert truth1.info["effects"] == ["target_growth:ppm=250:at=0.5:start_s=0:ramp_s=0",
                                      "vibration:um=2:hz=180:phase_deg=-1"]


def test_growth_refuses_a_point_off_the_field_and_a_negative_ramp():
    with pytest.raises(EffectError, match="at must be"):
        build_rig("paper", ["target_growth:at=1.5"])
    with pytest.raises(EffectError, match="ramp_s"):
        build_rig("paper", ["target_growth:ramp_s=-1"])
