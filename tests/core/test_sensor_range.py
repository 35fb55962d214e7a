"""The camera's readout range: a sample at its floor or ceiling sits clipped and carries no position.

A camera whose gain was raised after calibration saturates on the print's bright bars where calibration's frames did
not; its recording states the range it reads out (its bit depth, or the clip of a float camera), and the estimator sets
those samples aside. Before, the model (calibrated on unclipped frames) stated no range, every bright bar was read as
the print's own, and the paper rig's run erred 86 (read) to 10,000 (a 16-row strip, image alone) of its noise floors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.calibration_data import sensor_range
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.recording import SENSOR_RANGE
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import estimator_figures, rig_model

pytestmark = pytest.mark.unit


def test_a_recording_states_its_range_by_its_clip_or_its_bit_depth():
    assert sensor_range({SENSOR_RANGE: [0, 255.0]}) == (0.0, 255.0)
    assert sensor_range({"bit_depth": 12}) == (0.0, 4095.0)
    assert sensor_range({SENSOR_RANGE: [16.0, 4000.0], "bit_depth": 12}) == (16.0, 4000.0)  # (what it clips at)
    for nonsense in ([255.0, 0.0], [0.0], ["0", "255"], [0.0, math.inf], [True, 255.0]):
        assert sensor_range({SENSOR_RANGE: nonsense}) is None, nonsense
    assert sensor_range({}) is None
    settings = EstimatorSettings().for_recording({"bit_depth": 8})
    assert (settings.sensor_floor_gray, settings.sensor_ceiling_gray) == (0.0, 255.0)
    assert math.isinf(EstimatorSettings().for_recording({}).sensor_ceiling_gray)


def test_the_virtual_float_camera_states_its_clip_only_where_it_clips():
    assert SENSOR_RANGE not in build_rig("paper", "", seed=3).meta()
    clipping = build_rig("paper", "saturation", seed=3).meta()
    assert clipping[SENSOR_RANGE] == [0.0, 255.0] and "bit_depth" not in clipping
    assert SENSOR_RANGE not in build_rig("paper", "quantize:bits=8", seed=3).meta()  # (its bit depth says it)


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_a_camera_saturating_since_calibration_is_tracked_from_its_unclipped_samples(scenario):
    model = rig_model(scenario)
    assert model.info.get("sensor_range_gray") is None  # calibration's frames: a float camera that did not clip
    run, truth = build_rig(scenario, "saturation", seed=3, run=1).record(10.0)
    clipped = float(np.mean(run.frames >= 255.0))
    assert clipped > 0.1  # (the gain 1.4: the print's bright bars at the ceiling)
    clean, clean_truth = build_rig(scenario, "", seed=3, run=1).record(10.0)  # the same motion, nothing clipped
    stated = EstimatorSettings().for_recording(run.meta)
    for grating in ("check", "none"):
        floor = estimator_figures(model, clean, clean_truth, grating)["std"]
        figures = estimator_figures(model, run, truth, grating, stated)
        assert figures["silent"] == 0 and figures["flagged"] < 0.01, (grating, figures)
        # (0.84-0.89 of the clean run's error: the gain raised the signal over the sensor's noise, and what it clipped
        # is set aside)
        assert figures["std"] < 1.1 * floor, (grating, figures, floor)
    # the run's range unread (as the model states none): the bright bars read as the print's, and the light's gain
    # found wrong with them (28-71 % of the frames flagged, frames lost)
    unread = estimator_figures(model, run, truth, "check")
    assert unread["flagged"] > 0.1 and not unread["std"] < 5.0 * floor, unread
