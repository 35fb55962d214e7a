"""Physical signatures of the stage, grating and timing effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.drivers.sim.scenarios import build_config, build_rig
from graytrack.drivers.sim.stage import SimStage, SoftLimitError, SimStageConfig, constant_velocity

from .helpers import sine_fit


def test_move_respects_velocity_and_acceleration_limits_and_arrives():
    stage = SimStage(SimStageConfig(velocity_mm_s=4.0, acceleration_mm_s2=50.0))
    t_end = stage.move_to(10.0, 0.2)
    assert t_end == pytest.approx(0.2 + 10.0 / 4.0 + 4.0 / 50.0)  # trapezoid: d/v + v/a
    t = np.linspace(0, t_end + 0.5, 20001)
    v_cmd = np.gradient(stage.commanded_position(t), t)
    assert v_cmd.max() == pytest.approx(4.0, rel=1e-3)
    assert np.abs(np.gradient(v_cmd, t)).max() < 50.0 * 1.05
    assert stage.position(t_end + 0.5) == pytest.approx(10.0, abs=1e-9)
    assert not stage.on_target(t_end - 0.01) and stage.on_target(t_end + 0.2)


def test_a_stage_at_rest_from_its_creation_is_on_target_at_once():
    """A controller just powered up answers on target; a client's first #5 can come within milliseconds."""
    stage = SimStage(SimStageConfig(), position_mm=3.0, t_s=100.0)
    assert stage.on_target(100.0) and stage.on_target(100.0 + 1e-4)
    t_end = stage.move_to(4.0, 100.0)
    assert not stage.on_target(t_end) and stage.on_target(t_end + 0.2)


def test_soft_limits_stop_and_moves_during_moves():
    stage = SimStage(SimStageConfig(soft_limits_mm=(0.0, 20.0)))
    with pytest.raises(SoftLimitError):
        stage.move_to(25.0, 0.0)
    stage.move_to(15.0, 0.0)
    rest = stage.stop(1.0)
    x_stop = float(stage.position(rest + 1.0))
    assert 0 < x_stop < 15 and stage.target_mm == pytest.approx(x_stop, abs=1e-6)
    stage.move_to(2.0, rest + 1.0)  # reverse
    stage.move_to(12.0, rest + 1.3)  # redirect while moving back
    assert stage.position(rest + 10.0) == pytest.approx(12.0, abs=1e-9)
    with pytest.raises(ValueError):
        stage.move_to(3.0, 0.5)  # commands must come in time order


def test_following_error_is_proportional_to_velocity():
    cfg = build_config("paper", ["following_error:bandwidth_hz=15:kv=0"]).stage
    zeta, omega = cfg.damping, 2 * math.pi * 15
    lags = []
    for v in (2.0, 6.0):
        stage = SimStage(SimStageConfig(**{**vars(cfg), "velocity_mm_s": v}))
        t_end = stage.move_to(20.0, 0.0)
        lags.append(float(stage.following_error(t_end / 2)))
    assert lags[0] == pytest.approx(2 * zeta * 2.0 / omega, rel=1e-3)
    assert lags[1] / lags[0] == pytest.approx(3.0, rel=1e-3)
    default = SimStage(build_config("paper").stage)
    assert abs(float(default.following_error(default.move_to(20.0, 0.0) / 2))) < 0.1 * lags[0]


def test_grating_and_camera_both_see_the_lagging_stage():
    rig = build_rig("paper", ["following_error:bandwidth_hz=5:kv=0"])
    rec, truth = rig.record(2.0)
    assert np.abs(truth.reference_error_mm).max() <= 0.00025 + 1e-12


def test_settling_rings_after_a_move_and_delays_on_target():
    cfg = build_config("paper", ["settling:damping=0.1:bandwidth_hz=40"]).stage
    ringing, damped = SimStage(cfg), SimStage(build_config("paper").stage)
    ends = [s.move_to(5.0, 0.0) for s in (ringing, damped)]
    t = np.linspace(ends[0], ends[0] + 0.3, 3001)
    overshoot = ringing.position(t) - 5.0
    assert np.abs(overshoot).max() > 0.001  # ~a/ω² of ringing, twice the on-target window
    swings = np.sign(overshoot[np.abs(overshoot) > 0.0002])
    assert np.count_nonzero(np.diff(swings)) >= 3  # it oscillates about the target
    assert ringing.settled_time(ends[0]) > damped.settled_time(ends[1]) + 0.02


def test_grating_resolution_quantises_the_reference():
    rig = build_rig("paper", ["grating_resolution:um=2"])
    rec, truth = rig.record(2.0)
    steps = rec.reference / 0.002
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert np.abs(truth.reference_error_mm).max() <= 0.001 + 1e-12
    assert truth.reference_error_mm.std() * 1e3 == pytest.approx(2 / math.sqrt(12), rel=0.2)


def test_cyclic_error_is_periodic_in_position_with_the_grating_period():
    rig = build_rig("paper", ["grating_resolution:um=0", "cyclic_error:nm=300:period_um=20"])
    rec, truth = rig.record(4.0)
    amplitude, _, offset = sine_fit(truth.reference_error_mm, 2 * math.pi * truth.x_mm / 0.020)
    assert amplitude * 1e6 == pytest.approx(300, rel=0.02)
    wrong_period, _, _ = sine_fit(truth.reference_error_mm, 2 * math.pi * truth.x_mm / 0.023)
    assert wrong_period * 1e6 < 60


