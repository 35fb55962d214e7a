"""The lens's magnification drifting during a run (the virtual rig's ``magnification_drift``),
tracked as ``graytrack track`` does: named ``magnification`` without a grating, followed by the trim
with one, never silently wrong; scored against the truth."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model
from graytrack.core.drift_cause import lens_favoured
from graytrack.core.watches.scale import STRETCH_Z
from graytrack.service.commands.track_scale import check, scale_watch

DRIFT = "magnification_drift:ppm=3000:ramp_s=6"  # the lens warming up; the axis 300 px off: 56 µm of slide


@pytest.fixture(scope="module")
def rig():
    calibration, _ = build_rig("paper", "", seed=11).record(8.0)
    model = calibrate(calibration, "paper").model
    run, truth = build_rig("paper", DRIFT, seed=11, run=1).record(6.0)
    steady, steady_truth = build_rig("paper", "", seed=11, run=2).record(6.0)
    return model, run, truth, steady, steady_truth


def _tracked(model, run, truth, trim: bool, grating: bool):
    reference = run.reference if grating else np.full(run.n_frames, np.nan)
    watch = scale_watch(run, model, reference, trim)
    result = track(model, run.frames, reference, light="auto", robust=True, watches=[watch] if watch else [])
    flagged = result.stale | (check(run, model, result, trim, watch).columns["scale_stale"] == 1)
    error_um = (result.x_mm - truth.x_mm) * 1e3
    if not grating:  # acquired on the image alone: its origin is known up to whole periods
        error_um -= model.period_mm * 1e3 * np.round(np.nanmedian(error_um) / (model.period_mm * 1e3))
    return result, error_um, result.crlb_mm * 1e3, flagged


def test_without_a_grating_the_drift_is_named_magnification(rig):
    model, run, truth, steady, steady_truth = rig
    result, error_um, bound_um, flagged = _tracked(model, run, truth, trim=False, grating=False)
    late = slice(run.n_frames // 2, None)
    assert np.mean(result.stale_reason[late] == "magnification") > 0.9
    _, _, _, quiet = _tracked(model, steady, steady_truth, trim=False, grating=False)
    assert quiet.mean() < 0.01


def test_with_the_trim_it_is_followed_and_never_silently_wrong(rig):
    model, run, truth, *_ = rig
    result, error_um, bound_um, flagged = _tracked(model, run, truth, trim=True, grating=True)
    placed = np.isfinite(error_um)
    assert np.std(error_um[placed]) < 1.3 * np.sqrt(np.mean(bound_um[placed] ** 2))
    far = placed & (np.abs(error_um) > 4.0 * bound_um)
    assert (far & ~flagged).sum() <= 0.005 * placed.sum()


@pytest.fixture(scope="module")
def cycle(rig):
    """The lens's temperature cycle on the same rig: 0.15 % out and back within 6 s."""
    run, truth = build_rig("paper", "magnification_drift:ppm=1500:cycle_s=6", seed=11, run=3).record(10.0)
    return rig[0], run, truth


def test_a_cycle_is_named_magnification_while_its_slide_turns(cycle):
    """The monitor's line (500 frames) averages a cycle's slide rising and falling to no scale; the line of
    the last 100 frames (core/watches/scale.py ``LOCAL_WINDOW``) reads the slide turning at once: 36 of
    461 flagged frames named ``scale`` (122 on the monitor's line alone), every flagged frame still flagged."""
    model, run, truth = cycle
    result, _, _, flagged = _tracked(model, run, truth, trim=False, grating=True)
    named = collections.Counter(result.stale_reason[flagged].tolist())
    assert flagged.mean() > 0.9 and named["scale"] <= 0.15 * flagged.sum(), named


def test_the_stretch_names_the_lens_as_soon_as_it_explains_the_line_better():
    """With the grating read and no trim, the line camera − grating drifts first (the slide) and the
    stretch picks the cause. The paper rig's 1500 ppm ramp at its frame 321: stretch 600 ± 216 ppm,
    the line's scale −2505 ± 45 (no grown print: that would stretch the image by the scale). Held to 3σ
    that frame was named ``scale`` (29 such frames between frames named ``magnification``); a print's
    stretch is still not a lens's, nor is a line shifted without a scale (a camera moved on its mount)
    with a stretch within 1.5σ of none."""
    assert lens_favoured(600.0, 216.0, -2505.0, 45.0 ** 2)
    assert not 600.0 ** 2 > STRETCH_Z ** 2 * 216.0 ** 2  # what the 3σ rule alone said
    assert not lens_favoured(-450.0, 200.0, -250.0, 30.0 ** 2)  # a print grown 250 ppm, its stretch 1σ off
    assert not lens_favoured(300.0, 200.0, 0.0, 45.0 ** 2)  # 1.5σ and the line's scale unchanged: no cause told


def test_with_the_grating_the_drift_is_named_magnification_from_its_first_flags(rig):
    """The line camera − grating drifts before the stretch is significant; its scale, the slide's growth
    over the stage's speed, is one no grown print makes without stretching the image by as much and no
    grating or mount makes at all (core/drift_cause.py), so the drift is the lens's from its first
    flags: 2 of 277 flagged frames named ``scale`` (109 while the stretch alone had to tell)."""
    model, run, truth, *_ = rig
    result, _, _, flagged = _tracked(model, run, truth, trim=False, grating=True)
    named = collections.Counter(result.stale_reason[flagged].tolist())
    assert flagged.mean() > 0.9 and named["scale"] <= 0.03 * flagged.sum(), named


