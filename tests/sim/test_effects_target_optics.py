"""Physical signatures of the target and optics effects (noise-free renders of the clean rig)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.drivers.sim import paper

from .helpers import harmonic_amplitudes, light, one_period, pixel_phase, quiet_rig, sine_fit


def test_clean_rig_is_a_pure_sine_of_the_nominal_period():
    amps = harmonic_amplitudes(one_period(quiet_rig()))
    assert amps[0] == pytest.approx(128.0, abs=1e-9)
    assert amps[1] == pytest.approx(80.0, abs=1e-9)
    assert np.all(amps[2:] < 1e-9)


def test_paper_rig_renders_table2_field():
    rig = quiet_rig("paper")
    x = np.array([0.0, 3.3, 10.46])
    u = np.arange(100.0)
    expected = paper.paper_gray(x[:, None] + paper.PIXEL_PITCH_MM * u, u)
    np.testing.assert_allclose(light(rig, x)[:, 0, :], expected, atol=1e-9)


def test_harmonics_add_the_requested_orders_relative_to_the_fundamental():
    amps = harmonic_amplitudes(one_period(quiet_rig(effects=["harmonics:h2=0.05:h3=0.02:phase2_deg=30"])))
    assert amps[2] / amps[1] == pytest.approx(0.05, rel=1e-6)
    assert amps[3] / amps[1] == pytest.approx(0.02, rel=1e-6)
    assert amps[4] < 1e-9


def test_print_gamma_narrows_the_crests_and_keeps_the_range():
    profile = one_period(quiet_rig(effects=["print_gamma:gamma=1.5"]), n=512)
    lo, hi = profile.min(), profile.max()
    assert (lo, hi) == (pytest.approx(48.0, abs=0.1), pytest.approx(208.0, abs=0.1))
    above = np.mean(profile > 0.5 * (lo + hi))
    # (0.5 + 0.5 sin θ)^1.5 > 0.5  ⇔  sin θ > 2·0.5^(1/1.5) − 1
    expected = (math.pi - 2 * math.asin(2 * 0.5 ** (1 / 1.5) - 1)) / (2 * math.pi)
    assert above == pytest.approx(expected, abs=0.01)
    assert expected < 0.45


def test_pitch_scale_changes_the_printed_period():
    rig = quiet_rig(effects=["pitch_scale:ppm=2000"])
    tau_true = paper.PERIOD_MM * 1.002
    base, shifted_true, shifted_nominal = light(rig, [1.0, 1.0 + tau_true, 1.0 + paper.PERIOD_MM])
    np.testing.assert_allclose(shifted_true, base, atol=1e-8)
    assert np.abs(shifted_nominal - base).max() > 1.0  # 17 µm of phase at ~80·κ gray/mm


def test_chirp_makes_the_local_period_change_along_the_target():
    um, x_stage = 40.0, 2.0
    rig = quiet_rig(effects=[f"chirp:um={um}:order=2"])
    cfg = rig.config.target
    theta = pixel_phase(rig, x_stage)[0]
    kappa = 2 * math.pi / cfg.true_period_mm
    local = np.gradient(theta) / (kappa * rig.pixel_pitch_mm)  # = w'(x): 1 + 2a(x − c)/h²
    x_w = x_stage + rig.pixel_pitch_mm * np.arange(rig.n_pixels)
    expected = 1 + 2 * (um * 1e-3) * (x_w - cfg.chirp_center_mm) / cfg.chirp_half_span_mm**2
    np.testing.assert_allclose(local[2:-2], expected[2:-2], atol=2e-5)
    assert expected[-1] - expected[0] > 1e-3  # the effect is visible, not round-off


def _dip(ratio: np.ndarray) -> tuple[int, float]:
    index = int(np.argmax(np.abs(ratio - 1)))
    return index, float(ratio[index])


def test_dust_is_a_dark_spot_fixed_to_the_target():
    rig = quiet_rig(effects=["dust:count=1:size_um=60:depth=0.5"])
    clean = quiet_rig()
    spot = rig.config.target.defects[0]
    x0 = spot.x_mm - 50 * rig.pixel_pitch_mm
    x = [x0, x0 + 10 * rig.pixel_pitch_mm]
    ratio = light(rig, x)[:, 0] / light(clean, x)[:, 0]
    (u0, r0), (u1, r1) = _dip(ratio[0]), _dip(ratio[1])
    assert u0 == 50 and u1 == 40  # moves with the target, against the stage
    assert r0 < 0.9 and r1 < 0.9  # darker
    assert np.abs(ratio[0, :40] - 1).max() < 1e-6  # local


def test_scratches_are_bright_lines_at_an_angle_across_rows():
    rig = quiet_rig(effects=["rows:n=16", "scratches:count=1:width_um=30:depth=-0.4:angle_deg=30"])
    clean = quiet_rig(effects=["rows:n=16"])
    line = rig.config.target.defects[0]
    x0 = line.x_mm - 50 * rig.pixel_pitch_mm
    ratio = light(rig, [x0])[0] / light(clean, [x0])[0]
    assert ratio.max() > 1.2  # brighter
    peaks = []
    for row in ratio:  # sub-pixel peak by a parabola through the three highest samples
        i = int(np.argmax(row))
        a, b, c = row[i - 1], row[i], row[i + 1]
        peaks.append(i + 0.5 * (a - c) / (a - 2 * b + c))
    slope = np.polyfit(np.arange(16), peaks, 1)[0]
    assert slope == pytest.approx(math.tan(math.radians(30)), rel=0.03)


def test_a_defect_narrower_than_a_pixel_is_averaged_over_the_pixel_footprint():
    """A pixel integrates the light over its footprint: a 15 µm scratch seen by 62 µm pixels is a
    box-smoothed dip whose area (depth × σ√2π) is the scratch's own, its peak lowered to that area
    over the footprint; the scratch's centre at the pixel's centre or at its edge changes the
    reading continuously, never the spike a point sample would give."""
    from graytrack.drivers.sim.target import Defect, defect_gain

    sigma, depth, footprint = 0.015, 0.5, 0.062
    scratch = [Defect("scratch", 0.0, 0.0, sigma, depth)]
    x = np.linspace(-0.3, 0.3, 6001)
    point = defect_gain(scratch, x, 0.0)
    pixel = defect_gain(scratch, x, 0.0, aperture_mm=footprint)
    area = depth * sigma * math.sqrt(2 * math.pi)
    dx = x[1] - x[0]
    assert np.sum(1 - point) * dx == pytest.approx(area, rel=1e-4)
    assert np.sum(1 - pixel) * dx == pytest.approx(area, rel=1e-4)
    assert 1 - point.min() == pytest.approx(depth, rel=1e-6)
    assert 1 - pixel.min() == pytest.approx(area / footprint * math.erf(footprint / 2 / sigma / math.sqrt(2)),
                                            rel=1e-4)
    # half a footprint off the scratch, the pixel sees half of the scratch; a point sample far less
    edge = np.argmin(np.abs(x - footprint / 2))
    assert 1 - pixel[edge] == pytest.approx(0.5 * area / footprint * math.erf(footprint / sigma / math.sqrt(2)),
                                            rel=1e-3)
    assert 1 - point[edge] < 0.5 * (1 - pixel[edge])


def test_defocus_attenuates_harmonic_i_by_gaussian_mtf():
    sigma, tau = 0.3, paper.PERIOD_MM
    amps = harmonic_amplitudes(one_period(quiet_rig(effects=["harmonics:h2=0.1:h3=0",
                                                             f"defocus:sigma_um={sigma * 1e3}"])))
    mtf = lambda i: math.exp(-2 * math.pi**2 * sigma**2 * (i / tau) ** 2)  # noqa: E731
    assert amps[1] == pytest.approx(80 * mtf(1), rel=1e-6)
    assert amps[2] == pytest.approx(8 * mtf(2), rel=1e-6)
    assert amps[0] == pytest.approx(128.0, abs=1e-9)


def test_focus_drift_moves_the_blur_sigma_by_pixels_from_its_start_and_never_below_sharp():
    """From start_s the rig renders as a defocus of σ₀ + px·α·d would (σ on the target), before it
    as σ₀; a sharper change than the base blur clips at a sharp image."""
    pitch = paper.PIXEL_PITCH_MM
    x, before, after = np.linspace(0.0, 5.0, 5), np.full(5, 0.5), np.full(5, 1.5)
    drifting = quiet_rig("paper", ["defocus:sigma_um=200", "focus_drift:px=-0.5:start_s=1"])
    for t, sigma_um in ((before, 200.0), (after, 200.0 - 500.0 * pitch)):
        expected = light(quiet_rig("paper", [f"defocus:sigma_um={sigma_um}"]), x, t)
        np.testing.assert_allclose(light(drifting, x, t), expected, atol=1e-9)
    ramped = quiet_rig("paper", ["defocus:sigma_um=200", "focus_drift:px=2:start_s=0:ramp_s=2"])
    halfway = quiet_rig("paper", [f"defocus:sigma_um={200.0 + 1000.0 * pitch}"])
    np.testing.assert_allclose(light(ramped, x, np.ones(5)), light(halfway, x), atol=1e-9)
    sharp = quiet_rig("paper", ["defocus:sigma_um=20", "focus_drift:px=-3"])
    np.testing.assert_allclose(light(sharp, x, after), light(quiet_rig("paper"), x), atol=1e-9)


def test_focus_cycle_comes_and_goes_back_to_the_base_blur():
    """A temperature cycle: from start_s the blur σ moves to σ₀ + px·α·d at half a period and is back
    at σ₀ after a whole one (and again after two)."""
    pitch = paper.PIXEL_PITCH_MM
    x = np.linspace(0.0, 5.0, 5)
    cycling = quiet_rig("paper", ["defocus:sigma_um=200", "focus_cycle:px=1:period_s=4:start_s=1"])
    base = light(quiet_rig("paper", ["defocus:sigma_um=200"]), x)
    for t in (0.5, 5.0, 9.0):  # before the first cycle, after one, after two
        np.testing.assert_allclose(light(cycling, x, np.full(5, t)), base, atol=1e-9)
    peak = light(quiet_rig("paper", [f"defocus:sigma_um={200.0 + 1000.0 * pitch}"]), x)
    np.testing.assert_allclose(light(cycling, x, np.full(5, 3.0)), peak, atol=1e-9)
    quarter = light(quiet_rig("paper", [f"defocus:sigma_um={200.0 + 500.0 * pitch}"]), x)
    np.testing.assert_allclose(light(cycling, x, np.full(5, 2.0)), quarter, atol=1e-9)


def test_tilt_shifts_the_phase_linearly_with_row():
    deg = 5.0
    rig = quiet_rig(effects=["rows:n=16", f"tilt:deg={deg}"])
    theta = pixel_phase(rig, 2.0)
    row_phase = (theta - theta[0]).mean(axis=1)
    kappa = 2 * math.pi / paper.PERIOD_MM
    slope, intercept = np.polyfit(np.arange(16), row_phase, 1)
    assert slope == pytest.approx(-kappa * rig.pixel_pitch_mm * math.sin(math.radians(deg)), rel=1e-3)
    assert np.abs(row_phase - (slope * np.arange(16) + intercept)).max() < 1e-6
    untilted = pixel_phase(quiet_rig(effects=["rows:n=16"]), 2.0)
    assert np.abs(untilted - untilted[0]).max() < 1e-9


def test_distortion_stretches_the_pixel_footprint_towards_the_edges():
    k1 = 0.05
    rig = quiet_rig(effects=[f"distortion:k1={k1}"])
    kappa = 2 * math.pi / paper.PERIOD_MM
    footprint = np.gradient(pixel_phase(rig, 2.0)[0]) / (kappa * rig.pixel_pitch_mm)
    rho = (np.arange(100) - 49.5) / 50
    expected = 1 + 3 * k1 * rho**2  # d/du of (u − c)(1 + k1 ρ²)
    np.testing.assert_allclose(footprint[2:-2], expected[2:-2], atol=5e-4)
    assert footprint[2] - footprint[50] > 0.1


def _frame_amplitudes(frames: np.ndarray, rig) -> np.ndarray:
    phase = 2 * math.pi * rig.pixel_pitch_mm * np.arange(rig.n_pixels) / rig.config.target.true_period_mm
    return np.array([sine_fit(f.astype(float), phase)[0] for f in frames.reshape(frames.shape[0], -1)])


@pytest.mark.parametrize("extra", [[], ["chirp:um=0.001"]], ids=["fast-path", "slow-path"])
def test_motion_blur_loses_amplitude_as_sinc(extra):
    from graytrack.drivers.sim.stage import constant_velocity

    exposure_ms, v = 20.0, 100.0
    rig = quiet_rig(effects=[f"motion_blur:exposure_ms={exposure_ms}", *extra])
    rec, truth = rig.record(0.05, trajectory=constant_velocity(0.5, v))
    ratio = _frame_amplitudes(rec.frames, rig) / 80.0
    blur = v * exposure_ms * 1e-3 / paper.PERIOD_MM
    assert blur > 0.2
    np.testing.assert_allclose(ratio, math.sin(math.pi * blur) / (math.pi * blur), rtol=2e-4)
    still, _ = rig.record(0.05, trajectory=constant_velocity(0.5, 0.0))
    np.testing.assert_allclose(_frame_amplitudes(still.frames, rig), 80.0, rtol=1e-6)


def test_dust_settles_one_speck_at_a_time_and_stays_on_the_print():
    """``dust_settling``: specks land at their own times between start_s and start_s + over_s, sizes
    within the range given (in pixel footprints); before its time a speck's place is clean, after
    it the speck darkens the print there whatever the frame's position."""
    from graytrack.drivers.sim.effects import apply_effects
    from graytrack.drivers.sim.scenarios import build_config
    from graytrack.drivers.sim.target import defect_gain

    config = build_config("paper")
    apply_effects(config, "dust_settling:count=12:start_s=1:over_s=4:size_min_px=0.2:size_max_px=0.5", seed=2)
    specks = config.target.defects
    times = np.array([d.start_s for d in specks])
    assert len(specks) == 12 and np.all(np.diff(times) >= 0) and 1.0 <= times.min() and times.max() <= 5.0
    sizes = np.array([d.size_mm for d in specks]) / config.optics.pixel_pitch_mm
    assert np.all((sizes >= 0.2) & (sizes <= 0.5))
    speck = specks[5]
    at = np.array([[speck.x_mm]])
    before, after = (defect_gain([speck], at, speck.y_mm, t_s=np.array([t])) for t in (speck.start_s - 0.01,
                                                                                       speck.start_s + 0.01))
    assert before[0, 0] == 1.0 and after[0, 0] == pytest.approx(1.0 - speck.depth)
    assert defect_gain([speck], at, speck.y_mm)[0, 0] == pytest.approx(1.0 - speck.depth)  # no time: all landed
