"""Noise estimate from the data alone, and the Cramér–Rao bound against simulation."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.noise import crlb_mm, estimate_sigma, pooled_bound
from graytrack.core.tracking import track
from tests.conftest import paper_recording


@pytest.mark.parametrize("sigma_scale", [0.5, 1.0, 3.0])
def test_sigma_from_data_ignores_flicker(sigma_scale):
    rec = paper_recording(n_frames=400, seed=21)
    clean = paper_recording(n_frames=400, seed=21).frames - 0  # same noise draw
    rng = np.random.default_rng(3)
    extra = rng.normal(0, 0.7 * np.sqrt(max(sigma_scale**2 - 1, 0)), clean.shape) if sigma_scale >= 1 else 0
    frames = (clean if sigma_scale >= 1 else clean * 1.0) + extra
    flicker = 1 + 0.03 * np.sin(np.arange(400) * 0.9)
    truth = 0.7 * max(sigma_scale, 1.0)
    estimated = estimate_sigma(frames * flicker[:, None], rec.reference, 8.6)
    assert estimated == pytest.approx(truth * np.mean(flicker), rel=0.06)


def test_bound_predicts_monte_carlo_spread(paper_models):
    """Error std of 400 noisy copies of one frame equals the bound (within sampling error)."""
    model = paper_models["paper"].model
    x_true = 3.3
    clean = model.predict(np.array([x_true]))[0, 0]
    rng = np.random.default_rng(8)
    frames = clean + rng.normal(0, 0.7, (400, clean.size))
    result = track(model, frames, reference=np.full(400, x_true))
    _, slope = model.predict(np.array([x_true]), with_derivative=True)
    bound = crlb_mm(slope, 0.7)[0]
    assert np.std(result.x_mm - x_true) == pytest.approx(bound, rel=0.1)


def test_nuisance_costs_information():
    slope = np.ones((1, 10))
    nuisance = np.stack([np.linspace(0, 1, 10), np.ones(10)], axis=-1)[None]
    assert crlb_mm(slope, 1.0, nuisance)[0] > crlb_mm(slope, 1.0)[0]


def test_sigma_of_coarsely_quantised_frames_includes_the_quantisation():
    """Noise 0.3 of a code on integer codes: the MAD of differences collapses, the variance does not."""
    rec = paper_recording(n_frames=600, seed=23)
    rng = np.random.default_rng(4)
    codes = np.round(rec.frames / 4.0 + rng.normal(0, 0.3, rec.frames.shape) - 0.0)
    expected = np.sqrt(0.7**2 / 16 + 0.3**2 + 1 / 12)  # scaled noise, added noise, quantisation
    assert estimate_sigma(codes, rec.reference, 8.6) == pytest.approx(expected, rel=0.12)


def test_reference_resolution_is_found_only_on_a_grid():
    from graytrack.core.noise import reference_resolution_mm

    x = np.linspace(0, 10, 500)
    assert reference_resolution_mm(np.round(x / 0.005) * 0.005) == pytest.approx(0.005)
    assert reference_resolution_mm(x + np.random.default_rng(0).normal(0, 1e-4, 500)) == 0.0


@pytest.mark.parametrize("per_stop", [2, 3])
def test_sigma_of_a_step_and_settle_sweep_uses_the_stops_only(per_stop):
    """Frames at rest and no period in meta: the moves between stops must not count as noise."""
    from graytrack.drivers.sim import paper

    stops = np.repeat(np.linspace(0, 10, 90), per_stop)
    frames = paper.paper_frames(stops, rng=np.random.default_rng(9))[:, 0, :]
    assert estimate_sigma(frames, stops) == pytest.approx(0.7, rel=0.08)


@pytest.mark.parametrize("grating_um, expected_mm", [(None, (0.0, 0.0005)), (50.0, (0.05,))])
def test_step_and_settle_floor_comes_from_the_grating_not_the_stops(grating_um, expected_mm):
    """Stops 256.5 µm apart, frames at rest only (as the daemon's sweep keeps them): the readout's
    step is the grating's (or unknown), never the spacing of the stops."""
    from graytrack.core.noise import reference_resolution_mm
    from graytrack.drivers.sim.scenarios import build_rig
    from graytrack.drivers.sim.stage import steps

    rig = build_rig("paper", "" if grating_um is None else f"grating_resolution:um={grating_um}", seed=1)
    recording, truth = rig.record(9.0, trajectory=steps(0.0, 0.2565 * 30, 30, 0.2, rig.config.stage))
    at_rest = np.abs(truth.v_mm_s) < 1e-9
    step = reference_resolution_mm(recording.reference[at_rest])
    assert np.diff(np.unique(recording.reference[at_rest])).max() > 0.2  # the stops are there
    assert any(step == pytest.approx(value, abs=1e-9) for value in expected_mm), step


def test_the_pooled_bound_is_the_spread_of_frames_each_at_its_own_bound() -> None:
    """Half the frames with dust in view (bound 0.5 µm), half without (1.5 µm): errors drawn at
    those bounds spread as the pooled bound says, not as the median of either half."""
    rng = np.random.default_rng(3)
    bounds = np.r_[np.full(20_000, 0.5), np.full(20_001, 1.5), np.nan]
    errors = rng.normal(0.0, np.nan_to_num(bounds))
    assert pooled_bound(bounds) == pytest.approx(np.std(errors[:-1]), rel=0.02)
    assert np.nanmedian(bounds) == 1.5 and pooled_bound(bounds) == pytest.approx(np.sqrt(1.25), rel=1e-4)
    assert np.isnan(pooled_bound(np.array([np.nan, np.inf])))
