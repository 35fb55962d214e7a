"""Focus drifting between calibration and measurement (a lens mount warming up): the tracker
solves the change of blur as a nuisance when the frames ask for it, keeps x at its bound with it
profiled out, and the light field (which mimics a blur by trading its shape against x) is not
taken when the focus explains the frames as well with fewer unknowns. The focus watch flags a
sustained change; a steady run is never flagged."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis import diagnose
from graytrack.core.focus_solve import CurvatureTable, focus_solve
from graytrack.core.solvers import FrameSolution
from graytrack.core.tracking import Tracker, track
from graytrack.core.validity import FrameSign
from graytrack.core.watches.focus import FocusWatch
from graytrack.drivers.sim.scenarios import build_config, build_rig

BASE = "defocus:sigma_um=200"  # the rig's own blur (3.2 px): a sharper image has blur to lose
SECONDS = {"paper": 16.0, "strip16": 8.0}


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.square(values))))


@pytest.fixture(scope="module")
def recordings():
    return {scenario: build_rig(scenario, BASE, seed=3).record(seconds)[0] for scenario, seconds in SECONDS.items()}


@pytest.fixture(scope="module")
def models(recordings):
    return {(scenario, kind): calibrate(rec, "paper").model if kind == "paper" else diagnose(rec).final_model
            for scenario, rec in recordings.items() for kind in ("paper", "diagnose")}


def true_change_px2(scenario: str, px: float) -> float:
    optics = build_config(scenario, f"{BASE},focus_drift:px={px}").optics
    sigma = optics.defocus_sigma_mm + optics.focus_drift_mm
    return (sigma**2 - optics.defocus_sigma_mm**2) / optics.pixel_pitch_mm**2


def watched(result) -> np.ndarray:
    """The focus watch's verdict on every frame of a tracked run."""
    watch = FocusWatch()
    return np.array([watch.observe(FrameSign(k, focus=f, focus_sigma=s)) == "focus"
                     for k, (f, s) in enumerate(zip(result.focus_px2, result.focus_sigma_px2))])


