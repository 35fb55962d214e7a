"""The camera knocked on its mount (drivers/sim/effects.py ``knock``): from its instant on, the image is
the one the stage would give ``um`` further along the axis (the carriage, and so the truth and the
grating, stay put), and a strip's rows turn against each other by the knock's angle; before it,
nothing changed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.drivers.sim.effects import EffectError
from graytrack.drivers.sim.scenarios import build_rig, list_effects

from .helpers import light, quiet_rig

KNOCK = "knock:um=40:deg=0:at_s=2"


def test_listed_with_its_parameters():
    assert "um=40" in list_effects()["knock"] and "at_s=2" in list_effects()["knock"]


def test_after_the_knock_the_image_is_the_stage_further_on_before_it_nothing_changed():
    knocked, plain = quiet_rig(effects=[KNOCK]), quiet_rig()
    x = 3.0
    np.testing.assert_allclose(light(knocked, [x], [1.9]), light(plain, [x], [1.9]), atol=1e-6)
    after = light(knocked, [x], [2.1])
    np.testing.assert_allclose(after, light(plain, [x + 0.040], [2.1]), atol=1e-6)
    assert np.max(np.abs(after - light(plain, [x], [2.1]))) > 0.5  # gray: 40 µm of a sine's slope


def test_a_strips_rows_turn_against_each_other_by_the_knocks_angle():
    deg = 0.5
    knocked, plain = quiet_rig("strip16", [f"knock:um=0:deg={deg}:at_s=0"]), quiet_rig("strip16")
    y = knocked.geometry.y_mm
    across = y - y.mean()
    seen = light(knocked, [4.0], [0.5])[0]
    for row in (0, 15):  # each row sees the target shifted by −y·sin(angle) along the axis
        shift = -float(np.mean(across[row])) * math.sin(math.radians(deg))
        np.testing.assert_allclose(seen[row], light(plain, [4.0 + shift], [0.5])[0][row], atol=1e-6)
    assert abs(float(np.mean(across[15]) - np.mean(across[0]))) > 0.5  # mm: the two rows are far apart


def test_the_carriage_and_the_grating_do_not_move():
    plain_run, plain_truth = build_rig("paper", "", seed=1, run=1).record(3.0)
    run, truth = build_rig("paper", KNOCK, seed=1, run=1).record(3.0)
    np.testing.assert_array_equal(truth.x_mm, plain_truth.x_mm)
    np.testing.assert_array_equal(run.reference, plain_run.reference)
    later = run.t >= 2.0
    assert np.abs(run.frames[later].astype(float) - plain_run.frames[later]).max() > 0.5


def test_a_negative_instant_is_refused():
    with pytest.raises(EffectError, match="at_s"):
        quiet_rig(effects=["knock:at_s=-1"])
