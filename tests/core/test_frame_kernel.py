"""The per-frame solve in one call (core/frame_kernel.py): compiled with numba, and its Python twin
(the same control logic on numpy primitives, what GRAYTRACK_KERNEL=numpy runs) give the same
positions, bounds and flags to 1e-9 µm, on frames with each effect family the closed loop can add."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core import frame_kernel, kernels
from graytrack.core.solvers import FrameSolution
from graytrack.core.tracking import LiveTracker, Tracker, track
from graytrack.drivers.sim.causes import EFFECT_CAUSES
from tests.core.test_kernels import MICROMETRE_TOLERANCE, _fitted

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba is not installed: nothing to compare")


def _both(monkeypatch: pytest.MonkeyPatch, run_it):
    compiled = run_it()
    with monkeypatch.context() as patch:
        patch.setattr(kernels, "COMPILED", False)
        fallback = run_it()
    return compiled, fallback


def _same_track(a, b) -> None:
    placed = np.isfinite(a.x_mm)
    assert placed.mean() > 0.9
    assert np.array_equal(np.isfinite(b.x_mm), placed)
    assert np.max(np.abs(a.x_mm[placed] - b.x_mm[placed])) * 1e3 < MICROMETRE_TOLERANCE
    assert np.allclose(a.crlb_mm[placed], b.crlb_mm[placed], rtol=1e-9)
    assert np.array_equal(a.locked, b.locked)
    assert np.array_equal(a.rejected_px, b.rejected_px)
    assert np.array_equal(a.transient_px, b.transient_px)
    assert np.allclose(a.chi2, b.chi2, rtol=1e-9, equal_nan=True)
    assert np.array_equal(a.stale, b.stale)


@pytest.mark.parametrize("name", sorted(EFFECT_CAUSES))
def test_compiled_and_numpy_solves_track_alike(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    model, run = _fitted(name)
    compiled, fallback = _both(monkeypatch, lambda: track(model, run, tracker=Tracker(model, light="auto",
                                                                                      robust=True)))
    _same_track(compiled, fallback)


@pytest.mark.parametrize("name", ["target_map", "rows", "bad_pixels", "common_mode"])
def test_compiled_and_numpy_solves_agree_on_glints_and_bad_pixels(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames with a glint (a compact blob), a stuck pixel and a dark one: the robust solve, its blob
    search and its masks run in every frame, compiled and as the twin, live and in batch."""
    model, run = _fitted(name)
    frames = np.array(run.frames, dtype=np.float64)
    rng = np.random.default_rng(3)
    width = frames.shape[-1]
    for k in range(frames.shape[0]):
        centre = int(rng.integers(5, width - 5))
        bump = 60.0 * np.exp(-0.5 * ((np.arange(width) - centre) / 1.2) ** 2)
        if frames.ndim == 3:
            frames[k, : frames.shape[1] // 3] += bump  # a few rows only
        else:
            frames[k] += bump
    frames[..., 7] = frames.max() + 50.0  # a stuck pixel
    frames[..., width // 2] *= 0.2  # a dark one
    reference = np.asarray(run.reference)

    def batch():
        return track(model, frames, reference=reference, light="auto", robust=True)

    compiled, fallback = _both(monkeypatch, batch)
    _same_track(compiled, fallback)
    assert compiled.rejected_px.max() > 0 and compiled.transient_px.max() > 0

    def live():
        tracker = LiveTracker(model, x0_mm=float(reference[0]))
        return [tracker.update(frame, grating) for frame, grating in zip(frames, reference)]

    compiled_live, fallback_live = _both(monkeypatch, live)
    for a, b in zip(compiled_live, fallback_live):
        assert np.isfinite(a.x_mm) == np.isfinite(b.x_mm)
        if np.isfinite(a.x_mm):
            assert abs(a.x_mm - b.x_mm) * 1e3 < MICROMETRE_TOLERANCE
            assert a.crlb_mm == pytest.approx(b.crlb_mm, rel=1e-9)
        assert (a.rejected_px, a.transient_px, a.locked) == (b.rejected_px, b.transient_px, b.locked)


def test_one_robust_call_compiled_and_as_python() -> None:
    """The kernel's entry points directly: same row of FIELDS, same mask, from a start mask and without."""
    model, run = _fitted("target_map")
    tracker = Tracker(model, light="auto", robust=True)
    y = model.prepare(run.frames[:1]).reshape(-1).copy()
    y[10:14] += 80.0  # a blob
    y[40] = 0.0  # a dead sample
    w = tracker.static_weights[0]
    x0 = float(run.reference[0]) + 2e-3
    start = np.zeros(y.size, dtype=bool)
    start[40] = True
    for mask in (None, start):
        answers = []
        for compiled in (True, False):
            kernels.COMPILED = compiled
            try:
                out, set_aside = frame_kernel.robust(tracker.evaluator, y, w, x0, 1.0, 0.0, True, mask,
                                                     tracker.chi2_limit, tracker.layout, 5, 1e-5, 0.25)
                answers.append((out.copy(), set_aside.copy()))
            finally:
                kernels.COMPILED = True
        (a, mask_a), (b, mask_b) = answers
        assert abs(a[0] - b[0]) * 1e3 < MICROMETRE_TOLERANCE
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True)
        assert np.array_equal(mask_a, mask_b) and mask_a[40] and mask_a[10:14].all()


def _focus_solves_agree(solve) -> None:
    """``solve(prior)`` compiled and as Python, with and without the last frames' prior: position,
    light, δ and its error, and the bound agree."""
    from graytrack.core.focus_solve import FocusPrior

    for prior in (None, FocusPrior(1e-5, 1e-10)):
        answers = []
        for compiled in (True, False):
            kernels.COMPILED = compiled
            try:
                answers.append(solve(prior))
            finally:
                kernels.COMPILED = True
        a, b = answers
        assert abs(a.x_mm - b.x_mm) * 1e3 < MICROMETRE_TOLERANCE
        assert a.iterations == b.iterations > 1
        for field in ("information", "gain", "offset_gray", "chi2", "focus", "focus_sigma", "cost"):
            assert getattr(a, field) == pytest.approx(getattr(b, field), rel=1e-9, abs=1e-12), field
        assert math.isfinite(a.focus) and a.focus_sigma > 0


def _start(run) -> FrameSolution:
    return FrameSolution(float(run.reference[0]) + 1e-3, float("nan"), 0.0, 0, 1.02, -0.5)


def test_the_general_focus_solve_compiled_and_as_python() -> None:
    """The focus nuisance off the trig tables (a target map)."""
    from graytrack.core.focus_solve import general_focus_solve

    model, run = _fitted("target_map")
    tracker = Tracker(model, light="auto", robust=True)
    y = model.prepare(run.frames[:1]).reshape(-1)
    _focus_solves_agree(lambda prior: general_focus_solve(tracker.evaluator, y, tracker.static_weights[0], _start(run),
                                                          tracker.settings, model.period_mm, model.pixel_pitch_mm,
                                                          prior))


def test_the_trig_path_focus_solve_compiled_and_as_python() -> None:
    """The focus nuisance on the fast path's moments (the seed paper's model on a blurred frame)."""
    from graytrack.core.focus_solve import CurvatureTable, focus_solve

    model, run = _fitted("focus")
    tracker = Tracker(model, light="auto", robust=True)
    assert tracker.fast_path
    batch = tracker.batch(model.prepare(run.frames[:1]))
    curvature = CurvatureTable(tracker.tables, model.period_mm)
    _focus_solves_agree(lambda prior: focus_solve(batch, 0, curvature, _start(run), tracker.settings,
                                                  model.pixel_pitch_mm, prior))


def test_the_curvature_row_is_folded_anew_unless_the_same_memory_holds_the_same_weights() -> None:
    """The focus's weighted curvature row is kept for a batch's new view of the weights its frames share
    (the whole of one buffer: no address asked of numpy), and folded anew for the same values elsewhere
    (another alignment may sum in another order) or for values changed in place."""
    from graytrack.core.focus_solve import CurvatureTable

    model, _ = _fitted("focus")
    tracker = Tracker(model, light="auto", robust=True)
    curvature = CurvatureTable(tracker.tables, model.period_mm)
    shared = np.random.default_rng(3).uniform(0.5, 1.0, size=(1, model.n_pixels))
    first = curvature.weighted(shared[0])
    assert curvature.weighted(shared[0]) is first  # a new view of the same buffer
    assert np.array_equal(first, shared[0] @ curvature.table)
    elsewhere = shared.copy()
    assert curvature.weighted(elsewhere[0]) is not first  # the same values in another buffer
    assert curvature.weighted(shared[0]) is not first  # ... and back: the last seen was the copy
    kept = curvature.weighted(shared[0])
    shared[0, 5] *= 2.0
    changed = curvature.weighted(shared[0])
    assert changed is not kept and np.array_equal(changed, shared[0] @ curvature.table)
    strided = np.repeat(shared, 2, axis=1)[0, ::2]  # a view of half a buffer: compared by address
    assert curvature.weighted(strided) is not changed and curvature.weighted(strided[:]) is curvature.weighted(strided)


def test_the_fused_sample_weights_are_inverse_variance(monkeypatch: pytest.MonkeyPatch) -> None:
    """A live frame's weights in one compiled pass: 1/σ²(y) of the photon-transfer model times the
    pixel's weight and the rows averaged, zero at the sensor's limits, bit for bit numpy's."""
    from graytrack.core.pixel_noise import PixelNoise

    rng = np.random.default_rng(5)
    noise = PixelNoise(read_var=2.0, shot_gain=0.2, dark_gray=40.0, quant_var=1 / 12)
    y = rng.uniform(0.0, 4095.0, size=(1, 300))
    y[0, :3] = (0.0, 4095.0, 30.0)
    pixel_weight = (rng.uniform(size=300) > 0.1).astype(float)
    expected = 1.0 / noise.variance(y) * pixel_weight * 4
    inside = (y > 0.0) & (y < 4095.0)
    for compiled in (True, False):
        monkeypatch.setattr(kernels, "COMPILED", compiled)
        weights, shared = frame_kernel.sample_weights(y, noise, pixel_weight, 4, None)
        assert shared and np.array_equal(weights, expected)
        weights, shared = frame_kernel.sample_weights(y, noise, pixel_weight, 4, (0.0, 4095.0))
        assert not shared and np.array_equal(weights, expected * inside)
