"""Images a driver delivers twice (same pixels, new timestamp and reference) are not motion."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.core.repeats import repeated
from graytrack.core.tracking import track


REPEATS = np.arange(37, 1000, 41)  # frames the "driver" delivers again


def with_repeats(rec: Recording, at: np.ndarray = REPEATS) -> Recording:
    frames = rec.frames.copy()
    frames[at] = frames[at - 1]
    return Recording(frames, rec.t, rec.reference, dict(rec.meta))


def test_repeated_images_get_no_position_and_the_rest_stays_at_the_bound(paper_models, paper_val):
    rec = with_repeats(paper_val)
    result = track(paper_models["paper"].model, rec, light="auto", robust=True)
    np.testing.assert_array_equal(np.flatnonzero(result.repeated), REPEATS)
    assert np.isnan(result.x_mm[REPEATS]).all()
    assert [e.frame for e in result.events] == list(REPEATS)
    assert all("repeats frame" in e.reason and not e.lost for e in result.events), "set aside, not a loss of lock"
    from graytrack.service.commands.track import summary

    said = "\n".join(summary(result, rec.reference))
    assert "repeats frame" in said and "re-acquired" not in said
    error = result.error_um(rec.reference)
    bound = np.sqrt(np.nanmean(np.square(result.crlb_mm))) * 1e3
    # each repeat shows the stage one frame (10.5 µm) back: counted as motion the std was 1.45× the bound
    assert np.nanstd(error) < 1.15 * bound
    assert np.isfinite(error).sum() == rec.n_frames - REPEATS.size  # every other frame placed
    assert not result.stale.any()


def test_identical_images_are_repeats_only_when_the_noise_rules_out_chance():
    rng = np.random.default_rng(0)
    noisy = rng.normal(100.0, 0.7, (5, 100)).astype(np.float32)
    noisy[3] = noisy[2]
    assert list(repeated(noisy, 0.7)) == [False, False, False, True, False]
    assert not repeated(noisy, 0.0).any()  # a noise-free model: still frames may be identical
    coarse = np.round(rng.normal(100.0, 0.2, (4, 8))).astype(np.uint8)  # 8 pixels, σ ≪ 1 count
    coarse[2] = coarse[1]
    assert not repeated(coarse, 0.2).any()  # 8 samples at 0.2 DN repeat by chance too often to tell


def test_calibration_leaves_repeated_images_out_and_says_so(paper_cal):
    rec = with_repeats(paper_cal)
    result = calibrate(rec, "paper")
    assert result.model.info["repeated_frames"] == REPEATS.size
    assert f"{REPEATS.size} repeated image(s) left out" in result.model.describe()
    clean = calibrate(paper_cal, "paper")
    assert result.rmse_gray == pytest.approx(clean.rmse_gray, rel=0.02)


def test_live_tracking_gives_a_repeated_image_no_position(paper_models, paper_val):
    from graytrack.core.tracking import LiveTracker

    live = LiveTracker(paper_models["paper"].model, x0_mm=float(paper_val.reference[0]))
    fixes = [live.update(paper_val.frames[k], paper_val.reference[k]) for k in (0, 1, 1, 2)]
    assert [np.isfinite(f.x_mm) for f in fixes] == [True, True, False, True]
    assert "repeats frame 1" in fixes[2].event.reason and fixes[3].event is None
    assert abs(fixes[3].x_mm - paper_val.reference[2]) < 0.01


def test_black_or_saturated_frames_in_a_row_are_no_driver_repeat(paper_models, paper_val):
    """Light gone out for 20 frames (every sample at the digitiser's floor), then a flash (every
    sample at full scale): identical images that no noise could have told apart. They are frames
    without a position for want of light, not frames the driver delivered twice; an image clipped
    only in part and delivered twice is still a repeat."""
    frames = paper_val.frames.copy()
    frames[100:120] = 0.0
    frames[150:155] = 255.0
    flags = repeated(frames, 0.7)
    assert not flags[100:120].any() and not flags[150:155].any()
    clipped = paper_val.frames[200].copy()
    clipped[:40] = 255.0
    assert repeated(np.stack([clipped, clipped]), 0.7).tolist() == [False, True]
    result = track(paper_models["paper"].model, frames, reference=paper_val.reference, light="auto", robust=True)
    assert not result.repeated[100:155].any()
    assert not result.locked[100:120].any() and not result.locked[150:155].any()
    assert np.isnan(result.x_mm[100:120]).all()
    assert result.locked[130:145].all() and result.locked[160:].all()  # and found again after each
