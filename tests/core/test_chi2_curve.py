"""The calibration's χ² level along the stroke (core/chi2_curve.py): a model whose misfit depends on
where the target is seen has a χ² that wanders with x; held against one level, a normal run read as
changed images on a quarter of its frames (the light field and the focus then solved for nothing).
Held against the level where each frame was taken, only a real change stands out."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.calibration_line import record_calibration_line
from graytrack.core.chi2_curve import Chi2Curve, measured
from graytrack.core.recording import Recording
from graytrack.core.tracking import LiveTracker
from graytrack.drivers.sim.scenarios import build_rig


def test_a_flat_level_keeps_no_curve():
    rng = np.random.default_rng(1)
    x = rng.uniform(0.0, 10.0, 800)
    chi2 = rng.chisquare(2048, 800) / 2048
    assert measured(x, chi2) is None


def test_a_level_that_wanders_with_x_is_found_and_its_noise_shrunk_away():
    rng = np.random.default_rng(2)
    x = np.linspace(0.0, 10.0, 800)
    truth = 1.0 + 0.04 * np.sin(2 * np.pi * x / 10.0)
    chi2 = truth * rng.chisquare(2048, x.size) / 2048
    curve = measured(x, chi2)
    assert curve is not None
    at = np.array([curve.at(v) for v in x])
    assert np.max(np.abs(at / at.mean() - truth / truth.mean())) < 0.015  # 4 % wander to ~1 %
    assert curve.at(-5.0) == curve.level[0] and curve.at(50.0) == curve.level[-1]  # held beyond the ends


def test_too_few_frames_keep_no_curve():
    assert measured(np.linspace(0, 1, 30), np.linspace(1.0, 2.0, 30)) is None


@pytest.mark.parametrize("body",
                         [None, "flat", {"x_mm": [0.0], "level": [1.0]}, {"x_mm": [1.0, 0.0], "level": [1.0, 1.1]},
                                  {"x_mm": [0.0, 1.0], "level": [1.0]}, {"x_mm": [0.0, 1.0], "level": [1.0, "a"]}])
def test_a_malformed_curve_in_a_model_file_is_a_flat_level(body):
    try:
        curve = Chi2Curve.from_info({"calibration_chi2_curve": body})
    except ValueError:
        curve = "raised"
    assert curve is None or curve == "raised"


def test_a_curve_round_trips_through_the_model_info():
    curve = Chi2Curve((0.0, 1.0, 2.0), (0.97, 1.02, 1.01))
    again = Chi2Curve.from_info({"calibration_chi2_curve": curve.as_dict()})
    assert again == curve
    assert math.isclose(again.at(0.5), 0.995)


# --- tracking: the frames' noise grows and shrinks along the stroke (a misfit the model cannot
# carry, as on the lab strip); nothing changes between calibration and run.

WANDER = 0.08  # the noise's amplitude ±8 % along the stroke: χ² ±17 %
FRAMES = 1500  # a slow sweep over the stroke: the running χ² follows the wander


@pytest.fixture(scope="module")
def rig_model():
    calibration, _ = build_rig("strip16", seed=4).record(4.0)
    return calibrate(calibration, "paper").model, calibration


def wandering(model, like: Recording, seed: int, scale: float = 1.0) -> Recording:
    """A slow sweep over ``like``'s stroke imaged by ``model`` with noise whose amplitude wanders with x."""
    rng = np.random.default_rng(seed)
    lo, hi = float(np.nanmin(like.reference)), float(np.nanmax(like.reference))
    x = np.linspace(lo, hi, FRAMES)
    amplitude = scale * (1.0 + WANDER * np.sin(2 * np.pi * (x - lo) / (hi - lo)))
    values = model.predict(x)  # (K, R, n)
    frames = values + model.noise_gray * amplitude[:, None, None] * rng.standard_normal(values.shape)
    return Recording(frames, np.arange(FRAMES) / 200.0, x, dict(like.meta))


def suspect_share(model, run: Recording) -> float:
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    suspect = []
    for frame, reference in zip(run.frames, run.reference):
        live.update(frame, reference)
        suspect.append(live.state.chi2_suspect)
    return float(np.mean(suspect[100:]))


def test_a_run_whose_chi2_wanders_with_x_as_at_calibration_is_not_suspect(rig_model):
    model, calibration = rig_model
    model = copy.deepcopy(model)
    record_calibration_line(model, wandering(model, calibration, 10))
    assert "calibration_chi2_curve" in model.info
    flat = copy.deepcopy(model)
    flat.info.pop("calibration_chi2_curve")
    run = wandering(model, calibration, 11)
    with_curve, without = suspect_share(model, run), suspect_share(flat, run)
    assert without > 0.2  # held against one level, the wander reads as a change
    assert with_curve < 0.02, (with_curve, without)
    # a real change (the noise 8 % up everywhere: χ² 17 %) still stands out against the curve
    assert suspect_share(model, wandering(model, calibration, 12, scale=1.08)) > 0.8
