"""The camera's readout range: a sample at its floor or ceiling sits clipped and carries no position.

A camera whose gain was raised after calibration saturates on the print's bright bars where calibration's frames did
not; its recording states the range it reads out (its bit depth, or the clip of a float camera), and the estimator sets
those samples aside. Before, the model (calibrated on unclipped frames) stated no range, every bright bar was read as
the print's own, and the paper rig's run erred 86 (read) to 10,000 (a 16-row strip, image alone) of its noise floors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.calibration_data import readout_mismatch, sensor_range
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.models import save_model
from graytrack.core.recording import SENSOR_RANGE, save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.cli import main
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


def test_a_recording_read_out_on_another_range_than_the_models_is_refused(tmp_path, capsys):
    """A camera set to 12 bits since its 8-bit calibration: its gray values are 16 times the model's, which either
    engine would take for a light changed past anything a lamp does. The command refuses it with the cause and the
    fix; the same bit depth, or a recording or model that states none, passes."""
    assert readout_mismatch({"sensor_range_gray": [0.0, 255.0]}, {"bit_depth": 8}) is None
    assert readout_mismatch({}, {"bit_depth": 12}) is None and readout_mismatch({"sensor_range_gray": [0, 255]}, {}) \
        is None
    said = readout_mismatch({"sensor_range_gray": [0.0, 255.0]}, {"bit_depth": 12})
    assert said is not None and "0-255" in said and "0-4095" in said
    calibration, _ = build_rig("paper", "quantize:bits=8", seed=3).record(10.0)
    model = calibrate(calibration, "paper").model
    assert model.info["sensor_range_gray"] == [0.0, 255.0]
    model_path = tmp_path / "model.json"
    save_model(model, model_path)
    for bits, refused in ((12, True), (8, False)):
        run, _ = build_rig("paper", f"quantize:bits={bits}", seed=3, run=1).record(2.0)
        run_path, out = save(run, tmp_path / f"run{bits}.npz"), tmp_path / f"t{bits}.csv"
        for engine in ("watches", "estimator"):
            code = main(["track", str(run_path), "--model", str(model_path), "--engine", engine, "--out", str(out)])
            assert code == (2 if refused else 0), (bits, engine)
            err = capsys.readouterr().err
            assert ("0-4095" in err and "set its pixel format back" in err) == refused, err
        assert out.exists() != refused
