"""The camera moving on its mount without the grating (core/estimator/mount.py): a step of the image no motion
of the stage makes is the camera's place, found one frame late; a stage within its acceleration never is."""

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import track
from graytrack.core.estimator.mount import step_test
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.recording import STAGE_ACCELERATION
from graytrack.drivers.sim.scenarios import build_rig


def _motion(rng, t, acceleration):
    """A stage position at ``t`` driven by a piecewise-constant acceleration within ±``acceleration`` that
    changes at random instants between the frames (the hardest shapes: bang-bang at the limit)."""
    fine = np.linspace(t[0], t[-1], 4001)
    a = acceleration * np.sign(rng.standard_normal(fine.size))
    switch = np.cumsum(rng.random(fine.size) < 0.01)
    a = a[switch]
    dt = fine[1] - fine[0]
    v = rng.normal(0.0, 5.0) + np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)])
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    return np.interp(t, fine, x)


def test_no_motion_within_the_stages_acceleration_makes_a_step_beyond_the_allowance():
    """The allowance is the Peano bound of the step's functional: over a thousand motions at the limit, on
    uneven frame times (a dropped frame, a late one), the step a stage made is never beyond it, and a step of
    the image as large again is."""
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(1000):
        t = np.cumsum(rng.uniform(0.01, 0.04, 4))
        x = _motion(rng, t, 100.0)
        step = step_test(t, x, np.full(4, 1e-12), 100.0)
        assert step is not None
        worst = max(worst, abs(step.step_mm) / step.allowance_mm)
        knocked = x + np.array([0.0, 0.0, 1.0, 1.0]) * 2.0 * step.allowance_mm
        assert step_test(t, knocked, np.full(4, 1e-12), 100.0).excess > 0.0
    assert worst <= 1.0 + 1e-6
    assert worst > 0.5  # the bound is not loose: the hardest motions come near it


def test_the_allowance_at_even_frames_is_three_quarters_of_a_frame_at_full_acceleration():
    t = np.arange(4) * 0.02
    step = step_test(t, np.zeros(4), np.full(4, 1e-6), 100.0)
    assert step.allowance_mm == pytest.approx(0.75 * 100.0 * 0.02 ** 2)
    assert step.sigma_mm == pytest.approx(1e-3 * np.sqrt(5.0))  # (½, 3/2, 3/2, ½)² summed: 5
    assert step_test(np.array([0.0, 0.02, 0.02, 0.04]), np.zeros(4), np.full(4, 1e-6), 100.0) is None


@pytest.fixture(scope="module")
def strip():
    calibration, _ = build_rig("strip16", "", seed=5).record()
    return calibrate(calibration, "paper").model


def _scored(model, run, truth):
    estimates = track(model, run.frames, run.t, None, grating="none",
                      settings=EstimatorSettings().for_recording(run.meta))
    x = np.array([e.x_mm for e in estimates])
    bound = np.array([e.crlb_mm for e in estimates])
    error = x - truth.x_mm
    error -= model.period_mm * np.round(np.nanmedian(error) / model.period_mm)
    stale = np.array([e.stale for e in estimates])
    return estimates, error, bound, stale


def test_a_knock_without_the_grating_is_found_a_frame_late_and_carried_in_the_bound(strip):
    """16 rows, no grating read, a stage commanded at 100 mm/s²: the image jumps 40 µm against the carriage at
    2 s (and turns 0.2°). The frame after the knock finds the step (beyond the 30 µm the stage could have
    made between four frames at 50 frames/s), the place takes it, and every later frame is flagged `geometry`
    with a bound that carries what the frames cannot see; none is 4 bounds off unflagged (every one was)."""
    run, truth = build_rig("strip16", "knock:um=40:deg=0.2:at_s=2", seed=5, run=1).record(6.0)
    assert run.meta[STAGE_ACCELERATION] == pytest.approx(100.0)
    estimates, error, bound, stale = _scored(strip, run, truth)
    knocked = int(np.searchsorted(run.t, 2.0))
    found = [k for k, e in enumerate(estimates) if "mount" in e.message]
    assert found and knocked <= found[0] <= knocked + 2, found
    assert len(found) == 1
    assert estimates[found[0]].mode == "geometry" and estimates[found[0]].stale_reason == "geometry"
    after = np.arange(len(estimates)) > found[0]
    assert np.all(stale[after])
    assert np.all(np.abs(error[after]) < 4.0 * bound[after])
    assert np.sum((np.abs(error) > 4.0 * bound) & ~stale) <= 2  # the knock's own frame, told one frame late
    # the same run, the stage's acceleration unknown (a recording that does not say): the fastest rig's
    # 1000 mm/s² allows 300 µm, and the knock is not found
    run.meta.pop(STAGE_ACCELERATION)
    estimates, *_ = _scored(strip, run, truth)
    assert not any("mount" in e.message for e in estimates)


def test_a_stage_stepping_and_settling_is_not_taken_for_a_knock(strip):
    """Step-and-settle over the stroke at the stage's 100 mm/s² (moves that start and stop within a frame or
    two): no step is found, and the run is flagged as a steady one."""
    from graytrack.drivers.sim.stage import steps

    rig = build_rig("strip16", "", seed=5, run=2)
    start, end = rig.config.stroke_mm
    run, truth = rig.record(8.0, trajectory=steps(start, end, 12, 0.3, rig.config.stage))
    assert run.meta[STAGE_ACCELERATION] == pytest.approx(100.0)
    estimates, error, bound, stale = _scored(strip, run, truth)
    assert not any("mount" in e.message for e in estimates)
    assert np.sum((np.abs(error) > 4.0 * bound) & ~stale) == 0
