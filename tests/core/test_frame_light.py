"""An offset each frame draws afresh (core/adequacy.py frame_offset_gray): a one-row sensor's line offset at each
readout, its black level's reference drifting frame by frame. Calibration measures its σ from each frame's offset
against its neighbour's along the stroke; the estimator takes it out of each frame's solve as it takes a strip's
rows' offsets (core/estimator/kernel.py _normal) instead of letting a frame's own offset move the position through
the model's shape."""

from __future__ import annotations

import copy

import pytest

from graytrack.core.adequacy import frame_offset_gray
from graytrack.core.calibration import calibrate
from graytrack.core.calibration_data import calibration_data
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import calibrated_rig, estimator_figures

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def banded():
    """The paper rig's one row with its readout offset drawn afresh every frame (σ 1 gray), calibrated on one run
    and measured on another."""
    return calibrated_rig("paper", "row_banding:gray=1")


def test_the_frames_own_offset_is_measured_and_a_clean_rig_has_none(banded):
    model, calibration, _, _ = banded
    offset = frame_offset_gray(model, calibration_data(calibration))
    assert offset == pytest.approx(1.0, abs=0.15), offset  # the rig's banding: σ 1 gray (measured 1.03)
    assert model.info["frame_offset_gray"] == pytest.approx(offset, abs=1e-4)  # what calibration keeps
    for effects in ("", "gain_hunting:depth=0.05"):  # a gain swinging 5 % from frame to frame is not an offset
        clean, _ = build_rig("paper", effects, seed=3).record(20.0)
        assert "frame_offset_gray" not in calibrate(clean, "paper").model.info, effects


def test_the_estimator_takes_the_frames_own_offset_out_of_its_solve(banded):
    model, _, run, truth = banded
    without = copy.deepcopy(model)
    without.info.pop("frame_offset_gray")
    taken, left = estimator_figures(model, run, truth), estimator_figures(without, run, truth)
    # a frame's offset moved the position through the model's shape: 2.16 µm against 1.71 (today's path 1.75)
    assert taken["std"] < 0.85 * left["std"], (taken, left)
    assert 0.8 < taken["pull"] < 1.25 and taken["pull"] < left["pull"], (taken, left)  # the steady band (1.19 left)
    assert taken["flagged"] < 0.01, taken


def test_the_calibration_says_each_frame_draws_its_own_offset(banded):
    from graytrack.service.calibration_run import CalibrationRun

    model, _, _, _ = banded
    assert "an offset of 1.0" in model.describe()  # (1.03 gray)
    warnings = CalibrationRun("paper", model, {}, None, None).warnings()
    assert any("every frame is offset by 1.0" in line for line in warnings), warnings
