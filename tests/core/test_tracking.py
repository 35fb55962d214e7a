"""Sequential tracking: lock loss is flagged and re-acquired, never reported one period off."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.errors import TrackingError
from graytrack.core.recording import Recording
from graytrack.core.tracking import Tracker, track
from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.sim import paper


def jump_recording(jump_mm: float = 3.0, at: int = 150, seed: int = 11) -> Recording:
    """Slow motion with one instantaneous jump between frames ``at-1`` and ``at``."""
    x_mm = np.linspace(1.0, 2.5, 300)
    x_mm[at:] += jump_mm
    frames = paper.paper_frames(x_mm, rng=np.random.default_rng(seed))[:, 0, :]
    return Recording(frames.astype(np.float32), np.arange(300) * 1e-3, x_mm, {})


@pytest.mark.parametrize("with_reference", [True, False])
def test_three_mm_jump_is_flagged_and_reacquired(paper_models, with_reference):
    rec = jump_recording()
    reference = rec.reference if with_reference else np.full(rec.n_frames, np.nan)
    result = track(paper_models["paper"].model, rec.frames, reference=reference, x0_mm=rec.reference[0])
    assert [event.frame for event in result.events] == [150]
    assert result.events[0].reacquired
    assert not result.locked[150] and result.locked[:150].all() and result.locked[151:].all()
    error = result.error_um(rec.reference)
    assert np.abs(error).max() < 10.0  # every frame, the jump included, on the right period


def test_jump_beyond_half_a_period_without_reference_is_not_silently_wrong(paper_models):
    """5.5 mm is more than half a period: the image alone cannot tell; the frame must be flagged."""
    rec = jump_recording(jump_mm=5.5)
    result = track(paper_models["paper"].model, rec.frames, x0_mm=rec.reference[0])
    assert result.events and result.events[0].frame == 150
    assert not result.locked[150]
    with_ref = track(paper_models["paper"].model, rec)
    assert np.abs(with_ref.error_um(rec.reference)).max() < 10.0


def test_acquires_without_any_reference(paper_models, paper_val):
    model = paper_models["paper"].model
    start = 700  # inside the calibrated stroke; the periodic image is unique within one period
    result = track(model, paper_val.frames[start:start + 50])
    error = result.error_um(paper_val.reference[start:start + 50])
    offset_periods = np.round(np.nanmedian(error) / (model.period_mm * 1e3))
    assert np.nanstd(error) < 3.0
    assert abs(np.nanmedian(error) - offset_periods * model.period_mm * 1e3) < 5.0


def test_garbage_frame_is_flagged_not_tracked(paper_models, paper_val):
    frames = paper_val.frames[:40].copy()
    frames[20] = np.random.default_rng(0).uniform(0, 255, frames.shape[1])
    result = track(paper_models["paper"].model, frames, reference=paper_val.reference[:40])
    assert not result.locked[20] and np.isnan(result.x_mm[20])
    assert result.locked[21:].all()


def test_wrong_pixel_count_is_refused(paper_models):
    with pytest.raises(TrackingError, match="100 pixels"):
        track(paper_models["paper"].model, np.zeros((3, 64)))


def test_common_mode_gain_is_solved_with_position(paper_models, paper_val):
    model = paper_models["paper"].model.with_changes(common_mode=True, coeffs=paper_models["paper"].model.coeffs)
    gain = 1.0 + 0.05 * np.sin(np.arange(paper_val.n_frames) * 0.3)
    frames = paper_val.frames * gain[:, None] + 3.0
    result = track(model, frames, reference=paper_val.reference)
    np.testing.assert_allclose(result.gain, gain, atol=0.007)  # ≈ 5σ of the gain estimate
    assert np.std(result.error_um(paper_val.reference)) < 1.2 * np.mean(result.crlb_mm) * 1e3
    plain = track(paper_models["paper"].model, frames, reference=paper_val.reference)
    assert np.nanstd(plain.error_um(paper_val.reference)) > 3 * np.std(result.error_um(paper_val.reference))


def test_tracker_refuses_uncalibrated_model(paper_models):
    with pytest.raises(TrackingError, match="calibrate"):
        Tracker(paper_models["paper"].model.with_changes(coeffs=None))


def test_live_tracker_gives_the_batch_answer_frame_by_frame(paper_models):
    from graytrack.core.tracking import LiveTracker

    rec = jump_recording()
    model = paper_models["paper"].model
    batch = track(model, rec)
    live = LiveTracker(model, x0_mm=rec.reference[0])
    fixes = [live.update(frame, reference) for frame, reference in zip(rec.frames, rec.reference)]
    np.testing.assert_allclose([fix.x_mm for fix in fixes], batch.x_mm, atol=1e-9)
    assert [fix.locked for fix in fixes] == batch.locked.tolist()
    assert [k for k, fix in enumerate(fixes) if fix.event] == [150]
    np.testing.assert_allclose([fix.crlb_mm for fix in fixes], batch.crlb_mm, rtol=1e-9)


@pytest.mark.parametrize("start_mm,ambiguous", [(1.0, True), (5.2, False)])
def test_acquisition_without_reference_says_when_the_period_is_a_guess(paper_models, paper_val, start_mm, ambiguous):
    """The paper stroke (10.46 mm) holds 1.2 periods: near its ends the image fits twice, a period
    apart, and only the middle is unique. The tracker says which, instead of picking silently."""
    model = paper_models["paper"].model
    start = int(np.argmin(np.abs(paper_val.reference - start_mm)))
    result = track(model, paper_val.frames[start:start + 20])
    guesses = [event for event in result.events if "period is a guess" in event.reason]
    assert bool(guesses) == ambiguous
    if ambiguous:
        assert guesses[0].frame == 0 and not result.locked[0] and result.locked[1:].all()


def test_a_row_mean_over_samples_at_the_sensor_ceiling_is_set_aside():
    """A 16-row strip seen by a one-row (row-mean) model: a brighter light saturates the top four
    rows where the print is lightest. A mean over a clipped sample is biased by the clip, and
    calibration used no such column; tracked robustly, those columns are set aside (at the limit,
    as the samples stuck there), live as in batch."""
    from graytrack.core.tracking import LiveTracker

    calibration, _ = build_rig("strip16", "quantize:bits=8", seed=3).record(6.0)
    model = calibrate(calibration, "paper").model
    assert model.n_rows == 1 and model.info["sensor_range_gray"] == [0.0, 255.0]
    run, truth = build_rig("strip16", "quantize:bits=8", seed=3, run=1).record(3.0)
    frames = run.frames.copy()
    top = frames[:, :4, :]
    top[top > 150] = 255  # saturated, on those rows only
    assert 0.05 < float((frames == 255).any(axis=1).mean()) < 0.5
    result = track(model, frames, reference=run.reference, light="auto", robust=True)
    error = (result.x_mm - truth.x_mm) * 1e3
    bound = np.sqrt(np.nanmean(np.square(result.crlb_mm * 1e3)))
    assert np.isfinite(result.x_mm).all()
    assert np.std(error) < 1.3 * bound and abs(np.mean(error)) < 0.5 * bound
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    x_live = np.array([live.update(frame, grating).x_mm for frame, grating in zip(frames, run.reference)])
    assert np.max(np.abs(x_live - result.x_mm)) * 1e3 < 1e-9
