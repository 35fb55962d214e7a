"""A print that grew since calibration, tracked with the trim (``track --trim``): the trim's scale
accounts for the stretch of the image, so its positions are measured, not flagged; untrimmed, the
same run is still flagged. Scored against the truth."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model
from graytrack.service.commands.track_scale import check, scale_watch

GROWTH = "target_growth:ppm=250"  # humidity: the 16-row print 250 ppm longer than at calibration


@pytest.fixture(scope="module")
def grown():
    model = rig_model("strip16", "", seed=3, seconds=6.0)
    run, truth = build_rig("strip16", GROWTH, seed=3, run=1).record(6.0)
    return model, run, truth


def _tracked(model, run, trim: bool):
    watch = scale_watch(run, model, run.reference, trim)
    result = track(model, run, light="auto", robust=True, learn=True, watches=[watch] if watch else [])
    flagged = result.stale | (check(run, model, result, trim, watch).columns["scale_stale"] == 1)
    return result, flagged


def test_a_grown_print_under_the_trim_is_measured_not_flagged(grown):
    model, run, truth = grown
    result, flagged = _tracked(model, run, trim=True)
    assert flagged.mean() < 0.03, collections.Counter(result.stale_reason[flagged])  # main: most, `magnification`
    error_um = (result.x_mm - truth.x_mm) * 1e3
    placed = np.isfinite(error_um)
    far = placed & (np.abs(error_um) > 4.0 * result.crlb_mm * 1e3)
    # the first frames come before any evidence of the growth (the monitor's first line): 3 of them are off
    assert not (far & ~flagged)[5:].any()


def test_a_grown_print_without_the_trim_is_still_flagged(grown):
    model, run, _ = grown
    result, flagged = _tracked(model, run, trim=False)
    assert flagged[run.n_frames // 4:].mean() > 0.9
    assert set(result.stale_reason[flagged]) <= {"scale", "magnification", "geometry"}


def test_a_temperature_cycle_without_a_grating_is_named_while_the_stage_turns_round():
    """The stretch's harmonics of the print's phase, beside a drift in time and only where the stage
    saw enough phases: a 16-row cycle's stretch had been taken for a print's turning change at its
    peak (49-54 % of the frames 4+ bounds off, unflagged)."""
    model = rig_model("strip16", "", seed=3, seconds=6.0)
    run, truth = build_rig("strip16", "magnification_drift:ppm=1500:cycle_s=6", seed=3, run=1).record(6.0)
    result = track(model, run.frames, np.full(run.n_frames, np.nan), light="auto", robust=True)
    error_um = (result.x_mm - truth.x_mm) * 1e3
    error_um -= model.period_mm * 1e3 * np.round(np.nanmedian(error_um) / (model.period_mm * 1e3))
    placed = np.isfinite(error_um)
    far = placed & (np.abs(error_um) > 4.0 * result.crlb_mm * 1e3)
    peak = slice(run.n_frames // 4, 3 * run.n_frames // 4)  # the stretch beyond 750 ppm: ~13 µm of slide
    assert far[peak].all() and result.stale[peak].mean() > 0.95
