"""How fast the light's gain walks from frame to frame (core/adequacy.py frame_gain_rate): a camera hunting its
exposure steps its gain by a percent between frames, a regulated lamp holds it for minutes. Calibration measures the
walk from each frame's gain by how the square of the difference between two frames grows with the time between
them (what is drawn afresh each frame or belongs to the place a frame sees does not grow); the estimator's light then
drifts at least that fast, where held to the declared drift each step went into the position."""

from __future__ import annotations

import copy

import pytest

from graytrack.core.adequacy import FRAME_GAIN_RATE, frame_gain_rate
from graytrack.core.calibration_data import calibration_data
from graytrack.core.estimator.settings import TUNABLES
from tests.conftest import calibrated_rig, estimator_figures, rig_model

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def hunting():
    """The paper rig's camera hunting its gain (5 % swings in 1 % steps at 1.5 Hz), calibrated on one run and
    measured on another."""
    return calibrated_rig("paper", "gain_hunting:depth=0.05")


def test_a_hunting_gain_is_measured_and_kept_with_the_model(hunting):
    model, calibration, _, _ = hunting
    rate = frame_gain_rate(model, calibration_data(calibration))
    # steps of 1 % on most frames at 50 frames/s: a walk of some 0.1 per √s, twenty times the drift a lamp is
    # declared to have (measured 0.12)
    assert rate is not None and 0.05 < rate < 0.3, rate
    assert rate > 10 * TUNABLES["gain_rate"].default
    assert model.info[FRAME_GAIN_RATE] == pytest.approx(rate, abs=1e-5)
    assert "the gain walking" in model.describe()


@pytest.mark.parametrize("scenario, effects", [
    ("paper", ""),  # a lamp that holds
    ("paper", "flicker:mains_hz=50:depth=0.05"),  # a flicker the estimator has states for
    ("paper", "dust:count=6"),  # the print's marks: what a frame's gain takes up belongs to its place
])  # (the lab strip at 200 frames/s, whose 100 Hz flicker alternates from frame to frame, measures none on the
# sweep's calibration and 0.006 /√s on a 3 s one, near the declared drift: docs/robustness.md)
def test_a_light_that_holds_flickers_or_meets_the_prints_marks_walks_as_a_lamp_is_declared_to(scenario, effects):
    rate = rig_model(scenario, effects).info.get(FRAME_GAIN_RATE)
    # none measured, or of the declared drift's order; a hunting camera's is twenty times it
    assert rate is None or rate < 2 * TUNABLES["gain_rate"].default, (scenario, effects, rate)


def test_the_estimator_lets_a_hunting_gain_move_and_keeps_the_position(hunting):
    model, _, run, truth = hunting
    held = copy.deepcopy(model)
    held.info.pop(FRAME_GAIN_RATE)
    walking, declared = estimator_figures(model, run, truth), estimator_figures(held, run, truth)
    # each 1 % step the light held to its declared drift took into the position: 2.65 µm against 2.23 (today's
    # path, its light solved free on every frame, 2.16)
    assert walking["std"] < 0.9 * declared["std"], (walking, declared)
    assert 0.8 < walking["pull"] < 1.25 and walking["flagged"] < 0.01, walking


def test_the_calibration_says_the_camera_hunts(hunting):
    from graytrack.service.calibration_run import CalibrationRun

    model, _, _, _ = hunting
    warnings = CalibrationRun("paper", model, {}, None, None).warnings()
    assert any("gain walks" in line and "auto-exposure off" in line for line in warnings), warnings
