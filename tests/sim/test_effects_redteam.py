"""Physical signatures of the effects added by red-teaming the loop: glare, gain hunting, telegraph
pixels, row banding, Mono12-in-16, smudge, vibration, duplicated frames, camera clock drift."""

from __future__ import annotations


import numpy as np
import pytest

from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.sim.stage import constant_velocity

from .helpers import light, quiet_rig


def test_glare_adds_a_blob_fixed_to_the_camera_whatever_the_position():
    rig = quiet_rig(effects=["glare:gray=20:at=0.7:sigma_px=8"])
    plain = quiet_rig()
    added = light(rig, [1.0, 3.3]) - light(plain, [1.0, 3.3])
    np.testing.assert_allclose(added[0], added[1], atol=1e-9)  # does not move with the target
    assert int(np.argmax(added[0, 0])) == round(0.7 * 99)
    assert added[0, 0].max() == pytest.approx(20.0, rel=0.01)
    assert added[0, 0, 30] < 0.01  # beyond 4σ: nothing


def test_gain_hunting_swings_the_frame_gain_in_steps_at_its_frequency():
    rig = quiet_rig(effects=["gain_hunting:depth=0.05:hz=2:step=0.01:phase_deg=0"])
    t = np.linspace(0.0, 1.0, 201)
    frames = rig.render(np.full(t.size, 2.0), t).astype(float)[:, 0]
    gain = frames.mean(axis=1) / frames[0].mean()
    assert gain.max() == pytest.approx(1.05, abs=1e-6) and gain.min() == pytest.approx(0.95, abs=1e-6)
    np.testing.assert_allclose(gain, 1 + 0.01 * np.round(5 * np.sin(4 * np.pi * t)), atol=1e-6)


def test_telegraph_pixels_jump_between_two_levels_at_random_instants():
    rig = quiet_rig(effects=["telegraph_pixels:count=2:gray=6:rate_hz=5"], seed=2)
    bad = rig.config.sensor.bad_pixels
    assert [b.kind for b in bad] == ["telegraph", "telegraph"]
    t = np.linspace(0.0, 20.0, 2001)
    frames = rig.render(np.full(t.size, 2.0), t).astype(float)
    clean = light(rig, [2.0])[0]
    for b in bad:
        jump = frames[:, b.row, b.pixel] - clean[b.row, b.pixel]
        assert set(np.round(jump, 3)) == {0.0, 6.0}
        flips = np.count_nonzero(np.diff(jump))
        assert 60 < flips < 140  # 5 flips/s for 20 s, sampled at 100 Hz
    others = np.ones(clean.shape, dtype=bool)
    for b in bad:
        others[b.row, b.pixel] = False
    np.testing.assert_allclose(frames[:, others], np.broadcast_to(clean[others], (t.size, others.sum())), atol=1e-3)


def test_row_banding_is_an_offset_common_to_each_row_of_each_frame():
    rig = quiet_rig(effects=["rows:n=4", "row_banding:gray=1.5"])
    frames = rig.render(np.full(500, 2.0), np.zeros(500)).astype(float)
    offsets = frames - light(rig, [2.0])[0]
    np.testing.assert_allclose(offsets, np.broadcast_to(offsets[:, :, :1], offsets.shape), atol=1e-4)
    assert offsets[:, :, 0].std() == pytest.approx(1.5, rel=0.1)
    assert abs(np.corrcoef(offsets[:, 0, 0], offsets[:, 1, 0])[0, 1]) < 0.15  # rows independent


def test_mono12_in_16_steps_by_16_with_the_black_level():
    rig = build_rig("clean", ["mono12_in_16:black_gray=16:read_e=0"], seed=1)
    frames = rig.render(np.full(50, 2.0), np.zeros(50))
    assert frames.dtype == np.uint16 and np.all(frames % 16 == 0)
    dark = build_rig("clean", ["mono12_in_16:black_gray=16:read_e=0", "light_change:gain=0.000001:ambient_gray=0"])
    black = dark.render(np.full(50, 2.0), np.zeros(50)).astype(float)
    assert black.mean() == pytest.approx(16 * 256, abs=30)  # 16 gray of 255 in 16-bit counts (shot noise aside)


def test_smudge_darkens_one_place_of_the_print_for_every_row():
    rig = quiet_rig(effects=["rows:n=3", "smudge:at=0.5:width_um=700:depth=0.35"])
    lo, hi = 0.0, rig.config.stroke_mm[1] + rig.pixel_pitch_mm * rig.n_pixels
    centre = lo + 0.5 * (hi - lo)
    x = centre - rig.pixel_pitch_mm * 50  # the smudge under pixel 50
    ratio = light(rig, [x])[0] / light(quiet_rig(effects=["rows:n=3"]), [x])[0]
    np.testing.assert_allclose(ratio[:, 50], 0.65, atol=0.01)
    np.testing.assert_allclose(ratio[0], ratio[2], atol=1e-9)
    assert ratio[0, 0] == pytest.approx(1.0, abs=1e-4)  # 3 mm (4.4σ) away: untouched


def test_vibration_rides_on_the_motion_and_is_averaged_over_the_exposure():
    rig = build_rig("clean", ["read_noise:gray=0", "vibration:um=3:hz=200:phase_deg=0", "motion_blur:exposure_ms=2"])
    rec, truth = rig.record(0.5, trajectory=constant_velocity(2.0, 1.0))
    wiggle = truth.x_mm - (2.0 + truth.t_s)
    np.testing.assert_allclose(wiggle, 0.003 * np.sin(2 * np.pi * 200 * truth.t_s), atol=1e-9)
    np.testing.assert_allclose(truth.reference_error_mm, 0.0, atol=rig.config.grating.resolution_mm)
    # the exposure averages the vibration: sinc(f·T) of it survives in the mean position
    np.testing.assert_allclose(truth.x_mean_mm - (2.0 + truth.t_s), np.sinc(200 * 0.002) * wiggle, atol=2e-5)


def test_duplicate_frames_repeat_the_image_with_a_new_time_and_reference():
    rig = build_rig("paper", ["duplicate_frames:p=0.2"], seed=4)
    rec, truth = rig.record(2.0)
    same = np.all(rec.frames[1:] == rec.frames[:-1], axis=1)
    assert 10 < same.sum() < 35
    assert np.all(np.diff(rec.t) > 0) and np.all(np.diff(rec.reference) > 0)
    np.testing.assert_array_equal(truth.x_mm[1:][same], truth.x_mm[:-1][same])  # shows where the stage was


def test_clock_drift_makes_the_reference_error_grow_with_time():
    rig = build_rig("clean", ["read_noise:gray=0", "clock_drift:ppm=200"], seed=0)
    rec, truth = rig.record(2.0, trajectory=constant_velocity(1.0, 2.0))
    skew = truth.t_s - rec.t
    np.testing.assert_allclose(skew, 200e-6 * rec.t, atol=1e-12)
    np.testing.assert_allclose(truth.reference_error_mm, -2.0 * skew, atol=rig.config.grating.resolution_mm)
