"""Bad pixels in recordings that declare nothing: found, named by index, masked.

Three pixels (stuck at full scale, dead at 0, hot by +40 gray) in a 100-pixel line and in a
16-row strip. ``diagnose`` must name exactly those, and after the loop the held-out error must be
within 1.1× the bound of the remaining pixels; ``calibrate --model paper`` masks them too (a
data-quality step), so tracking another run with that model places every frame.
"""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis import diagnose
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

BAD = "bad_pixels:stuck=1:dead=1:hot=1:hot_gray=40"
ROWS = {1: "", 16: "rows:n=16,"}


def _truth(rig) -> dict[tuple[int, int], str]:
    names = {("stuck", 0.0): "dead", ("stuck", 255.0): "stuck", ("hot", 40.0): "hot"}
    return {(b.row, b.pixel): names[(b.kind, b.value)] for b in rig.config.sensor.bad_pixels}


@pytest.mark.parametrize("rows", list(ROWS))
def test_diagnose_names_the_bad_pixels_and_reaches_the_bound_of_the_rest(rows):
    rig = build_rig("paper", ROWS[rows] + BAD, seed=3)
    recording, _ = rig.record(12.0)
    report = diagnose(recording).report()
    listed = {(p["row"], p["pixel"]): p["reason"] for p in report["findings"]["bad_pixels"]}
    truth = _truth(rig)
    assert set(listed) == set(truth)
    for place, kind in truth.items():
        assert listed[place].startswith(kind)
    assert report["steps"][0]["effect"] == "bad_pixels"
    assert report["before"]["error_std_um"] > 1.3 * report["noise"]["crlb_um"]
    assert report["after"]["lost_frames"] == 0
    assert report["after"]["error_std_um"] <= 1.1 * report["noise"]["crlb_um"]


@pytest.mark.parametrize("rows", list(ROWS))
def test_paper_model_masks_them_and_tracks_another_run(rows):
    rig = build_rig("paper", ROWS[rows] + BAD, seed=3)
    calibration, _ = rig.record(12.0)
    run, _ = rig.record(6.0)  # the same camera later: new noise, the same bad pixels
    model = calibrate(calibration, "paper").model
    masked = {(p["row"], p["pixel"]) for p in model.info["bad_pixels"]}
    assert masked == set(_truth(rig))
    tracked = track(model, run)
    error = tracked.error_um(run.reference)
    assert np.isfinite(error).mean() >= 0.99
    assert np.nanstd(error) <= 1.5 * np.nanmedian(tracked.crlb_mm) * 1e3


@pytest.mark.parametrize("effects", ["", "rows:n=16"])
def test_clean_data_masks_nothing(effects):
    recording, _ = build_rig("paper", effects, seed=6).record(8.0)
    model = calibrate(recording, "paper").model
    assert model.pixel_weight is None and "bad_pixels" not in model.info


def test_noisy_pixels_are_masked_by_the_noise_curve():
    rig = build_rig("paper", "rows:n=16,bad_pixels:stuck=0:dead=0:hot=0:noisy=2:noisy_gray=3", seed=2)
    recording, _ = rig.record(8.0)
    model = calibrate(recording, "paper").model
    listed = {(p["row"], p["pixel"]): p["reason"] for p in model.info["bad_pixels"]}
    assert set(listed) == set(_truth_places(rig)) and all(r.startswith("noisy") for r in listed.values())


def test_a_pixel_that_does_not_follow_the_target_is_found_from_the_residual():
    """Its own gain and offset cannot explain it (that would be the flat field's): a slow wander."""
    from graytrack.core.effects.bad_pixels import residual_bad_pixels

    rng = np.random.default_rng(1)
    predicted = 128 + 80 * np.sin(np.linspace(0, 40, 600))[:, None, None] * np.ones((1, 2, 50))
    residual = 0.7 * rng.standard_normal(predicted.shape)
    residual[:, 0, 7] += 0.05 * (predicted[:, 0, 7] - 128)  # a weak pixel: the flat field's
    residual[:, 1, 30] += np.cumsum(rng.standard_normal(600)) * 0.5  # wanders on its own
    found = residual_bad_pixels(residual, predicted, np.ones(predicted.shape), 0.7)
    assert [(r, u) for r, u, _ in found] == [(1, 30)] and "does not follow" in found[0][2]


