"""The camera moving on its mount without the grating (core/estimator/mount.py): a step of the image no motion
of the stage makes is the camera's place, found one frame late; a stage within its acceleration never is."""

import math

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import track
from graytrack.core.estimator.mount import SHOWN_BEYOND, MountWatch, commanded, step_test
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.recording import STAGE_ACCELERATION, STAGE_PHASES, acceleration_phases
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
                      settings=EstimatorSettings().for_recording(run.meta), stage_phases=acceleration_phases(run.meta))
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
    run.meta.pop(STAGE_PHASES)
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


def test_commanded_phases_bound_each_interval_and_hold_while_the_servo_settles():
    phases = np.array([[0.10, 0.15, 100.0], [0.50, 0.55, 40.0], [0.52, 0.60, 70.0]])
    t = np.arange(0.0, 0.8, 0.02)
    asked = commanded(t, phases, 0.03)
    middle = 0.5 * (t[1:] + t[:-1])
    assert asked[(middle > 0.11) & (middle < 0.14)].min() == 100.0
    assert asked[np.searchsorted(t, 0.16)] == 100.0  # (0.16–0.18: within the 30 ms the servo settles)
    assert asked[np.searchsorted(t, 0.20)] == 0.0 and asked[np.searchsorted(t, 0.40)] == 0.0
    assert asked[np.searchsorted(t, 0.54) - 1] == 70.0  # overlapping phases: the larger
    watch = MountWatch(100.0, 4.0, phases, 5.0, 0.03)
    assert [watch.commands.asked(t[j - 1], t[j]) for j in range(1, t.size)] == asked.tolist()
    assert commanded(t, None, 0.03) is None


def test_a_jump_at_a_windows_last_frame_waits_for_the_window_that_centres_it():
    """With the commands known the allowance at a cruise is small, and a window whose last frame jumped would read
    part of the jump as a step between its middle frames; its speed after the step then differs from before
    (the window's one residual), so it waits, and the next window takes the whole step."""
    t = np.arange(8) * 0.02
    x = 1.05 * t
    x[5:] += 0.040  # the camera knocked between frames 4 and 5, the stage cruising (no phase)
    watch = MountWatch(100.0, 4.0, np.zeros((0, 3)), 2.0, 0.03)
    found = [(k, watch.add(t[k], x[k], 1e-8)) for k in range(t.size)]
    steps = [(k, step) for k, step in found if step is not None]
    assert len(steps) == 1 and steps[0][0] == 6  # the window 3-6: the step between its middle frames
    assert steps[0][1].step_mm == pytest.approx(0.040, abs=1e-6)


def test_the_calibrations_readings_show_what_the_stage_does_beyond_its_commands(strip):
    """The strip's calibration sweep states its commanded phases: what the grating saw beyond them (the servo's
    lag, the readings' quantisation) is a few mm/s², against the commanded 100 mm/s² the phases allow anyway."""
    assert 0.0 < strip.info[SHOWN_BEYOND] < 20.0


def test_a_knock_on_one_row_without_the_grating_is_found_where_the_commands_say_the_stage_cruised():
    """One row at 50 frames/s: a stage at its 100 mm/s² could move 30 µm between four frames, so the 40 µm knock
    is not a step beyond the stage's most. The recording states when the stage was commanded to accelerate;
    at 2 s it cruised, so the interval allows only what the stage does beyond its commands, and the knock is
    found a frame late and carried from then on."""
    calibration, _ = build_rig("paper", "", seed=5).record()
    model = calibrate(calibration, "paper").model
    run, truth = build_rig("paper", "knock:um=40:deg=0.2:at_s=2", seed=5, run=1).record(6.0)
    assert acceleration_phases(run.meta) is not None
    estimates, error, bound, stale = _scored(model, run, truth)
    knocked = int(np.searchsorted(run.t, 2.0))
    found = [k for k, e in enumerate(estimates) if "mount" in e.message]
    assert len(found) == 1 and knocked <= found[0] <= knocked + 2, found
    after = np.arange(len(estimates)) > found[0]
    assert np.all(stale[after]) and np.all(np.abs(error[after]) < 4.0 * bound[after])
    assert np.sum((np.abs(error) > 4.0 * bound) & ~stale) <= 2
    allowed = float(estimates[found[0]].message.split("beyond the ")[1].split(" µm")[0])
    assert allowed < 10.0  # a cruise: what the stage does beyond its commands (30 µm at its most without them)


