"""Without a grating, a lens's magnification drift is never silently wrong: each placed frame's bound
carries the slide the stretch the frames allow now could give the image (core/slide.py), until the
magnification watch flags it; with a grating, or an axis declared on the ROI, nothing is added.
Scored against the truth (the virtual rig's ``magnification_drift``, the optical axis 300 px off)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from graytrack.core.models import save_model
from graytrack.core.recording import save
from graytrack.core.slide import SlideWatch, carry
from graytrack.core.tracking import track
from graytrack.core.watches.magnification import MagnificationWatch
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model
from graytrack.service.cli import main
from tests.tables import read_columns

RAMP = "magnification_drift:ppm=1500:ramp_s=10"  # a warm-up: 28 µm of slide by the end
CYCLE = "magnification_drift:ppm=1500:cycle_s=6"  # a temperature cycle that comes and goes


@pytest.fixture(scope="module")
def models():
    return {scenario: rig_model(scenario, "", seed=3, seconds=20.0) for scenario in ("paper", "strip16")}


def _unread(model, run, truth, slide: SlideWatch | None):
    """Tracked as ``graytrack track --no-reference`` does: (error µm, bound µm, flagged, the slide's column)."""
    result = track(model, run.frames, np.full(run.n_frames, np.nan), light="auto", robust=True,
                   watches=[slide] if slide is not None else [])
    column = carry(result, slide)["slide_sigma_um"]
    error = (result.x_mm - truth.x_mm) * 1e3
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.nanmedian(error) / period_um)  # the image alone: origin up to whole periods
    return error, result.crlb_mm * 1e3, result.stale, column


def _silent(error, bound, flagged) -> float:
    placed = np.isfinite(error)
    return float((placed & (np.abs(error) > 4.0 * bound) & ~flagged).sum() / placed.sum())


@pytest.mark.parametrize("scenario,drift", [("strip16", RAMP), ("strip16", CYCLE), ("paper", RAMP)])
def test_a_drifting_lens_without_a_grating_is_never_silently_off(models, scenario, drift):
    model = models[scenario]
    run, truth = build_rig(scenario, drift, seed=3, run=1).record(10.0)
    error, bound, flagged, slide_um = _unread(model, run, truth, SlideWatch.for_model(model))
    assert _silent(error, bound, flagged) <= 0.005
    assert np.all(slide_um > 0) and np.all(bound >= slide_um)
    # the bound alone, as before: the first frames of a drift 4+ bounds off before the watch's mean can tell
    plain = _unread(model, run, truth, None)
    assert _silent(*plain[:3]) > 0.04


def test_a_steady_run_is_not_flagged_and_an_axis_on_the_roi_adds_nothing(models):
    model = models["strip16"]
    run, truth = build_rig("strip16", "", seed=3, run=1).record(10.0)
    error, bound, flagged, slide_um = _unread(model, run, truth, SlideWatch.for_model(model))
    floor_error, floor, floor_flagged, _ = _unread(model, run, truth, SlideWatch.for_model(model, axis_px=0.0))
    assert flagged.mean() < 0.01 and floor_flagged.mean() < 0.01
    assert np.all(floor <= bound)
    np.testing.assert_allclose(np.sqrt(bound ** 2 - slide_um ** 2), floor, rtol=1e-9)
    # what 300 px of lever and the stretch the frames cannot rule out (~60 ppm) make of a steady run
    late = slice(100, None)
    assert 0.5 < np.median(slide_um[late]) < 2.5
    assert np.nanstd(floor_error) < 1.3 * np.sqrt(np.nanmean(floor ** 2))


def test_a_frame_shown_to_no_watch_keeps_the_slide_before_it():
    watch = SlideWatch(MagnificationWatch(8.6), lever_mm=10.0)
    for frame, m in ((1, 0.0), (2, 2000e-6), (4, 6000e-6)):  # frames 0 and 3 repeated images: no watch saw them
        watch.step(frame, True, 1.0, lambda m=m: (m, 400e-6), float("nan"))
    watch.step(5, True, 1.0, lambda: (0.0, 400e-6), 1.0)  # a grating reading vouches for frame 5
    result = SimpleNamespace(x_mm=np.zeros(6), crlb_mm=np.full(6, 1e-3))
    column = carry(result, watch)["slide_sigma_um"]
    assert 0 < column[0] == column[1] < column[2] == column[3] < column[4] and column[5] == 0
    np.testing.assert_allclose(result.crlb_mm * 1e3, np.hypot(1.0, column))


