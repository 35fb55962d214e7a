"""The per-frame features' fast paths against their per-frame Python paths: the frames' stretches
by one compiled call (core/stretch.py) against numpy's least squares, the magnification watch's
compiled running sums (core/watches/_kernels.py) against its ``step`` frame by frame, the focus
solve's own estimate and blur variance solved inside its kernel against the small solves it
replaced, and whole runs, where the watch flags and where the focus moves, tracked both ways."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core import small_linalg, stretch
from graytrack.core.calibration import calibrate
from graytrack.core.focus_solve import _TRIG_OUT, _trig_focus, focus_moments, focus_solve
from graytrack.core.focus_follow import FocusFollow
from graytrack.core.solvers import FrameSolution
from graytrack.core.tracking import LiveTracker, Tracker, track
from graytrack.core.watches import _kernels
from graytrack.core.watches.magnification import MagnificationWatch, StretchProfile
from graytrack.drivers.sim.scenarios import build_rig

pytestmark = pytest.mark.skipif(not _kernels.COMPILED, reason="numba missing: the watches step in Python")

DRIFT = "magnification_drift:ppm=3000:ramp_s=6"  # the lens warming up: the watch names it within the run
BLUR = "defocus:sigma_um=200"  # the rig's own blur: a focus that drifts from it is followed
FOCUS = f"{BLUR},focus_drift:px=1:ramp_s=4"


@pytest.fixture(scope="module")
def rigs():
    """(model, run) of a 1-row paper rig whose lens warms up, and of one whose focus drifts."""
    out = {}
    for name, base, later in (("magnification", "", DRIFT), ("focus", BLUR, FOCUS)):
        calibration, _ = build_rig("paper", base, seed=4).record(8.0)
        run, _ = build_rig("paper", later, seed=4, run=1).record(6.0)
        out[name] = (calibrate(calibration, "paper").model, run)
    return out


def per_frame(monkeypatch) -> None:
    """The features' per-frame path: numpy's stretch for each frame, the watch stepped frame by frame."""
    monkeypatch.setattr(stretch, "COMPILED", False)
    monkeypatch.setattr(_kernels, "COMPILED", False)


OUTPUTS = ("x_mm", "crlb_mm", "locked", "chi2", "stale", "stale_reason", "focus_px2", "focus_sigma_px2", "gain")


@pytest.mark.parametrize("name", ["magnification", "focus"])
def test_a_run_is_tracked_as_frame_by_frame(monkeypatch, rigs, name):
    """Batch and live, where the watch flags (a lens warming up) and where the focus moves (the focus
    term taken, the stretch fitted beside a change of focus): every position, bound, flag and reason
    the same, bit for bit, whether the features run compiled or frame by frame in numpy."""
    model, run = rigs[name]
    fast = track(model, run.frames, light="auto", robust=True)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fast_live = [live.update(frame) for frame in run.frames[:150]]
    per_frame(monkeypatch)
    slow = track(model, run.frames, light="auto", robust=True)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    slow_live = [live.update(frame) for frame in run.frames[:150]]
    for field in OUTPUTS:
        a, b = getattr(fast, field), getattr(slow, field)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), field
    assert [f.stale_reason for f in fast_live] == [f.stale_reason for f in slow_live]
    for field in ("x_mm", "crlb_mm", "focus_px2", "focus_sigma_px2"):
        assert np.array_equal([getattr(f, field) for f in fast_live], [getattr(f, field) for f in slow_live],
                              equal_nan=True), field
    assert (fast.stale_reason == name).sum() > 20  # the comparison covered flagged frames
    if name == "focus":
        assert (fast.stale_reason == "focus").sum() > 50 and np.isfinite(fast.focus_px2).sum() > 100


def test_the_compiled_stretch_is_numpys_least_squares(monkeypatch, rigs):
    """Each frame's (m, σ), with the stretch alone, beside a change of focus and with pixels set aside,
    as numpy's inverse of the normal equations gives them: to 1e-7 of σ (the curvature column, by
    differences of slopes, leaves the five-column equations conditioned to ~1e4: rounding, ~1e-9)."""
    model, run = rigs["focus"]
    tracker = Tracker(model, light="auto", robust=True)
    batch = tracker.batch(tracker.prepare(run.frames[:60]), 1)
    rng = np.random.default_rng(0)
    frames = []
    for k, x in enumerate(run.reference[:60]):
        mask = rng.random(model.n_pixels) < 0.05 if k % 3 == 0 else None
        solution = FrameSolution(float(x) + 1e-4, 1.0, 1e8, 3, 1.0 + 0.01 * rng.normal(), rng.normal(),
                                 rejected_mask=mask, focus_sigma=0.1 if k % 2 else math.nan)
        frames.append(stretch.FrameStretch(tracker, batch, k, solution))
    m, sigma = stretch.stretches(frames)
    one_by_one = np.array([frame() for frame in frames])
    monkeypatch.setattr(stretch, "COMPILED", False)
    expected = np.array([frame() for frame in frames])
    assert np.array_equal(one_by_one, np.stack([m, sigma], axis=1))  # live's call, one frame: the same kernel
    assert np.all(np.isfinite(expected))
    assert np.max(np.abs(m - expected[:, 0]) / expected[:, 1]) < 1e-7
    assert np.max(np.abs(sigma / expected[:, 1] - 1.0)) < 1e-7


def stretch_signs(n: int, seed: int) -> tuple[list[bool], list[float], list]:
    """Frames' stretches: quiet, then a lens's growing stretch (flagged), then one that turns with the
    print's phase (significant, but a print's change: numpy's turning check keeps the flag down), gaps."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    x = 5.0 + 10.0 * np.sin(k / 8.0)  # the stage sweeping over periods: every phase seen within the memory
    phase = 2 * np.pi * x / 8.6
    m = np.where(k > n // 3, 800e-6, 0.0) + np.where(k > 2 * n // 3, 3000e-6 * np.cos(phase), 0.0)
    sigma = 300e-6 * (1.0 + rng.random(n))
    m = m + sigma * rng.normal(size=n)
    placed = (rng.random(n) > 0.03).tolist()
    x[rng.random(n) < 0.02] = np.nan
    entries = [None if rng.random() < 0.03 else (lambda m=m[i], s=sigma[i]: (m, s)) for i in range(n)]
    entries[5] = lambda: (math.nan, math.inf)  # a frame that cannot tell
    return placed, x.tolist(), entries


def test_the_magnification_watch_many_frames_at_once_as_frame_by_frame():
    """``step_many`` chunk by chunk, as batch tracking calls it, against ``step``: the same families and
    the same running sums, bit for bit, across a flag that rises and one a turning stretch holds down."""
    from graytrack.core.validity import Columns, _observe_all

    n = 1500
    placed, x, entries = stretch_signs(n, 3)
    profile = StretchProfile((1.0, 3.0, 5.0), (50.0, -20.0, 10.0), 30.0)
    at_once, stepped = MagnificationWatch(8.6, profile, record=True), MagnificationWatch(8.6, profile, record=True)
    families = []
    for start, stop in ((0, 400), (400, 401), (401, n)):
        part = Columns({"placed": placed[start:stop], "x_mm": x[start:stop], "stretch": entries[start:stop]})
        families += _observe_all(at_once, part, stop - start)
    expected = [stepped.step(*row) for row in zip(placed, x, entries)]
    assert families == expected
    assert "magnification" in families and families[-1] is None  # the flag rose, and the turning held it down
    assert at_once.turning_ppm > 0 and at_once.turning_ppm == stepped.turning_ppm
    for name in ("_normal", "_noise", "_right", "_scalars"):
        assert np.array_equal(getattr(at_once, name), getattr(stepped, name)), name
    assert at_once.record == stepped.record


def test_the_focus_solves_own_estimate_and_blur_variance_are_the_small_solves(rigs):
    """The frame's own (g, h, o) and the blur coefficient's variance, solved inside the focus kernel,
    against small_linalg's solve and inverse of the same normal equations and Fisher matrix (what the
    solve did in Python before): the same numbers, bit for bit, with a prior and without."""
    model, run = rigs["focus"]
    tracker = Tracker(model, light="auto", robust=True)
    batch = tracker.batch(tracker.prepare(run.frames[::30]), 1)
    follow = FocusFollow()
    for _ in range(12):
        follow.add(2e-5, 1e-5)
    for k, x in enumerate(run.reference[::30]):
        start = FrameSolution(float(x), 1.0, 1e8, 3)
        for prior in (None, follow.prior()):
            solution = focus_solve(batch, k, tracker._curvature, start, tracker.settings, model.pixel_pitch_mm, prior)
            rows, cc, scalars = focus_moments(batch, k, tracker._curvature, None)
            out = np.empty(_TRIG_OUT)
            has = prior is not None
            _trig_focus(rows, cc, batch.tables.phase_orders, scalars[0], scalars[1], scalars[2], float(x), 1.0, 0.0,
                        has, prior.delta_mm2 if has else 0.0, prior.variance_mm4 if has else 0.0,
                        tracker.settings.max_iterations, tracker.settings.tolerance_mm, tracker.settings.max_step_mm,
                        out)
            own = small_linalg.solve(out[7:16].reshape(3, 3), out[16:19])
            blur_variance = small_linalg.inv(out[19:35].reshape(4, 4))[2, 2]
            footprint = model.pixel_pitch_mm ** 2
            assert solution.focus == own[1] / own[0] / footprint
            assert solution.focus_sigma == math.sqrt(max(blur_variance, 0.0)) / abs(own[0]) / footprint
            assert solution.x_mm == out[0]


def test_a_drifted_line_steps_the_scale_watch_on_stretches_computed_at_once(monkeypatch, rigs):
    """Where the line camera − grating drifts (the lens warming up), the scale watch names the stretch
    frame by frame; the chunk's stretches are computed first by one compiled call. Against the frames
    stepped one by one with each frame's own call (the path before): every position, bound, flag and
    reason bit for bit, and the stepped chunk was the path taken."""
    from graytrack.core.watches.scale import ScaleWatch

    model, run = rigs["magnification"]
    taken = []
    stepped = ScaleWatch._stepped
    monkeypatch.setattr(ScaleWatch, "_stepped", lambda watch, columns: taken.append(1) or stepped(watch, columns))
    fast = track(model, run.frames, reference=run.reference, light="auto", robust=True)
    assert taken  # the line drifted within the chunk
    monkeypatch.setattr(ScaleWatch, "_stepped", lambda watch, columns: None)  # _observe_all steps each frame
    slow = track(model, run.frames, reference=run.reference, light="auto", robust=True)
    for field in OUTPUTS:
        a, b = getattr(fast, field), getattr(slow, field)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), field
    assert (fast.stale_reason == "magnification").sum() > 20 and (fast.stale_reason == "scale").sum() > 0