def test_with_the_grating_the_drift_is_named_magnification_not_scale(rig):
    model, run, truth, *_ = rig
    result, _, _, flagged = _tracked(model, run, truth, trim=False, grating=True)
    late = slice(run.n_frames // 2, None)
    named = result.stale_reason[late][flagged[late]]
    assert np.mean(named == "magnification") > 0.9, collections.Counter(named.tolist())


FAR = "magnification_drift:ppm=3000:axis_px=-1000:ramp_s=6"  # the axis 1000 px off: the slide reaches 185 µm


@pytest.fixture(scope="module")
def far(rig):
    """The lens's ramp on the same rig with the optical axis far off the ROI: from frame ~215 the camera
    is more than 100 of its bounds off the grating, where the far-off judgement speaks (a wrong model's)."""
    run, truth = build_rig("paper", FAR, seed=11, run=4).record(6.0)
    return rig[0], run, truth


def test_a_lens_sliding_the_camera_far_off_the_grating_is_named_magnification_not_a_wrong_model(far):
    """Untrimmed, the scale watch carries the far-off judgement (core/watches/far_off.py) and names it with
    what drifted the line: the lens's. Every frame from the first one 100 bounds off is named
    ``magnification``; before, the far-off watch alone named them ``scale`` (a model of another period or
    pitch), decisively: 60 of 294 flagged frames, all from frame 259 on (now 14, the ramp's first flags).
    A model 5 % off in period is still ``scale`` (tests/core/test_validity.py)."""
    model, run, truth = far
    result, _, _, flagged = _tracked(model, run, truth, trim=False, grating=True)
    beyond = np.abs(result.x_mm - run.reference) > 100.0 * result.crlb_mm
    first = int(np.argmax(beyond))
    assert beyond.any() and first < run.n_frames - 60  # the far frames are the run's last ~85
    assert flagged[first:].all()
    assert (result.stale_reason[first:] == "magnification").all(), collections.Counter(result.stale_reason[first:])
    named = collections.Counter(result.stale_reason[flagged].tolist())
    assert named["scale"] <= 0.1 * flagged.sum(), named


def test_the_far_lens_is_named_the_same_chunk_by_chunk_as_frame_by_frame(monkeypatch, far):
    """The scale watch's chunk paths (the line held: the far-off judgement over the chunk at once; drifted:
    named frame by frame beside the line) against its ``step`` on every frame: the same reasons, bit for bit."""
    from graytrack.core.watches.scale import ScaleWatch

    model, run, _ = far
    chunked = track(model, run.frames, run.reference, light="auto", robust=True)
    monkeypatch.setattr(ScaleWatch, "step_many", lambda watch, columns, n: None)  # _observe_all steps each frame
    stepped = track(model, run.frames, run.reference, light="auto", robust=True)
    assert np.array_equal(chunked.stale_reason, stepped.stale_reason)
    assert (chunked.stale_reason == "magnification").sum() > 200


@pytest.fixture(scope="module")
def strip():
    """A 16-row strip's model, calibrated on 8 s of the rig as it was."""
    return rig_model("strip16", "", seed=3, seconds=8.0)


def test_a_16_row_lens_ramp_is_named_magnification_from_its_first_flags(strip):
    """The line drifts on frame 18 of a 16-row strip's lens ramp, before the magnification watch has the
    frames its own flag waits for (``MIN_FRAMES``); the cause is weighed on the stretches seen so far
    (``MagnificationWatch.so_far``: their level and its σ from their own noise and scatter) beside the line's
    scale of thousands of ppm, which no grown print gives with a stretch near none: 1 of the run's first 82
    flagged frames named ``scale`` (7 before, frames 18-24). A grown print is still ``scale``
    (tests/diagnosis/test_target_growth_end_to_end.py)."""
    run, truth = build_rig("strip16", "magnification_drift:ppm=1500:ramp_s=10", seed=3, run=1).record(2.0)
    result, _, _, flagged = _tracked(strip, run, truth, trim=False, grating=True)
    named = collections.Counter(result.stale_reason[flagged].tolist())
    assert flagged.sum() > 70 and flagged[-50:].all()
    assert named["scale"] <= 2 and named["magnification"] >= flagged.sum() - 2, named


@pytest.mark.parametrize("trajectory", ["rest", "sweep"])
def test_a_16_row_model_of_another_period_far_off_is_still_the_models_scale(strip, trajectory):
    """The far-off judgement the scale watch carries names a model 1 % off in period ``scale`` (its stretch
    is the line's scale, or the line cannot tell: no lens's), on every settled frame, as its own module did."""
    from graytrack.core.watches.far_off import WINDOW
    from graytrack.drivers.sim.stage import oscillation

    wrong = strip.with_changes(period_mm=strip.period_mm * 1.01, coeffs=strip.coeffs)
    motion = {"trajectory": oscillation(5.0, 0.0, 1.0)} if trajectory == "rest" else {}
    run, _ = build_rig("strip16", "", seed=3, run=1).record(2.0, **motion)
    watch = scale_watch(run, wrong, run.reference)
    result = track(wrong, run, light="auto", robust=True, watches=[watch])
    settled = result.stale_reason[WINDOW + 10:]
    assert (settled == "scale").all(), collections.Counter(settled.tolist())
