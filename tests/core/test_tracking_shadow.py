"""A cable's shadow sweeping across the field after calibration (drivers/sim/shadow.py), tracked as
`track` does: the shadow's band is learned and followed across the field (core/moving_band.py), with
the grating read and without it, on the paper rig and on a 16-row strip: its frames measured near
the bound, flagged ``light``; none placed far off without a flag, and once the shadow has left the
tracker is back on the calibrated light, at its bound and unflagged, within a few frames. Before
core/chi2_episode.py the shadow's frames held the running χ² (and the grating watch's window) up
for hundreds of frames: the light stayed solved and every frame flagged, three times the frames the
shadow covered. Before core/moving_band.py a shape learned free per column followed the shadow with
the grating only (1.4–2.2× the clean bound; without it 25–83×, on the strip 6–55× with 10 % lost)."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.chi2_episode import RECENT, RecentChi2
from graytrack.core.tracking import LiveTracker, track
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

SHADOW = "moving_shadow:depth=0.33:passes=2:period_s=3:start_s=1.5"
RECOVERY = 12  # frames after the shadow has left by which the tracker is back (the issue: "a few")
FAR = 4.0  # bounds


@pytest.fixture(scope="module")
def model():
    return rig_model("paper", "", seed=3, seconds=16.0)


@pytest.fixture(scope="module")
def shadow_run(model):
    rig = build_rig("paper", SHADOW, seed=5, run=1)
    run, truth = rig.record(7.0)
    in_view = rig.config.illumination.shadow.in_view(truth.t_s, rig.geometry.x_mm)
    return run, truth, in_view, track(model, run, light="auto", robust=True)


@pytest.fixture(scope="module")
def strip_model():
    return rig_model("strip16", "", seed=3, seconds=8.0)


def _ridden(model, scenario: str, grating: bool):
    """(placed, error µm, the clean frames' rms bound µm, frames flagged, placed frames 4+ bounds off
    unflagged, shadow in view) of the shadow run tracked as `track` does, with the grating or without."""
    rig = build_rig(scenario, SHADOW, seed=5, run=1)
    run, truth = rig.record(7.0)
    in_view = rig.config.illumination.shadow.in_view(truth.t_s, rig.geometry.x_mm)
    reference = run.reference if grating else None
    result = track(model, run.frames, reference=reference, x0_mm=float(run.reference[0]), light="auto", robust=True)
    error = (result.x_mm - truth.x_mm) * 1e3
    placed = np.isfinite(error)
    before = ~in_view & (np.cumsum(in_view) == 0)
    clean_bound = float(np.sqrt(np.mean((result.crlb_mm[before] * 1e3) ** 2)))
    silent = placed & ~result.stale & (np.abs(error) > FAR * result.crlb_mm * 1e3)
    return placed, error, clean_bound, result.stale, silent, in_view


def _after(in_view: np.ndarray, frames: int) -> np.ndarray:
    """Frames at least ``frames`` after the shadow last left the field (and before it comes back)."""
    since = np.zeros(in_view.size, dtype=int)
    count = 10**6  # before the first pass: long clear
    for k, shown in enumerate(in_view):
        count = 0 if shown else count + 1
        since[k] = count
    return (since >= frames) & (np.cumsum(in_view) > 0)


def test_back_on_the_calibrated_light_within_a_few_frames(shadow_run):
    run, truth, in_view, result = shadow_run
    assert 0.1 < in_view.mean() < 0.3 and np.count_nonzero(np.diff(in_view.astype(int)) == -1) == 2  # two passes
    back = _after(in_view, RECOVERY)
    assert back.sum() > 100
    assert not result.stale[back].any()  # old code: every one of them flagged (light, geometry, transients)
    assert (result.gain[back] == 1.0).mean() > 0.9  # the light is no longer solved (old: on every frame)
    error, bound = (result.x_mm - truth.x_mm)[back] * 1e3, result.crlb_mm[back] * 1e3
    assert np.sqrt(np.mean(error**2)) < 1.2 * np.sqrt(np.mean(bound**2))
    before = ~in_view & (np.cumsum(in_view) == 0)
    assert np.sqrt(np.mean(bound**2)) < 1.15 * np.sqrt(np.mean((result.crlb_mm[before] * 1e3) ** 2))


def test_flags_the_shadow_not_the_frames_after_it(shadow_run):
    run, truth, in_view, result = shadow_run
    flagged_outside = result.stale & ~in_view
    assert flagged_outside.sum() <= 2 * RECOVERY  # old code: 5x the frames the shadow covered
    assert result.stale.sum() <= 1.5 * in_view.sum()


def test_never_placed_far_off_without_a_flag(shadow_run):
    run, truth, in_view, result = shadow_run
    placed = np.isfinite(result.x_mm)
    assert placed.mean() >= 0.98  # frames lost: at most 2 %
    far = np.abs(result.x_mm - truth.x_mm) > FAR * result.crlb_mm
    silent = far & ~result.stale & placed
    # the shadow's edge entering bends a frame 4-5 bounds at a χ² within its noise: 1 of 350 here
    assert silent.sum() <= 0.005 * placed.sum() and not (silent & ~in_view).any()


def test_rides_through_the_shadow_with_the_grating(shadow_run):
    """The issue's goal: over the whole run, the shadow's frames included, the error's spread within
    1.5× the clean frames' bound with at most 2 % of the frames lost (1.28× here, none lost). The
    shape learned free per column: 1.47×, 1.56× beside the focus follower and the texture."""
    run, truth, in_view, result = shadow_run
    error = (result.x_mm - truth.x_mm) * 1e3
    placed = np.isfinite(error)
    before = ~in_view & (np.cumsum(in_view) == 0)
    clean_bound = np.sqrt(np.mean((result.crlb_mm[before] * 1e3) ** 2))
    assert placed.mean() >= 0.98
    assert np.std(error[placed]) <= 1.5 * clean_bound
    under = in_view & placed
    assert (result.stale_reason[under] == "light").mean() > 0.7  # measured, and said to rest on a learned shape


@pytest.mark.parametrize("scenario,grating", [("paper", False), ("strip16", True), ("strip16", False)])
def test_rides_through_the_shadow_without_the_grating_and_on_a_strip(model, strip_model, scenario, grating):
    """Without the grating the band is learned from the frames alone (the print's pattern moves with
    x, the band with its edges); on a 16-row strip the row mean's lower noise asks more of the shape.
    Measured: paper without the grating 1.31×; the strip 1.19× / 1.23× (1 of 350 frames 4+ bounds off
    unflagged each). Before core/moving_band.py: 25–83× without the grating, the strip 6–55× with
    38–56 frames of 500 lost."""
    placed, error, clean_bound, stale, silent, in_view = _ridden(model if scenario == "paper" else strip_model,
                                                                 scenario, grating)
    assert placed.mean() >= 0.98
    assert np.std(error[placed]) <= 1.5 * clean_bound
    assert silent.sum() <= 0.005 * placed.sum()
    assert not (stale & ~in_view).any()  # outside the shadow nothing flagged


def test_a_steady_run_follows_no_band(model):
    """A clean run: no band is ever taken (nothing flagged), with the grating or without."""
    run, truth = build_rig("paper", "", seed=5, run=1).record(4.0)
    for reference in (run.reference, None):
        result = track(model, run.frames, reference=reference, x0_mm=float(run.reference[0]), light="auto",
                       robust=True)
        assert not result.stale.any() and np.isfinite(result.x_mm).all()


def test_live_tracking_gives_the_batch_answer_through_the_shadow(model, shadow_run):
    run, truth, in_view, result = shadow_run
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fixes = [live.update(frame, grating) for frame, grating in zip(run.frames, run.reference)]
    np.testing.assert_allclose([fix.x_mm for fix in fixes], result.x_mm, atol=1e-9, rtol=0)
    assert [fix.stale_reason or "" for fix in fixes] == result.stale_reason.tolist()


def test_a_level_that_persists_is_never_taken_for_an_episode_that_ended():
    """The recent frames must be at the calibration's level *and* well below the running average:
    a χ² a little up for good keeps the recent frames up with it; a field's answer never counts."""
    limits = [1.0 + 5.0 * np.sqrt(2.0 / (n * 100)) for n in range(1, 101)]
    recent = RecentChi2()
    for _ in range(RECENT):
        recent.add(1.12)
    assert recent.ended(1.12, 1.0, limits) is None  # a persistent rise
    assert recent.ended(1.5, 1.0, limits) == pytest.approx(1.12)  # an episode over it left: restarted at its level
    for _ in range(RECENT):
        recent.add(1.3)
    assert recent.ended(1.8, 1.0, limits) is None  # not back at the calibration's level
    for _ in range(RECENT):
        recent.add(1.0)
    assert recent.ended(1.5, 1.0, limits) == pytest.approx(1.0)  # an episode that has left
    assert recent.ended(1.1, 1.0, limits) is None  # too little above to tell
    recent.add(1.0, plain=False)
    assert recent.ended(1.5, 1.0, limits) is None  # a light field's answer does not end it


