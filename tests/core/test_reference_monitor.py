"""The camera-against-grating line: recovered with honest uncertainty, flagged only on evidence."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.reference_monitor import (MIN_FRAMES, Line, ReferenceMonitor, StructureProfile, Trimmer, follow,
                                             structure_profile)
from graytrack.core.validity import FrameSign, Monitor
from graytrack.core.watches.scale import ScaleWatch

BOUND_MM = 1.5e-3


def _sweep(n: int, scale_ppm: float = 0.0, offset_um: float = 0.0, extra_um: float = 0.0, seed: int = 0,
           still_at: float | None = None):
    rng = np.random.default_rng(seed)
    ref = np.full(n, still_at) if still_at is not None else np.linspace(0.0, 10.0, n)
    err_um = (offset_um + scale_ppm * 1e-3 * (ref - 5.0) + rng.normal(0, BOUND_MM * 1e3, n)
              + extra_um * rng.normal(size=n))
    return ref + err_um * 1e-3, ref


def _monitor(**options) -> ReferenceMonitor:
    return ReferenceMonitor(5.0, 5.0, **options)


def test_the_line_is_recovered_within_its_stated_uncertainty():
    pulls = []
    for seed in range(20):
        x, ref = _sweep(500, scale_ppm=-250.0, offset_um=0.4, seed=seed)
        monitor = _monitor()
        for xi, ri in zip(x, ref):
            monitor.observe(xi, ri, BOUND_MM)
        line = monitor.estimate
        pulls.append(((line.scale_ppm + 250.0) / line.scale_sigma_ppm, (line.offset_um - 0.4) / line.offset_sigma_um))
        assert monitor.stale
    pulls = np.array(pulls)
    assert line.scale_sigma_ppm == pytest.approx(1.5 / (np.sqrt(500) * 10.0 / np.sqrt(12)) * 1e3, rel=0.1)
    assert np.all(np.abs(pulls) < 4) and 0.5 < pulls.std() < 1.5


def test_scatter_beyond_the_bounds_widens_the_uncertainty_instead_of_faking_evidence():
    flagged = 0
    for seed in range(20):  # the grating (or a vibration) adds 3 µm rms the bounds do not know
        x, ref = _sweep(2000, extra_um=3.0, seed=seed)
        monitor = _monitor()
        flagged += sum(monitor.observe(xi, ri, BOUND_MM) for xi, ri in zip(x, ref))
        assert monitor.estimate.scale_sigma_ppm > 2.0 * 1.5 / (np.sqrt(500) * 10.0 / np.sqrt(12)) * 1e3
    assert flagged == 0


def test_a_resting_stage_shows_the_offset_only_and_half_a_grating_step_is_no_evidence():
    x, ref = _sweep(600, offset_um=0.2, still_at=2.0)
    monitor = _monitor(resolution_mm=0.5e-3)
    flags = [monitor.observe(xi, ri, BOUND_MM) for xi, ri in zip(x, ref)]
    assert not any(flags)  # 0.2 µm, 4 σ of the mean here, is less than half the 0.5 µm step
    assert abs(monitor.estimate.scale_ppm) < 5.0  # the prior holds the unobservable scale
    x, ref = _sweep(600, offset_um=1.0, still_at=2.0)
    monitor = _monitor(resolution_mm=0.5e-3)
    assert any(monitor.observe(xi, ri, BOUND_MM) for xi, ri in zip(x, ref))


def test_outliers_are_left_out_and_a_real_jump_restarts_the_window():
    x, ref = _sweep(800, seed=2)
    x[300:305] += 0.05  # a few frames 50 µm off (glints)
    monitor = _monitor()
    assert not any(monitor.observe(xi, ri, BOUND_MM) for xi, ri in zip(x, ref))
    x, ref = _sweep(800, seed=3)
    x[400:] += 0.02  # the camera knocked 20 µm along the axis
    monitor = _monitor()
    flags = [monitor.observe(xi, ri, BOUND_MM) for xi, ri in zip(x, ref)]
    assert not any(flags[:400]) and any(flags[400:500]) and flags[-1]  # 25 outliers, then a fresh window


def test_the_trim_waits_for_evidence_then_removes_the_drift_and_can_be_cleared():
    x, ref = _sweep(1500, seed=4)
    assert not follow(_monitor(), x, ref, np.full(x.size, BOUND_MM), trim=True).events
    x, ref = _sweep(1500, scale_ppm=400.0, offset_um=-2.0, seed=5)
    followed = follow(_monitor(), x, ref, np.full(x.size, BOUND_MM), trim=True)
    # (the first frames, 3-4 bounds off the calibration's line, are flagged before the trim: a message first)
    first = next(k for k, event in followed.events if not isinstance(event, str))
    assert np.all(followed.trim_um[:first] == 0) and followed.trim_um[first] != 0
    late = slice(1000, None)
    residual = (followed.x_mm[late] - ref[late]) * 1e3
    assert np.std(residual) < 1.05 * BOUND_MM * 1e3
    assert abs(np.mean(residual)) < 3 * np.mean(followed.trim_sigma_um[late]) < 1.0  # within the trim's own σ
    assert followed.stale[late].sum() == 0
    trimmer = Trimmer(_monitor())
    for xi, ri in zip(x, ref):
        trimmer.observe(xi, ri, BOUND_MM)
    assert trimmer.trim is not None
    cleared = trimmer.clear("calibrated")
    assert cleared.kind == "trim_cleared" and trimmer.trim is None and trimmer.step(3.0) == (3.0, 0.0)


def test_the_watch_blames_scale_through_the_validity_monitor():
    x, ref = _sweep(400, offset_um=3.0, seed=6)
    monitor = Monitor([ScaleWatch(_monitor())])
    verdicts = [monitor.observe(FrameSign(k, information=BOUND_MM ** -2, x_mm=xi, reference_mm=ri))
                for k, (xi, ri) in enumerate(zip(x, ref))]
    assert verdicts[-1].stale and verdicts[-1].reason == "scale"
    assert not verdicts[0].stale  # one frame 2 bounds off (3 by its noise) is no evidence; two at 3-4 are (its
    # running mean judged from the first frame on, at START_LIMIT while it first fills: core/watches/scale.py)
    assert any(v.stale for v in verdicts[:3 * MIN_FRAMES])  # 3 µm at a 1.5 µm bound: evident within a few frames
    unread = Monitor([ScaleWatch(_monitor())])
    assert not any(unread.observe(FrameSign(k, information=BOUND_MM ** -2, x_mm=xi)).stale
                   for k, xi in enumerate(x))  # no grating reading: nothing to say


def test_an_episode_of_frames_off_the_grating_is_flagged_while_chi2_stays_quiet():
    """Forty frames placed 4 bounds off (a smudge coming into view: its wings bend the fit, the frames'
    χ² within their noise): the line's outlier gate leaves them out, yet the camera is off the
    grating; the running mean of camera − grating catches the episode within a window of frames,
    and frames with a wide bound (a transient set aside) weigh as little as they know."""
    from graytrack.core.watches.scale import SUSPECT_WINDOW

    rng = np.random.default_rng(11)
    n, start, stop = 400, 300, 340
    ref = np.linspace(0.0, 10.0, n)
    bound_um = np.full(n, BOUND_MM * 1e3)
    bound_um[start + 10:start + 20] = 20.0  # frames whose bound a transient widened, off the other way
    err_um = rng.normal(0.0, 1.0, n) * bound_um
    err_um[start:stop] += np.where(bound_um[start:stop] > 10.0, 30.0, -4.0 * BOUND_MM * 1e3)
    x = ref + err_um * 1e-3
    watch = ScaleWatch(_monitor())
    flags = [watch.step(False, True, xi, ri, (b * 1e-3) ** -2) for xi, ri, b in zip(x, ref, bound_um)]
    assert not any(flags[:start])  # 300 steady frames at their bound: nothing to say
    episode = flags[start:stop]
    assert set(episode) <= {"scale", None} and episode.count("scale") >= stop - start - SUSPECT_WINDOW // 2
    assert all(episode[-15:])  # flagged to its end (the wide frames thinned the window's information for a while)
    again = ScaleWatch(_monitor())  # χ² suspect over the episode: the same disagreement is called geometry
    suspect = [again.step(start <= k < stop, True, xi, ri, (b * 1e-3) ** -2)
               for k, (xi, ri, b) in enumerate(zip(x, ref, bound_um))]
    assert suspect[stop - 1] == "geometry" and not any(suspect[:start])


def test_a_run_that_starts_off_the_grating_is_flagged_from_its_first_frame():
    """A camera that disagrees with the grating by 10 of its bounds from the start (a print grown,
    a camera moved since calibration) is off on its first frame already: the running mean is
    judged on the frames seen so far, not once its window has filled (until 2026-11-26 the first
    5-15 frames of such runs were called fresh). Steady starts are not flagged by that."""
    for seed in range(5):
        x, ref = _sweep(30, offset_um=10.0 * BOUND_MM * 1e3, seed=seed)
        watch = ScaleWatch(_monitor())
        flags = [watch.step(False, True, xi, ri, BOUND_MM ** -2) for xi, ri in zip(x, ref)]
        assert all(flag == "scale" for flag in flags)
    early = 0
    for seed in range(200):  # 200 starts at the bound: 4,000 first frames
        x, ref = _sweep(20, seed=100 + seed)
        watch = ScaleWatch(_monitor())
        early += sum(watch.step(False, True, xi, ri, BOUND_MM ** -2) is not None for xi, ri in zip(x, ref))
    assert early == 0


def test_a_change_since_calibration_a_few_bounds_off_is_flagged_from_the_runs_second_frame():
    """A 16-row print grown 250 ppm since calibration starts 1.5 µm off the truth, 4.5 of its 0.34 µm
    bounds; read against a 0.5 µm grating that is 3.7 σ of camera − grating a frame. The running mean
    of the first frames (1, 2, 3: 3.7, 4.8, 5.4 σ) is tested at START_LIMIT while it first fills, not at
    the sliding window's SUSPECT_LIMIT: at 6 σ the run's first three frames went unflagged (0.6 % of its
    frames 4+ bounds off without a flag), now only the first. Steady starts stay quiet."""
    from graytrack.core.watches.scale import START_LIMIT, SUSPECT_LIMIT

    assert START_LIMIT < SUSPECT_LIMIT
    bound_mm, step = 0.336e-3, 0.5e-3
    unflagged = []
    for seed in range(20):
        rng = np.random.default_rng(200 + seed)
        true = np.linspace(0.0, 0.4, 20)
        ref = np.round(true / step) * step  # the grating reads to its step
        x = true + 1.46e-3 + rng.normal(0.0, bound_mm, true.size)
        watch = ScaleWatch(ReferenceMonitor(5.0, 5.0, reference_sigma_mm=step / np.sqrt(12), resolution_mm=step))
        flags = [watch.step(False, True, xi, ri, bound_mm ** -2) for xi, ri in zip(x, ref)]
        unflagged.append(sum(flag is None for flag in flags))
    assert sum(unflagged) <= 30 and max(unflagged) <= 2  # the first frame at most, now and then the second
    early = 0
    for seed in range(500):  # 500 steady starts on the same grating: 10,000 first frames
        rng = np.random.default_rng(1000 + seed)
        true = np.linspace(0.0, 0.4, 20)
        x = true + rng.normal(0.0, bound_mm, true.size)
        watch = ScaleWatch(ReferenceMonitor(5.0, 5.0, reference_sigma_mm=step / np.sqrt(12), resolution_mm=step))
        early += sum(watch.step(False, True, xi, ri, bound_mm ** -2) is not None
                     for xi, ri in zip(x, np.round(true / step) * step))
    assert early == 0


def test_a_stage_resting_at_two_places_does_not_take_the_gratings_rounding_for_a_scale():
    rng = np.random.default_rng(7)
    step = 1e-3  # a 1 µm grating: each resting place reads up to ±0.5 µm off, the same in every frame
    true = np.repeat([2.0004, 8.0006, 2.0004, 8.0006], 300)  # read 0.4 µm low, then 0.4 µm high
    ref = np.round(true / step) * step
    x = true + rng.normal(0, 0.38e-3, true.size)  # a 16-row strip's bound
    rounding = ReferenceMonitor(5.0, 5.0, reference_sigma_mm=step / np.sqrt(12), resolution_mm=step,
                                calibration_frames=1000, calibration_x_std_mm=3.0)
    naive = ReferenceMonitor(5.0, 5.0, reference_sigma_mm=0.0, resolution_mm=step,
                             calibration_frames=1000, calibration_x_std_mm=3.0)
    flags = [rounding.observe(xi, ri, 0.38e-3) for xi, ri in zip(x, ref)]
    naive_flags = [naive.observe(xi, ri, 0.38e-3) for xi, ri in zip(x, ref)]
    assert any(naive_flags)  # what it guards against: 0.8 µm of rounding across 6 mm seen as 130 ppm
    assert not any(flags)


def test_a_stage_parked_where_the_model_errs_within_its_bound_is_not_taken_for_a_drift():
    """A model calibrated on 1,200 frames with 132 coefficients leaves ~1 µm of its own error at a
    place it was not fitted to (bound 3 µm): parked there for 1,000 frames the window measures that
    offset to 0.1 µm. Fixed at the place, like the grating's rounding, it is no drift; a print that
    grows 400 ppm while the stage moves is still one."""
    rng = np.random.default_rng(5)
    bound_mm, place_um = 3e-3, 3.0 * np.sqrt(132 / 1200)
    calibration = Line(0.0, 0.0, (0.01, 0.0, 4.0), 5.0, 1200, 5.0)

    def monitor(place_sigma_um: float) -> ReferenceMonitor:
        return ReferenceMonitor(5.0, 5.0, calibration=calibration, calibration_frames=1200, calibration_x_std_mm=3.0,
                                place_sigma_um=place_sigma_um)

    parked = np.full(1000, 4.0)
    x = parked + (-1.2 + rng.normal(0.0, bound_mm * 1e3, parked.size)) * 1e-3  # 0.4 of a bound off there
    naive, honest = monitor(0.0), monitor(place_um)
    assert any(naive.observe(xi, ri, bound_mm) for xi, ri in zip(x, parked))  # what it guards against
    assert not any(honest.observe(xi, ri, bound_mm) for xi, ri in zip(x, parked))
    grown, ref = _sweep(600, scale_ppm=400.0, seed=8)
    moving = monitor(place_um)
    assert any(moving.observe(xi, ri, BOUND_MM) for xi, ri in zip(grown, ref))


def test_the_trim_follows_every_clear_improvement_but_logs_only_large_ones():
    """A trim taken on the first frames of a sweep extrapolates its scale over the stroke it has not
    seen: it is refined quietly whenever a window knows the line clearly better, and only the
    large steps are events (the daemon's log is not a trace)."""
    x, ref = _sweep(500, scale_ppm=-250.0, offset_um=3.0, seed=4)
    trimmer = Trimmer(_monitor())
    events, trims = [], []
    for xi, ri in zip(x, ref):
        if trimmer.observe(xi, ri, BOUND_MM) is not None:
            events.append(trimmer.trim)
        if trimmer.trim is not None and (not trims or trims[-1] is not trimmer.trim):
            trims.append(trimmer.trim)
    assert events and len(trims) > 2 * len(events)
    final = trimmer.trim
    assert abs(final.scale_ppm + 250.0) < 4 * final.scale_sigma_ppm
    assert final.scale_sigma_ppm < trimmer.logged.scale_sigma_ppm / 0.95 or final is trimmer.logged


def test_the_structure_profile_keeps_a_models_error_along_the_stroke_and_drops_mere_noise():
    rng = np.random.default_rng(5)
    x_mm = np.linspace(0.0, 10.0, 1000)
    bound_um = np.full(x_mm.size, 1.5)
    noise_only = structure_profile(x_mm, rng.normal(0.0, 1.5, x_mm.size), bound_um)
    assert noise_only is None  # its means are their own noise: allowed for, not subtracted
    structure = 1.0 * np.sin(2 * np.pi * x_mm / 8.6)  # an error of the model's at the print's period
    profile = structure_profile(x_mm, structure + rng.normal(0.0, 1.5, x_mm.size), bound_um)
    assert profile is not None
    assert profile.noise_um == pytest.approx(1.5 / np.sqrt(1000 / 16), rel=0.3)
    assert np.sqrt(np.mean((profile.at_um(x_mm) - structure) ** 2)) < 2.0 * profile.noise_um
    assert profile.residual_um < 0.5 * np.sqrt(np.mean(structure ** 2))
    assert StructureProfile.from_dict(profile.as_dict()).at_um(5.0) == pytest.approx(profile.at_um(5.0), abs=1e-3)
    readings = np.concatenate([rng.uniform(-1.0, 11.0, 2000), profile.centers_mm])
    # the per-frame form, bit for bit (the compiled batch loop reads the array form)
    assert [profile.at_one_um(float(r)) for r in readings] == profile.at_um(readings).tolist()


@pytest.mark.parametrize("compiled", [False, True])
def test_a_slope_of_the_models_own_structure_over_a_short_stretch_is_no_drift_at_the_centre(compiled):
    """A window over the stroke's first 1.3 mm sees the model's own structure (0.2 µm, fixed along the
    stroke) as a slope of up to 0.2 µm over its half-span: here 1 µm/mm, 3.2 of that slope's σ. Before,
    the structure's slope was held at the centre, so the same slope extrapolated 4.6 mm read as an
    offset 4.6 µm off known to 0.2 µm: flagged (χ² ≈ 500), and a steady run with a seed model's
    telegraph residue trimmed on 433 of its 500 frames. A camera moved 2 µm is still flagged."""
    rng = np.random.default_rng(5)
    ref = np.linspace(0.0, 1.3, 68)
    for offset_um, flagged in ((0.0, False), (2.0, True)):
        monitor = ReferenceMonitor(5.2255, 5.2255, calibration=Line(center_mm=5.2255, covariance=(0.004, 0.0, 400.0)),
                                   calibration_structure_um=0.2)
        error_um = offset_um + 1.0 * (ref - 0.65) + rng.normal(0.0, 0.05, ref.size)
        x = ref + error_um * 1e-3
        bound = np.full(ref.size, 0.05e-3)
        if compiled:
            stale = monitor.observe_many(x, ref, bound, np.ones(ref.size, dtype=bool))[-1]
        else:
            stale = [monitor.observe(xi, ri, bi) for xi, ri, bi in zip(x, ref, bound)][-1]
        assert stale == flagged, monitor.significance


def test_the_structure_left_is_measured_on_whole_stops_the_profile_did_not_see():
    """A sweep of stops whose model error differs from stop to stop (σ 1 µm, finer than the profile's
    stretches): what the profile leaves is that error. Measured on every other frame, each held-out
    frame's stop was in the profile's own frames, and the structure left read as nothing (0.01 µm over
    these seeds); held out by whole readings (core/holdout.py), it reads as what it is."""
    left = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        x_mm = np.repeat(np.linspace(0.0, 10.0, 64), 10)  # 64 stops of 10 frames, one reading each
        per_stop = np.repeat(rng.normal(0.0, 1.0, 64), 10)
        residual = 2.0 * np.sin(2 * np.pi * x_mm / 8.6) + per_stop + rng.normal(0.0, 0.2, x_mm.size)
        profile = structure_profile(x_mm, residual, np.full(x_mm.size, 0.5))
        assert profile is not None
        left.append(profile.residual_um)
    assert 0.7 < np.mean(left) < 1.3, left
