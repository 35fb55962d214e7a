"""The closed loop on virtual-rig recordings whose effects nobody tells it about.

Each case switches effects on in the rig; ``diagnose`` sees only the recording. It must name the
effect's family with evidence, and bring the held-out error to within 1.3× the Cramér–Rao bound.
"""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis import diagnose
from graytrack.core.timing import model_reference
from graytrack.core.tracking import track
from graytrack.core.watches.adequacy import LOCAL_LIMIT
from graytrack.drivers.sim.scenarios import build_rig

CASES = {
    # rig effects                                   effects the loop may name for them
    "gradient:per_10mm=0.06": {"stroke"},
    "chirp:um=150": {"stroke"},
    "prnu:sigma=0.02": {"flat_field"},
    "flicker:mains_hz=60:depth=0.03": {"common_mode"},
    "saturation:gain=1.3,sensor_gamma:gamma=0.8,quantize:bits=8": {"clipping"},
    # the light's gradient along the stroke is one gain a frame, which the common mode holds once τ_w
    # is refined with the flat field known (held at the seed's, stroke terms had to turn the phase too)
    "gradient:per_10mm=0.05,prnu:sigma=0.015,flicker:mains_hz=60:depth=0.02": {"flat_field", "common_mode"},
}


def run_loop(effects: str, seed: int = 3, seconds: float = 20.0):
    rig = build_rig("paper", effects, seed=seed)
    recording, _ = rig.record(seconds)
    return diagnose(recording).report()


@pytest.mark.parametrize("effects", list(CASES))
def test_loop_names_the_effect_and_reaches_the_noise_floor(effects):
    report = run_loop(effects)
    named = {step["effect"] for step in report["steps"]}
    assert CASES[effects] <= named, f"expected {CASES[effects]}, loop added {named}"
    assert all(step["evidence"] and step["family"] for step in report["steps"])
    bound = report["noise"]["crlb_um"]
    assert report["before"]["error_std_um"] > 2.0 * bound  # the paper's model alone is well above it
    assert report["after"]["error_std_um"] <= 1.3 * bound
    assert report["after"]["rmse_gray"] < report["before"]["rmse_gray"]


def test_tilted_strip_is_traced_to_the_rows():
    """Tilt in a 16-row strip: the rows disagree and the loop models them one by one.

    With this rig's 8.6 mm period a tilt shifts rows by micrometres, so the row average the seed
    model sees is only slightly blurred: the tracking error before is already close to the bound
    and the gain is in the residual (rows no longer disagree) more than in the error.
    """
    rig = build_rig("paper", "rows:n=16,tilt:deg=10", seed=3)
    # 8 s, 400 frames (the loop holds half out): the held-out error's spread is known to ±1/√(2·200) = 5 %,
    # against 1.3x allowed (1.09x measured at 8 s, 1.02x at 12 s); the residual's rms over 200 frames of
    # 16 rows to a few tenths of a percent, against 1.05x (1.010x at 8 s, 1.009x at 12 s); the tilt to
    # 0.01-0.05 % against 3 %. The loop's fits cost this test about in proportion to the frames.
    recording, _ = rig.record(8.0)
    result = diagnose(recording)
    report = result.report()
    assert [step["effect"] for step in report["steps"]] == ["rows"]
    # the camera's tilt itself: row r sees the target shifted by −r·α·d·sin(10°)
    assert result.final_model.row_shift_mm == pytest.approx(-0.062 * np.sin(np.radians(10.0)), rel=0.03)
    assert "per row" in report["steps"][0]["evidence"]
    assert report["before"]["rmse_gray"] > 1.5 * report["noise"]["gray"]
    assert report["after"]["rmse_gray"] < 1.05 * report["noise"]["gray"]
    assert report["after"]["error_std_um"] <= 1.3 * report["noise"]["crlb_um"]


@pytest.mark.parametrize("seed", [3, 4])
def test_clean_data_gains_nothing_harmful(seed):
    report = run_loop("", seed=seed)
    assert report["after"]["error_std_um"] <= 1.05 * report["before"]["error_std_um"]
    assert report["after"]["error_std_um"] <= 1.2 * report["noise"]["crlb_um"]


def test_unlisted_combination():
    """Effects and magnitudes outside the list above, all at once."""
    report = run_loop("sensor_gamma:gamma=0.7,gradient:per_10mm=0.1,dsnu:sigma=2,flicker:mains_hz=60:depth=0.02,"
                      "harmonics:h2=0.08:h3=0.03", seed=7)
    assert report["before"]["error_std_um"] > 3.0 * report["noise"]["crlb_um"]
    assert report["after"]["error_std_um"] <= 1.3 * report["noise"]["crlb_um"]