def _truth_places(rig) -> set[tuple[int, int]]:
    return {(b.row, b.pixel) for b in rig.config.sensor.bad_pixels}


def test_dust_across_a_strip_is_no_pixel_defect():
    """Dust on the print, seen through a 16-row strip, leaves a residual in pixels of every column.
    Those pixels follow the target's dust, not a defect of their own: masking them (a shared model
    loses a bad pixel's whole column) left a model with no pixel at all and a calibration χ² of 0,
    whose tracker called every frame fresh. The probe names only what the pixels' own time series
    show, and never a mask of more than a share of the line."""
    from graytrack.core.calibration import KIND_SPECS
    from graytrack.core.diagnosis.heldout import loop_split
    from graytrack.core.diagnosis.loop import _stage
    from graytrack.core.effects.bad_pixels import EFFECT, MAX_MASKED_SHARE, masked_share, residual_bad_pixels
    from graytrack.core.geometry import initial_geometry

    recording, _ = build_rig("strip16", "dust", seed=3).record(8.0)
    _, train, val, _ = loop_split(recording, None)
    seed = _stage(KIND_SPECS["paper"], train, val, initial_geometry(train), refine_geometry=True)
    residual = train.frames - np.broadcast_to(seed.train.predicted, train.frames.shape)
    following = residual_bad_pixels(residual, seed.train.predicted, seed.train.usable, train.sigma_gray)
    assert masked_share(following, train.frames.shape[1:], False) > MAX_MASKED_SHARE  # the premise: dust everywhere
    evidence = EFFECT.probe(seed)
    if evidence is not None:
        assert masked_share(evidence.argument, train.frames.shape[1:], seed.spec.per_row) <= MAX_MASKED_SHARE
        grown = EFFECT.grow(seed.spec, evidence.argument)
        trial = _stage(grown, train, val, initial_geometry(train))
        assert trial.model.info["calibration_chi2"] > 0


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_a_roi_partly_off_the_print_is_masked_by_the_loop_as_by_calibrate(scenario):
    """The last 30 % of the line's columns look past the print's edge at a plain surface: stuck, each
    on its own time series. `calibrate` masked them (its screen has no share limit) and placed the
    run at its bound; the loop's probe refused a mask of more than a fifth of the line, grew three
    pixel polynomials and a flat field around the step instead, and its model (20× its bound on its
    own frames, every frame flagged) placed the strip's run 9.5× its bound with 153 frames lost.
    Findings of the pixels' own time series are masked however many, while the model keeps the
    share of the line a model needs (core/geometry_check.py)."""
    spec = "off_target:share=0.3"
    recording, _ = build_rig(scenario, spec, seed=3).record(12.0)
    result = diagnose(recording)
    report = result.report()
    assert report["steps"][0]["effect"] == "bad_pixels"
    masked_columns = {p["pixel"] for p in report["findings"]["bad_pixels"]}
    assert masked_columns == set(range(70, 100))
    assert report["after"]["lost_frames"] == 0
    assert report["after"]["error_std_um"] <= 1.3 * report["noise"]["crlb_um"]
    assert result.final_model.info["calibration_error_ratio"] < 1.5
    run, _ = build_rig(scenario, spec, seed=3, run=1).record(4.0)
    loop_run = track(result.final_model, run, light="auto", robust=True)
    plain_run = track(calibrate(recording, "paper").model, run, light="auto", robust=True)
    loop_error, plain_error = (np.nanstd(tracked.error_um(run.reference)) for tracked in (loop_run, plain_run))
    assert np.isfinite(loop_run.x_mm).all() and not loop_run.stale.any()
    assert loop_error <= 1.1 * plain_error