@pytest.mark.parametrize("seed,start_s,seconds,grating", [(4, 2.0, 4.0, True), (2, 1.5, 3.0, False)])
def test_the_first_pass_is_measured_from_its_first_frames(model, seed, start_s, seconds, grating):
    """A shadow's first pass (depth 0.2): its first frames, the band's tail alone in view, are answered
    by the band found in them (its depth, softness and place not yet learned, its bound the joint one),
    not by the uniform light, whose answers stood until the band had been seen to move: 16-46 µm off,
    4-15 bounds. Measured 1.24× / 1.17× the clean frames' bound, no frame of the shadow 4+ bounds
    off; on the code before 2.27× / 1.53×, 4 and 2 frames."""
    rig = build_rig("paper", f"moving_shadow:depth=0.2:passes=1:start_s={start_s}", seed=seed, run=1)
    run, truth = rig.record(seconds)
    in_view = rig.config.illumination.shadow.in_view(truth.t_s, rig.geometry.x_mm)
    reference = run.reference if grating else None
    result = track(model, run.frames, reference=reference, x0_mm=float(run.reference[0]), light="auto", robust=True)
    error, bound = (result.x_mm - truth.x_mm) * 1e3, result.crlb_mm * 1e3
    before = ~in_view & (np.cumsum(in_view) == 0)
    clean_bound = float(np.sqrt(np.mean(bound[before] ** 2)))
    assert np.isfinite(error).all()  # none lost
    assert np.std(error) <= 1.5 * clean_bound
    far = np.abs(error) > FAR * bound
    assert (far & in_view).sum() <= 1  # the frame before the band is found, at a χ² within its noise, at most
    assert not (far & ~result.stale).any()