def test_phases_given_as_they_are_commanded_are_the_phases_given_up_front():
    """A running rig hands its commands over as it issues them (in any order, each kept while a window may reach
    it): every interval is allowed what the same phases given up front allow."""
    rng = np.random.default_rng(3)
    starts = np.sort(rng.uniform(0.0, 20.0, 40))
    phases = np.column_stack([starts, starts + rng.uniform(0.01, 0.3, 40), rng.uniform(10.0, 200.0, 40)])
    t = np.cumsum(rng.uniform(0.005, 0.05, 600))
    up_front = commanded(t, phases, 0.03)
    live = MountWatch(100.0, 4.0, np.zeros((0, 3)), 5.0, 0.03)
    given = 0
    for k in range(1, t.size):
        while given < len(phases) and phases[given, 0] < t[k] + 0.5:  # issued half a second ahead
            live.command(*phases[given])
            given += 1
        live.add(t[k], 0.0, 1e-6)  # (the window's times, for what it may drop)
        window = live.t if live.n == 4 else None
        if window is not None:
            expected = up_front[k - 3:k]
            assert [live.commands.asked(window[j - 1], window[j]) for j in range(1, 4)] == expected.tolist()
    assert len(live.commands.starts) < len(phases)  # what no window reaches again was dropped


def test_the_live_estimator_finds_a_knock_from_the_commands_it_is_handed():
    """The daemon's way: no phases in a recording, each handed to the live estimator as the stage is told."""
    from graytrack.core.estimator.live import LiveEstimator

    calibration, _ = build_rig("paper", "", seed=5).record()
    model = calibrate(calibration, "paper").model
    run, truth = build_rig("paper", "knock:um=40:deg=0.2:at_s=2", seed=5, run=1).record(6.0)
    phases = acceleration_phases(run.meta)
    live = LiveEstimator(model, None, "none", settings=EstimatorSettings().for_recording(run.meta),
                         commands_known=True)
    given, found = 0, []
    for k, frame in enumerate(run.frames):
        while given < len(phases) and phases[given, 0] <= run.t[k]:
            live.commanded(*phases[given])
            given += 1
        live.update(frame, float("nan"), float(run.t[k]))
        if "mount" in live.last.message:
            found.append((k, live.last.message))
    knocked = int(np.searchsorted(run.t, 2.0))
    assert len(found) == 1 and knocked <= found[0][0] <= knocked + 2, found
    assert float(found[0][1].split("beyond the ")[1].split(" µm")[0]) < 10.0  # a cruise's allowance, not the 30 µm


def test_a_phase_open_until_the_stage_rests_is_closed_by_giving_it_again():
    """The daemon knows when it told the stage to move, not how long the move takes: the phase is given open
    (end inf, the stage's most) and given again, same start, once the readings show the stage at rest."""
    watch = MountWatch(100.0, 4.0, np.zeros((0, 3)), 5.0, 0.03)
    watch.command(1.0, math.inf)
    assert watch.commands.asked(1.5, 1.52) == 100.0 and watch.commands.asked(50.0, 50.02) == 100.0
    watch.command(1.0, 1.4, None)
    assert watch.commands.starts == [1.0] and watch.commands.asked(1.42, 1.44) == 100.0  # within the servo's settling
    assert watch.commands.asked(1.5, 1.52) == 0.0
    watch.command(2.0, 2.1, 30.0)
    assert watch.commands.asked(2.05, 2.07) == 30.0 and len(watch.commands.starts) == 2
