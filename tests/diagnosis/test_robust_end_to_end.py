"""The whole chain on recordings whose files declare nothing: the closed loop calibrates on one
run, the tracker measures another run in which the world has changed (the light, a pixel gone
bad), and the error stays at the noise floor of the run it measures.

The bound is the rms of the per-frame Cramér–Rao bounds, with the light's gain and offset unknown
where the tracker solved them: the floor for an error spread over frames whose bounds differ.
"""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.diagnosis import diagnose
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

# A bench with most of the library at once: 16 rows, a photon-transfer 8-bit sensor, PRNU, bad
# pixels, light uneven along the stroke, a printed harmonic, a slightly tilted camera.
BENCH = ("rows:n=16,photon_transfer:full_well=32000:read_e=12:bits=8,prnu:sigma=0.01,"
         "bad_pixels:stuck=1:dead=1:hot=1,gradient:per_10mm=0.05,harmonics:h2=0.02,tilt:deg=1")


def error_against_bound(model, recording) -> tuple[int, float, float]:
    """(frames lost, error std µm, rms bound µm) of the product's default tracking."""
    result = track(model, recording, light="auto", robust=True)
    error = result.error_um(recording.reference)
    lost = int((~np.isfinite(error)).sum())
    bound = float(np.sqrt(np.nanmean(np.square(result.crlb_mm * 1e3))))
    return lost, float(np.nanstd(error)), bound


@pytest.mark.slow
def test_a_lab_strip_keeps_its_floor_when_the_light_changes_and_a_pixel_fails_in_the_run():
    # 8 s of calibration, 400 frames of 16 rows (the tilted strip's in test_closed_loop.py): the claim is about the
    # measured run, 8 s as before, whose error is judged against its own frames' bounds. The calibration's length
    # enters through the noise of the fitted coefficients, a fixed error at each place that adds to the run's
    # spread in quadrature, about as the coefficients a row over the frames: a few percent of the bound at 400
    # frames against the 30 % allowed. The three defects sit in every frame, so the loop names them on any length.
    calibration, _ = build_rig("paper", BENCH, seed=3).record(8.0)
    result = diagnose(calibration)
    report = result.report()
    named = {(item["row"], item["pixel"]) for item in report["findings"]["bad_pixels"]}
    assert len(named) >= 3  # the three defects of the bench, by index
    # the measured run: the lamp dims by 15 % and stray light comes in after 3 s, and at 5 s one
    # more pixel sticks at full scale; nothing of this is in the calibration
    later = (BENCH + ",light_change:gain=0.85:ambient_gray=8:start_s=3,"
             "bad_pixels:stuck=1:dead=0:hot=0:row=7:pixel=60:start_s=5")
    run, _ = build_rig("paper", later, seed=3, run=1).record(8.0)
    lost, spread, bound = error_against_bound(result.final_model, run)
    assert lost == 0
    assert spread <= 1.3 * bound, f"{spread:.3f} µm against a bound of {bound:.3f} µm"


@pytest.fixture(scope="module")
def loop_model():
    """The closed loop's model of a plain paper rig, fitted once for both steps of light (seeded: the
    same model each time, and tracking reads it without changing it)."""
    calibration, _ = build_rig("paper", "", seed=4).record(16.0)
    return diagnose(calibration).final_model


@pytest.fixture(scope="module")
def eight_bit_model():
    """The paper model of an 8-bit rig, fitted once for the batch and the live saturation tests."""
    from graytrack.core.calibration import calibrate

    calibration, _ = build_rig("paper", "quantize:bits=8", seed=6).record(16.0)
    return calibrate(calibration, "paper").model


@pytest.mark.parametrize("gain,offset", [(0.7, 20.0), (1.3, -20.0)])
def test_the_closed_loops_model_tracks_through_a_step_change_of_light(loop_model, gain, offset):
    model = loop_model
    run, _ = build_rig("paper", f"light_change:gain={gain}:ambient_gray={offset}:start_s=4", seed=4, run=1).record(8.0)
    lost, spread, bound = error_against_bound(model, run)
    assert lost == 0
    assert spread <= 1.1 * bound, f"{spread:.3f} µm against a bound of {bound:.3f} µm"


def test_samples_driven_into_saturation_after_calibration_are_set_aside(eight_bit_model):
    """More light than at calibration drives the crests of an 8-bit sensor into its ceiling: the
    tracker sets those samples aside (they say nothing about x) instead of losing the frames."""
    model = eight_bit_model
    assert model.info["sensor_range_gray"] == [0.0, 255.0]
    run, _ = build_rig("paper", "quantize:bits=8,light_change:gain=1.35:ambient_gray=5", seed=6, run=1).record(8.0)
    assert (run.frames == 255).mean() > 0.05  # a good share of the samples sit at the ceiling
    lost, spread, bound = error_against_bound(model, run)
    assert lost == 0
    assert spread <= 1.3 * bound, f"{spread:.3f} µm against a bound of {bound:.3f} µm"


def test_live_tracking_sets_saturated_samples_aside_as_the_batch_tracker_does(eight_bit_model):
    from graytrack.core.tracking import LiveTracker

    model = eight_bit_model  # (the batch test's, calibrated on 16 s rather than 10 s: the same 8-bit rig)
    run, _ = build_rig("paper", "quantize:bits=8,light_change:gain=1.35:ambient_gray=5:start_s=1",
                       seed=6, run=1).record(3.0)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fixes = [live.update(frame) for frame in run.frames]
    batch = track(model, run, x0_mm=float(run.reference[0]), light="auto", robust=True)
    np.testing.assert_allclose([fix.x_mm for fix in fixes], batch.x_mm, atol=1e-9)
    assert all(fix.locked for fix in fixes)


def test_a_change_of_the_lights_shape_after_calibration_is_followed_by_a_light_field():
    """Vignetting appearing after calibration changes the light's shape across the line, which no
    uniform gain and offset can absorb: the running χ² rises, the tracker solves a light field
    (gain smooth across the line) and ends at its larger bound; χ² is back, but the precision lost
    to the field is flagged: stale for the light."""
    model = rig_model("paper", "", seed=3, seconds=16.0)
    run, _ = build_rig("paper", "vignetting:edge=0.05", seed=3, run=1).record(8.0)
    result = track(model, run, light="auto", robust=True)
    error, bound = result.error_um(run.reference)[-200:], result.crlb_mm[-200:] * 1e3
    assert np.isfinite(result.x_mm).all()
    assert np.sqrt(np.mean(np.square(error))) <= 1.3 * np.sqrt(np.mean(np.square(bound)))
    assert (result.stale_reason[-200:] == "light").all()
    steady, _ = build_rig("paper", "", seed=3, run=1).record(8.0)
    assert not track(model, steady, light="auto", robust=True).stale.any()