def test_validation_recording_is_used_as_held_out():
    rig = build_rig("paper", "prnu:sigma=0.02", seed=5)
    calibration, _ = rig.record(16.0)
    validation, _ = rig.record(8.0)
    result = diagnose(calibration, validation)
    assert result.holdout.startswith("validation recording")
    assert len(result.after.figures.error_um) == validation.n_frames
    assert np.isfinite(result.after.figures.error_um).all()
    assert result.report()["after"]["error_std_um"] <= 1.3 * result.report()["noise"]["crlb_um"]


def test_dust_on_the_target_becomes_a_map_and_beats_the_plain_floor():
    """Local defects fixed to the target: mapped along it, they even add information (a sharp edge)."""
    report = run_loop("dust:count=6")
    assert [step["effect"] for step in report["steps"]][:1] == ["target_map"]
    assert report["before"]["error_std_um"] > 4.0 * report["noise"]["crlb_before_um"]
    assert report["after"]["rmse_gray"] < 1.05 * report["noise"]["gray"]
    assert report["after"]["error_std_um"] < report["noise"]["crlb_before_um"]


def test_reference_read_late_is_traced_to_timing_and_corrected():
    """A latch 0.3 ms after mid-exposure on a stage oscillating at up to 66 mm/s: error ∝ velocity."""
    rig = build_rig("highspeed", "time_skew:ms=0.3", seed=3)
    recording, _ = rig.record(1.0)
    result = diagnose(recording)
    report = result.report()
    assert report["steps"][0]["effect"] == "reference_timing"
    assert result.final_model.info["reference_skew_s"] == pytest.approx(0.3e-3, rel=0.1)
    assert report["before"]["error_std_um"] > 10 * report["noise"]["crlb_um"]
    assert report["after"]["error_std_um"] <= 1.3 * report["noise"]["crlb_um"]
    # judged against the grating at the exposure, as it was fitted: the latch (20 µm at 66 mm/s) is
    # no error of the model's. Against the raw grating it read 36x its bound on its own frames and
    # every frame of every run was flagged `geometry`.
    info = result.final_model.info
    assert info["calibration_error_ratio"] < 1.5
    assert max(info["calibration_error_profile"]["ratio"]) < LOCAL_LIMIT
    run, _ = build_rig("highspeed", "time_skew:ms=0.3", seed=3, run=1).record(0.5)
    tracked = track(result.final_model, run, reference=model_reference(result.final_model, run.t, run.reference))
    assert tracked.stale.mean() < 0.05
    error = tracked.error_um(model_reference(result.final_model, run.t, run.reference))
    assert np.nanstd(error) < 1.5 * np.nanmean(tracked.crlb_mm) * 1e3


def test_a_rolling_shutter_leaves_the_strips_position_at_its_bound():
    """Rows exposed 100 µs apart on a stage at up to 66 mm/s: each row sees the print up to 50 µm
    from the frame's mid-exposure position, but the rows centre on it, and the strip's position
    (their mean) is the mid-frame one. Neither the seed model (χ² 4× at speed) nor the loop's is
    off its bound, and no frame is flagged for it."""
    rig_effects = "rolling_shutter:line_us=100"
    # One second of calibration: two of the stage's 2 Hz oscillations, 1,000 frames at every speed up to
    # 66 mm/s both ways. The statistics are the run's (1,000 frames, as before); the calibration's length
    # enters through its coefficients' noise, an error fixed at each place of about bound·√(44 coefficients
    # / 1,000 frames) = 0.21 bound: +2 % on the spread in quadrature (+1 % from 2 s) against the 15 %
    # allowed, and averaged over the stroke's places in the run's mean, held to 0.2 bound (1.05x and 0.04
    # bound at 1 s, 1.06x and 0.02 at 2 s). The seed model's calibration tracks each of its frames through
    # the shadow follower's search (χ² 4x at speed), so this test's time follows the calibration's length.
    recording, _ = build_rig("highspeed", rig_effects, seed=3).record(1.0)
    run, truth = build_rig("highspeed", rig_effects, seed=3, run=1).record(1.0)
    result = diagnose(recording)
    for model in (calibrate(recording, "paper").model, result.final_model):
        tracked = track(model, run, light="auto", robust=True)
        error = (tracked.x_mm - truth.x_mm) * 1e3
        bound = np.sqrt(np.nanmean(np.square(tracked.crlb_mm * 1e3)))
        assert np.nanstd(error) < 1.15 * bound and abs(np.nanmean(error)) < 0.2 * bound
        assert not tracked.stale.any()


def test_heavy_saturation_that_defeats_the_seed_model_is_reported_and_fixed():
    """Gain 1.6 into an 8-bit clip: the seed model places no held-out frame; clipping fixes it."""
    import json

    report = run_loop("saturation:gain=1.6,quantize:bits=8", seed=5)
    assert report["before"]["error_std_um"] is None and report["before"]["lost_frames"] > 0
    assert report["steps"][0]["effect"] == "clipping"
    assert report["after"]["lost_frames"] == 0
    assert report["after"]["error_std_um"] <= 1.3 * report["noise"]["crlb_um"]
    json.dumps(report, allow_nan=False)  # the contract file holds no NaN or infinity