def without_focus(model) -> Tracker:
    tracker = Tracker(model, light="auto", robust=True)
    tracker.focus_capable = False  # the tracker as it was before the focus term
    return tracker


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
@pytest.mark.parametrize("kind", ["paper", "diagnose"])
@pytest.mark.parametrize("px", [0.5, -0.5])
def test_focus_drift_after_calibration_is_measured_at_the_bound(models, scenario, kind, px):
    model = models[scenario, kind]
    run, _ = build_rig(scenario, f"{BASE},focus_drift:px={px}", seed=3, run=1).record(SECONDS[scenario] / 2)
    result = track(model, run, light="auto", robust=True)
    error, bound = result.error_um(run.reference), result.crlb_mm * 1e3
    assert np.isfinite(result.x_mm).all()
    ratio = float(np.std(error)) / rms(bound)
    flagged = watched(result).mean()
    assert ratio <= 1.3 or flagged >= 0.9, (ratio, flagged)
    assert ratio <= 1.2  # measured at the bound (flagged or not)
    if scenario == "strip16":
        # 16 rows see the blur change on every frame: it is solved, physically right, and flagged
        estimated = np.isfinite(result.focus_px2)
        assert estimated[-len(error) // 2:].mean() > 0.9
        focus, sigma = result.focus_px2[estimated], result.focus_sigma_px2[estimated]
        mean = float(np.sum(focus / sigma**2) / np.sum(sigma**-2))
        truth = true_change_px2(scenario, px)
        assert mean == pytest.approx(truth, rel=0.15)
        assert flagged > 0.6 and watched(result)[-len(error) // 2:].all()
        before = track(model, run, tracker=without_focus(model))
        assert float(np.std(before.error_um(run.reference))) > 1.5 * rms(before.crlb_mm * 1e3)  # the field's bias


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_a_steady_focus_is_never_flagged(models, scenario):
    model = models[scenario, "paper"]
    run, _ = build_rig(scenario, BASE, seed=3, run=1).record(SECONDS[scenario] / 2)
    result = track(model, run, light="auto", robust=True)
    assert watched(result).mean() < 0.01
    assert rms(result.error_um(run.reference)) <= 1.2 * rms(result.crlb_mm * 1e3)


def test_the_light_field_is_still_taken_when_the_light_changes_shape(models):
    """A light gradient is no blur: the field explains it far better, and is taken."""
    model = models["strip16", "paper"]
    run, _ = build_rig("strip16", f"{BASE},gradient:per_10mm=0.05", seed=3, run=1).record(4.0)
    result = track(model, run, light="auto", robust=True)
    error, bound = result.error_um(run.reference)[-100:], result.crlb_mm[-100:] * 1e3
    assert rms(error) <= 1.3 * rms(bound)
    assert not watched(result)[-100:].any()


def test_focus_solve_recovers_an_exact_blur_and_its_bound_is_the_schur_complement(models):
    """A frame rendered from the model with each harmonic attenuated exactly by a blur change of
    2 px²: the solve finds x and δ; its information is 1/[I⁻¹]ₓₓ of the Fisher matrix of
    (x, g, h, o) built from numerical derivatives of the exactly blurred model."""
    model = models["strip16", "paper"]
    tracker = Tracker(model, light="auto")
    fast, pitch = tracker.tables.fast, model.pixel_pitch_mm
    omega = 2 * math.pi / model.period_mm
    delta_mm2 = 4.0 * pitch**2

    def blurred(x: float, delta: float) -> np.ndarray:
        z = np.exp(1j * omega * x * fast.harmonics)
        return fast.constant + ((z * np.exp(-0.5 * delta * (omega * fast.harmonics) ** 2)) @ fast.v).real

    x_true, gain, offset = 3.1, 0.93, 5.0
    sigma = model.noise_gray / 8.0
    rng = np.random.default_rng(5)
    y = gain * blurred(x_true, delta_mm2) + offset + rng.normal(0.0, sigma, fast.constant.size)
    weights = np.full((1, y.size), 1.0 / sigma**2)
    from graytrack.core.solvers import TrigPolyBatch

    batch = TrigPolyBatch(tracker.tables, y[None], weights)
    start = FrameSolution(x_true + 0.02, 0.0, 0.0, 0, 1.0, 0.0)
    solution = focus_solve(batch, 0, CurvatureTable(tracker.tables, model.period_mm), start, tracker.settings, pitch)
    assert abs(solution.x_mm - x_true) < 4.0 / math.sqrt(solution.information)
    assert solution.focus == pytest.approx(4.0, abs=4.0 * solution.focus_sigma)
    assert solution.focus > 3.0 * solution.focus_sigma
    assert solution.gain == pytest.approx(gain, rel=1e-2) and solution.chi2 < 1.2
    h, x, d = 1e-6, solution.x_mm, solution.focus * pitch**2
    g = solution.gain
    columns = [g * (blurred(x + h, d) - blurred(x - h, d)) / (2 * h), blurred(x, d),
               g * (blurred(x, d + 1e-7) - blurred(x, d - 1e-7)) / 2e-7, np.ones(y.size)]
    jacobian = np.stack(columns, axis=1)
    fisher = jacobian.T @ (jacobian * weights[0][:, None])
    covariance = np.linalg.inv(fisher)
    assert 1.0 / solution.information == pytest.approx(covariance[0, 0], rel=2e-2)
    assert solution.focus_sigma == pytest.approx(math.sqrt(covariance[2, 2]) / pitch**2, rel=5e-2)


def test_focus_watch_needs_a_sustained_and_physical_change():
    watch = FocusWatch()
    assert watch.observe(FrameSign(0, focus=40.0, focus_sigma=1.0)) is None  # one wild frame says nothing
    steady = [watch.observe(FrameSign(k, focus=0.1 * (-1) ** k, focus_sigma=1.0)) for k in range(1, 60)]
    assert not any(steady)
    small = FocusWatch()  # precise but harmless: 0.1 px² at 0.01 px² per frame
    assert not any(small.observe(FrameSign(k, focus=0.1, focus_sigma=0.01)) for k in range(60))
    moved = FocusWatch()
    verdicts = [moved.observe(FrameSign(k, focus=3.0 + 0.5 * (-1) ** k, focus_sigma=2.0)) for k in range(60)]
    assert verdicts[-1] == "focus" and verdicts[0] is None
    later = [moved.observe(FrameSign(60 + k)) for k in range(FocusWatch().window)]
    assert later[-1] is None  # a window without estimates: forgotten


def test_the_general_path_solves_the_same_focus(models):
    """A model off the fast path (here forced) solves the blur from the model evaluated at x: the
    same x, δ and bound as the fast path's moments, to the differences' accuracy."""
    from graytrack.core.focus_solve import general_focus_solve

    model = models["strip16", "paper"]
    tracker = Tracker(model, light="auto")
    run, _ = build_rig("strip16", f"{BASE},focus_drift:px=0.5", seed=3, run=1).record(0.5)
    batch = tracker.batch(model.prepare(run.frames), run.frames.shape[1])
    curvature = CurvatureTable(tracker.tables, model.period_mm)
    for k in range(0, batch.n_frames, 5):
        start = FrameSolution(float(run.reference[k]) + 0.003, 0.0, 0.0, 0, 1.0, 0.0)
        fast = focus_solve(batch, k, curvature, start, tracker.settings, model.pixel_pitch_mm)
        general = general_focus_solve(tracker.evaluator, batch.frames[k], batch.weights(k), start, tracker.settings,
                                      model.period_mm, model.pixel_pitch_mm)
        assert general.x_mm == pytest.approx(fast.x_mm, abs=0.02 / math.sqrt(fast.information))
        assert general.focus == pytest.approx(fast.focus, abs=0.02 * fast.focus_sigma)
        assert general.information == pytest.approx(fast.information, rel=1e-3)


def test_live_tracking_carries_the_focus(models):
    """The daemon's LiveTracker solves the same focus term and reports it with each fix."""
    from graytrack.core.tracking import LiveTracker

    model = models["strip16", "paper"]
    run, _ = build_rig("strip16", f"{BASE},focus_drift:px=0.5", seed=3, run=1).record(2.0)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fixes = [live.update(frame, float(reference)) for frame, reference in zip(run.frames, run.reference)]
    batch = track(model, run, light="auto", robust=True)
    focus = np.array([fix.focus_px2 for fix in fixes])
    np.testing.assert_allclose(focus, batch.focus_px2, rtol=1e-6, atol=1e-9, equal_nan=True)
    assert np.isfinite(focus[-50:]).all()
    np.testing.assert_allclose([fix.x_mm for fix in fixes], batch.x_mm, atol=1e-9, rtol=0)


def test_focus_watch_allows_the_range_the_model_was_calibrated_over():
    class Calibrated:
        info = {"calibration_focus_range_px2": [-4.0, 4.0]}
        n_rows, n_pixels = 1, 100

    inside, outside = FocusWatch.for_model(Calibrated()), FocusWatch.for_model(Calibrated())
    assert not any(inside.observe(FrameSign(k, focus=3.0, focus_sigma=0.5)) for k in range(60))
    assert outside.observe(FrameSign(0, focus=6.0, focus_sigma=0.5)) is None
    assert [outside.observe(FrameSign(k, focus=6.0, focus_sigma=0.5)) for k in range(60)][-1] == "focus"