def test_time_skew_gives_a_reference_error_proportional_to_velocity():
    rig = build_rig("paper", ["grating_resolution:um=0", "time_skew:ms=2"])
    rec, truth = rig.record(1.0, trajectory=constant_velocity(1.0, 0.0))
    assert np.abs(truth.reference_error_mm).max() < 1e-12  # standing still: no error
    for v in (1.0, 5.0):
        rec, truth = build_rig("paper", ["grating_resolution:um=0", "time_skew:ms=2"]).record(
            1.0, trajectory=constant_velocity(1.0, v))
        np.testing.assert_allclose(truth.reference_error_mm, v * 0.002, atol=1e-12)


def test_jitter_gives_a_random_reference_error_scaled_by_velocity():
    v = 8.0
    rec, truth = build_rig("paper", ["grating_resolution:um=0", "jitter:us=300"]).record(
        4.0, trajectory=constant_velocity(0.5, v))
    lag_s = -truth.reference_error_mm / v
    assert lag_s.std() == pytest.approx(300e-6, rel=0.15)
    assert abs(lag_s.mean()) < 60e-6
    np.testing.assert_allclose(rec.t, truth.t_s)  # the camera stamps the true exposure


def test_timestamp_jitter_moves_the_recorded_times_only():
    rec, truth = build_rig("paper", ["timestamp_jitter:us=200"]).record(4.0)
    assert (rec.t - truth.t_s).std() == pytest.approx(200e-6, rel=0.15)
    assert np.abs(truth.reference_error_mm).max() <= 0.00025 + 1e-12


def test_dropped_frames_leave_gaps_in_time():
    rig = build_rig("paper", ["dropped_frames:p=0.2", "frame_rate:hz=100"])
    rec, truth = rig.record(5.0)
    assert rec.n_frames / 500 == pytest.approx(0.8, abs=0.06)
    gaps = np.diff(truth.frame_index)
    assert gaps.max() >= 2 and gaps.min() == 1
    np.testing.assert_allclose(np.diff(rec.t), gaps / 100.0, atol=1e-12)


def test_frame_rate_sets_the_clock_and_caps_the_exposure():
    rig = build_rig("paper", ["motion_blur:exposure_ms=20", "frame_rate:hz=200"])
    rec, _ = rig.record(1.0)
    assert rec.n_frames == 200
    np.testing.assert_allclose(np.diff(rec.t), 0.005)
    assert rig.exposure_s == pytest.approx(0.005) and rec.meta["frame_rate_hz"] == 200


def test_grating_latency_reports_an_earlier_position():
    rig = build_rig("paper", ["grating_resolution:um=0", "grating_latency:ms=3"])
    stage = rig.make_stage(position_mm=1.0)
    stage.move_to(9.0, 0.0)
    grating = rig.make_grating(stage)
    t = np.linspace(0.5, 1.0, 11)  # cruising
    np.testing.assert_allclose(grating.read(t), stage.position(t - 0.003), atol=1e-12)
    np.testing.assert_allclose(grating.read(t) - stage.position(t), -stage.velocity(t) * 0.003, atol=1e-6)


def test_position_kernel_matches_the_numpy_path():
    """The compiled per-instant position (what a live camera asks three times a frame) is the numpy
    path's ``p + e`` through moves, settling and rest, for numbers, rows and grids of instants."""
    stage = SimStage(SimStageConfig(damping=0.3), position_mm=1.0, t_s=0.0)  # a servo that rings after each move
    stage.move_to(6.0, 0.1)
    stage.move_to(2.5, 2.0)
    t = np.concatenate([np.linspace(-0.5, 5.0, 4001), [0.1, 2.0]])
    p, _, e, _ = stage._evaluate(t)
    assert np.max(np.abs(stage.position(t) - (p + e))) <= 1e-12
    grid = t[:4000].reshape(40, 100)
    assert stage.position(grid).shape == (40, 100)
    p1, _, e1, _ = stage._evaluate(1.25)
    assert np.ndim(stage.position(1.25)) == 0
    assert abs(stage.position(1.25) - (p1 + e1)) <= 1e-12


def test_rolling_shutter_exposes_each_row_later_and_so_further_along_in_motion():
    """Row r of a moving frame sees the print where the stage is (r − 7.5)·line later than mid-frame
    (16 rows): each row equals a global-shutter row at its own delayed positions; at rest nothing changes."""
    rolling, global_shutter = build_rig("highspeed", "rolling_shutter:line_us=50"), build_rig("highspeed")
    exposure = rolling.exposure_s
    moving = np.array([[5.0, 5.001, 5.002]])  # 10 mm/s over the 0.2 ms exposure
    velocity = 0.002 / exposure
    light = rolling.render_light(moving, np.array([0.1]))
    for r in range(rolling.n_rows):
        delayed = moving + velocity * (r - 7.5) * 50e-6
        assert np.allclose(light[0, r], global_shutter.render_light(delayed, np.array([0.1]))[0, r], rtol=0, atol=1e-9)
    assert not np.allclose(light, global_shutter.render_light(moving, np.array([0.1])), rtol=0, atol=1e-3)
    still = np.array([[5.0]])
    assert np.array_equal(rolling.render_light(still, np.array([0.1])),
                          global_shutter.render_light(still, np.array([0.1])))
