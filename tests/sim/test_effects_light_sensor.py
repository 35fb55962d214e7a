"""Physical signatures of the illumination and sensor effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.drivers.sim import paper
from graytrack.drivers.sim.stage import constant_velocity

from .helpers import light, quiet_rig


def test_gradient_follows_stroke_position_not_target_phase():
    per_10mm = 0.1
    rig = quiet_rig(effects=[f"gradient:per_10mm={per_10mm}"])
    tau = paper.PERIOD_MM
    # x and x + τ show the same target phase: only a field fixed to the target tells them apart
    a, b = light(rig, [1.0, 1.0 + tau])[:, 0]
    plain_a, plain_b = light(quiet_rig(), [1.0, 1.0 + tau])[:, 0]
    np.testing.assert_allclose(plain_b, plain_a, atol=1e-9)
    # the same pixel at the same target phase gets the light of another place on the target
    x_w = 1.0 + rig.pixel_pitch_mm * np.arange(rig.n_pixels) - rig.config.illumination.gradient_center_mm
    gain = lambda dx: 1 + per_10mm / 10 * dx  # noqa: E731
    np.testing.assert_allclose(b / a, gain(x_w + tau) / gain(x_w), rtol=1e-9)
    assert (b / a).min() > 1.08


def test_vignetting_is_a_gain_fixed_to_the_pixels():
    rig = quiet_rig(effects=["vignetting:edge=0.2"])
    x = [0.7, 5.3]
    ratio = light(rig, x)[:, 0] / light(quiet_rig(), x)[:, 0]
    np.testing.assert_allclose(ratio[0], ratio[1], atol=1e-12)
    rho2 = ((np.arange(100) - 49.5) / 50) ** 2
    np.testing.assert_allclose(ratio[0], 1 - 0.2 * rho2, atol=1e-12)


def test_flicker_is_a_common_mode_gain_per_frame_at_twice_mains():
    depth, mains, exposure = 0.05, 60.0, 0.001
    rig = quiet_rig(effects=[f"flicker:mains_hz={mains}:depth={depth}:phase_deg=0"])
    t = np.arange(200) / 997.0
    x = np.full(t.size, 3.0)
    ratio = rig.render_light(x, t)[:, 0] / quiet_rig().render_light(x, t)[:, 0]
    spread_over_pixels = ratio.std(axis=1)
    assert spread_over_pixels.max() < 1e-12  # common mode: one gain per frame
    expected = 1 + depth * np.sinc(2 * mains * exposure) * np.cos(2 * math.pi * 2 * mains * t)
    np.testing.assert_allclose(ratio[:, 0], expected, atol=1e-12)
    assert ratio[:, 0].max() - ratio[:, 0].min() > 1.9 * depth * 0.9
    # a camera driver with its own exposure: the flicker averages over that window instead
    long = rig.render_light(x, t, exposure_s=0.006)[:, 0, 0] / quiet_rig().render_light(x, t)[:, 0, 0]
    expected_long = 1 + depth * np.sinc(2 * mains * 0.006) * np.cos(2 * math.pi * 2 * mains * t)
    np.testing.assert_allclose(long, expected_long, atol=1e-12)


def test_light_change_scales_the_lamp_and_adds_stray_light_from_its_start():
    rig = quiet_rig(effects=["light_change:gain=0.8:ambient_gray=10:start_s=1:ramp_s=2"])
    t = np.array([0.0, 0.99, 2.0, 3.0, 5.0])
    x = np.full(t.size, 3.0)
    changed, steady = rig.render_light(x, t)[:, 0], quiet_rig().render_light(x, t)[:, 0]
    gain = np.array([1.0, 1.0, 0.9, 0.8, 0.8])
    ambient = np.array([0.0, 0.0, 5.0, 10.0, 10.0])
    np.testing.assert_allclose(changed, gain[:, None] * steady + ambient[:, None], atol=1e-9)
    step = quiet_rig(effects=["light_change:gain=1.2:ambient_gray=-4:start_s=1"]).render_light(x, t)[:, 0]
    np.testing.assert_allclose(step[[1, 2]], [steady[1], 1.2 * steady[2] - 4.0], atol=1e-9)


def _still_frames(rig, n_frames: int, x: float = 2.0, noise: bool = True) -> np.ndarray:
    x_samples = np.full(n_frames, x)
    return rig.render(x_samples, np.zeros(n_frames), noise=noise).astype(float)


def test_prnu_is_a_residual_pattern_fixed_to_the_pixels():
    rig = quiet_rig(effects=["prnu:sigma=0.02"], seed=4)
    residual = []
    for x in (0.9, 4.4):
        residual.append(_still_frames(rig, 1, x, noise=False)[0, 0] / light(rig, [x])[0, 0])
    np.testing.assert_allclose(residual[0], residual[1], atol=1e-6)  # same pattern at any position
    assert residual[0].std() == pytest.approx(0.02, rel=0.3)
    other_seed = quiet_rig(effects=["prnu:sigma=0.02"], seed=5)
    other = _still_frames(other_seed, 1, 0.9, noise=False)[0, 0] / light(other_seed, [0.9])[0, 0]
    assert abs(np.corrcoef(residual[0], other)[0, 1]) < 0.5


def test_dsnu_is_an_offset_fixed_to_the_pixels_whatever_the_light():
    rig = quiet_rig(effects=["dsnu:sigma=1.5"], seed=2)
    offsets = [_still_frames(rig, 1, x, noise=False)[0, 0] - light(rig, [x])[0, 0] for x in (0.9, 4.4)]
    np.testing.assert_allclose(offsets[0], offsets[1], atol=1e-4)
    assert offsets[0].std() == pytest.approx(1.5, rel=0.3)


def test_shot_noise_variance_grows_with_signal():
    full_well = 4000.0
    rig = quiet_rig(effects=[f"shot_noise:full_well={full_well}"])
    frames = _still_frames(rig, 400)[:, 0]
    mean, var = frames.mean(axis=0), frames.var(axis=0)
    slope, intercept = np.polyfit(mean, var, 1)
    assert slope == pytest.approx(255.0 / full_well, rel=0.1)
    assert abs(intercept) < 0.3


def test_read_noise_variance_is_independent_of_signal():
    rig = build = quiet_rig(effects=["read_noise:gray=2.0"])
    frames = _still_frames(build, 400)[:, 0]
    mean, std = frames.mean(axis=0), frames.std(axis=0)
    assert std.mean() == pytest.approx(2.0, rel=0.03)
    assert abs(np.polyfit(mean, std**2, 1)[0]) < 0.01
    assert rig.frame_dtype == np.float32


@pytest.mark.parametrize("bits, dtype, scale", [(8, np.uint8, 1), (12, np.uint16, 16)])
def test_quantize_rounds_to_the_bit_depth(bits, dtype, scale):
    rig = quiet_rig(effects=[f"quantize:bits={bits}"])
    frames = rig.render(np.array([2.0, 5.0]), np.zeros(2), noise=False)
    assert frames.dtype == dtype
    expected = np.clip(np.rint(light(rig, [2.0, 5.0]) * scale), 0, 2**bits - 1)
    np.testing.assert_array_equal(frames, expected)
    rec, _ = rig.record(0.2)
    assert rec.frames.dtype == dtype and rec.meta["bit_depth"] == bits


def test_sensor_gamma_bends_the_response():
    rig = quiet_rig(effects=["sensor_gamma:gamma=0.5"])
    out = rig.render(np.array([2.0]), np.zeros(1), noise=False)[0, 0]
    np.testing.assert_allclose(out, 255 * (light(rig, [2.0])[0, 0] / 255) ** 0.5, rtol=1e-6)


def test_saturation_clips_the_crests_at_full_scale():
    rig = quiet_rig(effects=["saturation:gain=2"])
    x = np.linspace(0, paper.PERIOD_MM, 50)
    out = rig.render(x, np.zeros(x.size), noise=False)[:, 0]
    lin = 2 * light(rig, x)[:, 0]
    assert out.max() == pytest.approx(255.0)
    assert (out == np.float32(255.0)).mean() > 0.2
    below = lin < 255
    np.testing.assert_allclose(out[below], lin[below], rtol=1e-6)


def test_rows_make_a_strip_of_independent_noise_over_the_same_line():
    rig = build = quiet_rig("paper", effects=["rows:n=16", "read_noise:gray=0.7"])
    rec, truth = build.record(0.5)
    assert rec.frames.shape == (25, 16, 100) and rig.n_rows == 16
    clean = rig.render_light(truth.x_mm, truth.t_s)
    noise = rec.frames - clean
    assert noise.std() == pytest.approx(0.7, rel=0.05)
    corr = np.corrcoef(noise[:, 0].ravel(), noise[:, 1].ravel())[0, 1]
    assert abs(corr) < 0.1
    np.testing.assert_allclose(clean[:, 0], clean[:, 15], atol=1e-12)  # rows agree without tilt


def test_lab_scenario_is_an_8bit_strip_with_light_and_sensor_imperfections():
    rig = build = quiet_rig("lab")
    rec, truth = build.record(0.5)
    assert rec.frames.dtype == np.uint8 and rec.frames.shape[1:] == (16, 128)
    assert truth.pixel_gain.std() > 0.005 and truth.light_gain.std() > 0
    assert rig.config.sensor.full_well_e == 10000 and rig.config.effects == ["read_noise:gray=0"]
    assert constant_velocity(0, 1).velocity(np.zeros(3)).tolist() == [1, 1, 1]


def test_fixed_patterns_belong_to_physical_pixels_when_the_roi_moves():
    from graytrack.drivers.sim.rig import VirtualRig
    from graytrack.drivers.sim.scenarios import build_config

    config = build_config("lab", seed=1)
    first = VirtualRig(config, seed=1)
    config.optics.roi_x += 10
    shifted = VirtualRig(config, seed=1)
    np.testing.assert_array_equal(shifted.sensor.prnu[:, :-10], first.sensor.prnu[:, 10:])
    np.testing.assert_array_equal(shifted.sensor.dsnu[:, :-10], first.sensor.dsnu[:, 10:])
    # vignetting is about the optical axis (sensor centre), not the ROI: the ROI sits right of centre now
    assert shifted.geometry.radius2[:, -1].mean() > first.geometry.radius2[:, -1].mean()


def test_gradient_on_the_fast_path_matches_the_per_pixel_product_while_moving():
    effects = ["gradient:per_10mm=0.2:curvature=0.1", "motion_blur:exposure_ms=10"]
    fast = quiet_rig(effects=effects)
    slow = quiet_rig(effects=[*effects, "dust:count=1:depth=0"])  # a defect forces the per-pixel path
    assert not fast._slow and slow._slow
    x = np.c_[np.linspace(0, 10, 40), np.linspace(0.5, 10.5, 40), np.linspace(1, 11, 40)]
    t = np.zeros(40)
    np.testing.assert_allclose(fast.render_light(x, t), slow.render_light(x, t), rtol=5e-5)
    np.testing.assert_allclose(fast.render_light(x[:, :1], t), slow.render_light(x[:, :1], t), rtol=1e-12)