def test_track_writes_the_slide_it_carries(models, tmp_path, capsys):
    save_model(models["strip16"], tmp_path / "m.json")
    save(build_rig("strip16", RAMP, seed=3, run=1).record(4.0)[0], tmp_path / "run.npz")
    common = ["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "m.json")]
    assert main([*common, "--out", str(tmp_path / "n.csv"), "--no-reference"]) == 0
    assert "slide   no grating read" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "a.csv"), "--no-reference", "--axis-px", "0"]) == 0
    assert main([*common, "--out", str(tmp_path / "g.csv")]) == 0
    unread, on_axis, read = (read_columns(tmp_path / f"{name}.csv") for name in "nag")
    assert np.all(unread["slide_sigma_um"] > 0) and np.all(on_axis["slide_sigma_um"] == 0)
    np.testing.assert_allclose(unread["crlb_um"], np.hypot(on_axis["crlb_um"], unread["slide_sigma_um"]), rtol=1e-6)
    assert np.all(np.isnan(read["slide_sigma_um"]))  # the grating vouches: nothing carried



def test_the_estimator_writes_the_slide_its_bound_states_without_a_grating(models, tmp_path, capsys):
    """``track --engine estimator`` without the grating: each bound states the lens's slide (core/estimator/,
    ``slide_mm``), written as the same column and said in the same line; on the lens's axis, none."""
    save_model(models["strip16"], tmp_path / "m.json")
    save(build_rig("strip16", RAMP, seed=3, run=1).record(4.0)[0], tmp_path / "run.npz")
    common = ["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "m.json"), "--engine", "estimator"]
    assert main([*common, "--out", str(tmp_path / "n.csv"), "--no-reference"]) == 0
    assert "slide   no grating read" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "a.csv"), "--no-reference", "--axis-px", "0"]) == 0
    assert "(declared): median 0.00 um" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "g.csv")]) == 0
    assert "slide   no grating read" not in capsys.readouterr().out
    unread, on_axis = (read_columns(tmp_path / f"{name}.csv") for name in "na")
    assert np.all(unread["slide_sigma_um"] > 0) and np.all(unread["crlb_um"] >= unread["slide_sigma_um"])
    assert np.all(on_axis["slide_sigma_um"] == 0)
    assert "slide_sigma_um" not in read_columns(tmp_path / "g.csv")  # the grating checks the slide

def test_chunks_without_a_grating_carry_the_slide_too(models):
    """``track --chunk-frames`` without a grating: each chunk's tracker carries a slide watch of its own
    (core/chunked.py); before, its bounds carried nothing (and the column was NaN)."""
    from graytrack.core.chunked import track_chunked

    model = models["strip16"]
    run, truth = build_rig("strip16", RAMP, seed=3, run=1).record(10.0)
    unread = np.full(run.n_frames, np.nan)
    period_um = model.period_mm * 1e3

    def silent(result) -> float:
        error = (result.x_mm - truth.x_mm) * 1e3
        error -= period_um * np.round(np.nanmedian(error) / period_um)  # origin up to whole periods
        return _silent(error, result.crlb_mm * 1e3, result.stale)

    carried, report = track_chunked(model, run.frames, unread, 120, light="auto", robust=True, slide=True)
    plain, _ = track_chunked(model, run.frames, unread, 120, light="auto", robust=True)
    assert report.chunks == 4 and plain.slide_sigma_um is None
    placed = np.isfinite(carried.x_mm)
    slide_um = carried.slide_sigma_um[placed]
    assert np.all(slide_um > 0) and np.all(carried.crlb_mm[placed] * 1e3 >= slide_um)
    assert silent(carried) <= 0.005 < 0.04 < silent(plain)


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_a_steady_lens_is_held_to_the_bound_less_the_slide(models, scenario):
    """Without the grating the estimator's bound states the slide of a lens the frames cannot yet tell from one
    drifting at its fastest declared rate; a steady lens has none, so its errors are held to the bound less the
    slide (docs/method.md), which must then be honest, and the whole bound is the wider by what it states."""
    from graytrack.core.estimator.filter import track as estimate

    model = models[scenario]
    run, truth = build_rig(scenario, "", seed=3, run=1).record(10.0)
    estimates = estimate(model, run.frames, run.t, np.full(run.n_frames, np.nan), grating="none")
    error = np.array([e.x_mm for e in estimates]) - truth.x_mm
    error = 1e3 * (error - model.period_mm * np.round(np.nanmedian(error) / model.period_mm))
    bound, slide = (np.array([getattr(e, name) for e in estimates]) * 1e3 for name in ("crlb_mm", "slide_mm"))
    placed = np.isfinite(error)
    assert placed.mean() > 0.99 and np.all(slide[placed] > 0)
    tested = np.sqrt(np.mean(error[placed] ** 2 / (bound[placed] ** 2 - slide[placed] ** 2)))
    whole = np.sqrt(np.mean((error[placed] / bound[placed]) ** 2))
    assert 0.8 <= tested <= 1.25
    assert whole < 0.8 * tested  # (the slide no frame of a steady lens shows)
