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
from graytrack.core.chi2_curve import Chi2Curve, frame_spread, measured
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


def test_a_frames_chi2_spread_is_that_of_the_samples_it_draws_independently():
    """Noise shared by groups of k samples scatters a frame's χ² as 2048/k samples' would: a spread of √k. A
    misfit that moves with the place the frames see is no such noise (neighbours along the stroke share it)."""
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 10.0, 1000)
    white = rng.chisquare(2048, x.size) / 2048
    assert frame_spread(x, white, None, 2048) == 1.0
    for k in (4, 16):  # a row's offset drawn each frame: one draw for a whole row of k samples
        shared = rng.chisquare(2048 // k, x.size) / (2048 // k)
        assert frame_spread(x, shared, None, 2048) == pytest.approx(math.sqrt(k), rel=0.1)
    wander = (1.0 + 0.3 * np.sin(2 * np.pi * x / 3.0)) * white  # a misfit with the place: 30 % either way
    assert frame_spread(x, wander, None, 2048) == 1.0
    assert frame_spread(x[:10], white[:10], None, 2048) == 1.0  # too few frames to say


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


# --- the estimator on a 16-row strip with noise its rows share: each row offset by a gray drawn every frame (row
# banding) and six pixels flickering between two levels, at calibration as in the run; nothing changes between them.

@pytest.fixture(scope="module")
def banded():
    effects = "row_banding:gray=1,telegraph_pixels:count=6"
    calibration, _ = build_rig("strip16", effects, seed=3).record(12.0)
    model = calibrate(calibration, "paper").model
    run, truth = build_rig("strip16", effects, seed=3, run=1).record(6.0)
    return model, run, truth


def scored(model, run, truth, grating: str) -> tuple[float, float]:
    """(share flagged, share 4+ bounds off the truth unflagged) of the run tracked by the estimator."""
    from graytrack.core.estimator import filter as estimator

    estimates = estimator.track(model, run.frames, run.t, run.reference if grating == "check" else None,
                                grating=grating)
    stale = np.array([e.stale for e in estimates])
    error_um = (np.array([e.x_mm for e in estimates]) - truth.x_mm) * 1e3
    if grating == "none":  # placed from the image alone: its origin is known up to whole periods
        period_um = model.period_mm * 1e3
        error_um -= period_um * np.round(np.median(error_um) / period_um)
    far = np.abs(error_um) > 4.0 * np.array([e.crlb_mm for e in estimates]) * 1e3
    return float(stale.mean()), float(np.mean(far & ~stale))


def without_rows(model):
    """The model as tracked before a strip's row banding was taken out of its frames (the spread alone counts)."""
    plain = copy.deepcopy(model)
    for key in ("row_offset_gray", "row_chi2_share", "row_chi2_spread", "frame_offset_gray"):
        plain.info.pop(key, None)
    return plain


def test_noise_the_samples_share_is_counted_and_a_steady_run_is_not_flagged_for_it(banded):
    model, run, truth = banded
    counted = without_rows(model)  # the frames' χ² spread alone answers the banding here
    assert counted.info["frame_chi2_spread"] > 3.0  # 16 rows of 128 samples scatter their χ² as a few hundred
    white = copy.deepcopy(counted)
    white.info["frame_chi2_spread"] = 1.0
    for grating in ("check", "none"):
        flagged, silent = scored(counted, run, truth, grating)
        as_white, _ = scored(white, run, truth, grating)
        # counted as independent, the same frames fail their test on one frame in seven, for nothing
        assert as_white > 0.1 and flagged < 0.02, (grating, flagged, as_white)
        # (without the rows' offsets taken out the bound is a little narrow for the errors: rms pull 1.1-1.3; a
        # frame in 150 just past 4 bounds goes unflagged without the grating)
        assert silent <= 0.01, (grating, silent)


def test_a_strips_row_banding_is_measured_and_taken_out_of_every_frame(banded, rig_model):
    """Each row offset by a gray drawn afresh every frame: calibration measures its σ, and the estimator takes each
    row's offset out of the frame instead of letting it move the position through the row's slopes."""
    from graytrack.core.estimator import filter as estimator

    model, run, truth = banded
    assert model.info["row_offset_gray"] == pytest.approx(1.0, abs=0.1)  # the rig's banding: σ 1 gray
    assert 0.2 < model.info["row_chi2_share"] < 0.6  # most of the residual the calibration left was the banding
    assert "row_offset_gray" not in rig_model[0].info  # a clean strip has none
    errors = {}
    for name, tracked in (("rows", model), ("spread alone", without_rows(model))):
        estimates = estimator.track(tracked, run.frames, run.t, run.reference, grating="check")
        error_um = (np.array([e.x_mm for e in estimates]) - truth.x_mm) * 1e3
        pull = math.sqrt(np.mean((error_um / (np.array([e.crlb_mm for e in estimates]) * 1e3)) ** 2))
        errors[name] = (float(np.std(error_um)), pull, float(np.mean([e.stale for e in estimates])))
    (rows, pull, flagged), (alone, pull_alone, _) = errors["rows"], errors["spread alone"]
    assert rows < 0.8 * alone, errors  # measured 0.52 against 0.76 µm
    assert 0.8 < pull < 1.25 and pull < pull_alone, errors  # the steady acceptance's band (1.28 with the spread alone)
    assert flagged < 0.01, errors


def test_the_calibration_says_the_sensors_noise_is_shared(banded, rig_model):
    from graytrack.service.calibration_run import CalibrationRun

    model, _, _ = banded
    assert any("noise is shared between samples" in line
               for line in CalibrationRun("paper", model, {}, None, None).warnings())
    assert "noise shared between samples" in model.describe()  # (the daemon's status and the report name the model so)
    assert "row banding 1.0" in model.describe()
    assert any("row banding" in line for line in CalibrationRun("paper", model, {}, None, None).warnings())
    clean, _ = rig_model  # a clean strip: nothing to say
    assert "frame_chi2_spread" in clean.info and clean.info["frame_chi2_spread"] == 1.0
    assert not any("shared" in line for line in CalibrationRun("paper", clean, {}, None, None).warnings())
    assert "shared" not in clean.describe()
