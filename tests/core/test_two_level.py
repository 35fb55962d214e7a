"""Pixels that read at one of two levels (core/estimator/two_level.py): found on calibration's sweep where each
level is held over runs of frames whatever the sample sees, and each frame's level taken out while tracking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.estimator import EstimatorSettings
from graytrack.core.estimator.filter import Estimator, track
from graytrack.core.estimator.two_level import TWO_LEVEL, TwoLevel, found
from graytrack.core.recording import acceleration_phases
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

TELEGRAPH = "telegraph_pixels:count=3"


def _switching(rng: np.random.Generator, frames: int, rate_per_frame: float) -> np.ndarray:
    """A two-state sequence that leaves its state with ``rate_per_frame`` each frame (True: high)."""
    state = np.zeros(frames, dtype=bool)
    for k in range(1, frames):
        state[k] = (not state[k - 1]) if rng.random() < rate_per_frame else state[k - 1]
    return state


def test_a_sample_holding_two_levels_whatever_it_sees_is_found_and_nothing_else():
    """On a synthetic sweep of 1,000 frames at 50 frames/s: two traps (6 and 4 gray, switching 4 and 2 times a
    second) are found with their levels and rates; a sample whose residual follows the print's sine (a gain's), one
    clipped at the print's bright phase, one a mark darkens at one place of the stroke, one a glint lifts for a frame
    or two, and every sample at once on a few stretches of frames (a change of the whole image) are not."""
    rng = np.random.default_rng(11)
    frames, samples = 1000, 12
    t = np.arange(frames) / 50.0
    x = np.linspace(0.0, 10.0, frames)
    h = 120.0 + 80.0 * np.sin(2.0 * np.pi * x[:, None] / 2.0 + np.linspace(0.0, 3.0, samples)[None, :])
    noise = 0.7
    r = noise * rng.standard_normal((frames, samples))
    r[:, 1] += 6.0 * _switching(rng, frames, 4.0 / 50.0)
    r[:, 2] += 4.0 * _switching(rng, frames, 2.0 / 50.0)
    r[:, 3] += 0.05 * (h[:, 3] - 120.0)  # a gain of its own: its residual a sine of the print's phase
    r[:, 4] -= np.clip(h[:, 4] - 180.0, 0.0, None)  # clipped at the bright phase
    r[:, 5] -= 30.0 * np.exp(-0.5 * ((x - 6.0) / 0.05) ** 2)  # a mark the print carries past the sample
    glints = (rng.random(frames) < 0.1) & (np.abs(x - 3.0) < 0.5)  # a glossy spot of the print over the sample
    r[:, 6] += 60.0 * (glints | np.roll(glints, 1))  # a glint for a frame or two
    whole = (np.arange(frames) // 100) % 3 == 1
    r[:, 7:] += 5.0 * whole[:, None]  # every sample at once
    stretch = np.minimum((x / 10.0 * 8).astype(int), 7)
    kept = found(r, h, t, stretch)
    assert kept is not None and kept.samples.tolist() == [1, 2]
    assert np.allclose(kept.high - kept.low, [6.0, 4.0], atol=0.2)
    assert np.allclose(kept.sigma, noise, rtol=0.15)
    assert np.allclose(kept.rate_hz, [4.0, 2.0], rtol=0.3)


def test_a_frames_level_is_the_likelier_one_with_the_switching_rate_as_its_prior():
    """A value at either level is taken at it; one half-way is taken where the sample was (leaving a level is the
    rarer thing), its weight cut by what the choice leaves open; a level taken out is written down."""
    levels = TwoLevel(np.array([2]), np.array([0.0]), np.array([6.0]), np.array([0.7]), np.array([4.0]))
    y, mask = np.full(4, 100.0), np.ones(4)
    modes, taken = np.zeros(1, dtype=bool), np.zeros(4)
    residual = np.array([0.0, 0.0, 5.8, 0.0])
    out = levels.apply(y.copy(), mask, residual, None, 0.02, modes, taken)
    assert modes[0] and taken[2] == 6.0 and out[2] == pytest.approx(1.0, abs=1e-6)
    y_half = y.copy()
    out = levels.apply(y_half, mask, np.array([0.0, 0.0, 3.0, 0.0]), None, 0.02, modes, taken)
    assert modes[0] and y_half[2] == pytest.approx(94.0) and out[2] < 0.2 and mask[2] == 1.0
    levels.apply(y.copy(), mask, np.array([0.0, 0.0, 0.1, 0.0]), None, 0.02, modes, taken)
    assert not modes[0] and taken[2] == 0.0


def test_a_document_of_another_shape_or_version_is_not_read():
    good = TwoLevel(np.array([1, 3]), np.zeros(2), np.full(2, 6.0), np.full(2, 0.7), np.full(2, 4.0)).as_dict()
    assert TwoLevel.from_info({TWO_LEVEL: good}, 4) is not None
    assert TwoLevel.from_info({TWO_LEVEL: good}, 3) is None
    assert TwoLevel.from_info({TWO_LEVEL: {**good, "version": 99}}, 4) is None
    assert TwoLevel.from_info({TWO_LEVEL: {**good, "sigma_gray": [0.7, -1.0]}}, 4) is None
    assert TwoLevel.from_info({TWO_LEVEL: {**good, "rate_hz": [4.0]}}, 4) is None
    assert TwoLevel.from_info({}, 4) is None


def _tracked(model, run, grating: str) -> tuple[Estimator, np.ndarray, np.ndarray, list]:
    estimator = Estimator(model, settings=EstimatorSettings().for_recording(run.meta), grating=grating,
                          stage_phases=acceleration_phases(run.meta))
    estimates = track(model, run.frames, run.t, run.reference, estimator=estimator)
    return estimator, np.array([e.x_mm for e in estimates]), np.array([e.crlb_mm for e in estimates]), estimates


@pytest.mark.parametrize("scenario, effects", [("paper", TELEGRAPH),
                                               ("strip16", "row_banding:gray=1,telegraph_pixels:count=6")])
def test_the_rigs_flickering_pixels_are_found_at_calibration_and_a_steady_run_learns_nothing_of_them(scenario,
                                                                                                      effects):
    """Calibration finds the rig's telegraph pixels and no other (the truth's), their 6-gray swing and their flips.
    A steady run, with the grating read and without it, then learns no mark on the print from their flips (each flip
    landed as a candidate in both maps, and now and then the print's took one: a steady run learned one to two),
    flags none of its frames and states a bound its errors keep."""
    seconds = 10.0 if scenario == "strip16" else 20.0
    model = rig_model(scenario, effects, seed=3, seconds=seconds)
    run, truth = build_rig(scenario, effects, seed=3, run=1).record(seconds / 2)
    kept = TwoLevel.from_info(model.info, model.n_rows * model.n_pixels)
    pixels = truth.info["config"]["sensor"]["bad_pixels"]
    assert kept is not None
    assert sorted(kept.samples.tolist()) == sorted(p["row"] * model.n_pixels + p["pixel"] for p in pixels)
    assert np.allclose(kept.high - kept.low, 6.0, atol=0.4)
    # (~4 flips a second; a strip's row banding, a gray on every row each frame, adds a few a second the noise makes)
    assert np.all((kept.rate_hz > 2.5) & (kept.rate_hz < 8.0))
    for grating in ("check", "none"):
        estimator, x, bound, estimates = _tracked(model, run, grating)
        error = (x - truth.x_mm) * 1e3
        if grating == "none":
            period = model.period_mm * 1e3
            error -= period * np.round(np.nanmedian(error) / period)
        placed = np.isfinite(error)
        assert placed.mean() > 0.99
        assert not (estimator.print_map.learned() & ~estimator.print_map.restored).any()
        assert sum(e.stale for e in estimates) < 0.01 * len(estimates)
        assert np.all(np.abs(error[placed]) < 4.0 * bound[placed] * 1e3)
        if grating == "check":
            assert 0.8 <= math.sqrt(np.mean((error[placed] / (bound[placed] * 1e3)) ** 2)) <= 1.25
