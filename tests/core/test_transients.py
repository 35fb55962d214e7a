"""Transients (glints): the virtual rig's effect, calibration setting their samples aside, tracking
rejecting the blob, and the accuracy both give on a run the model was not told about.

Pattern: calibrate on one session with glints on 5 % of the frames, track a second session with
glints on 15 %; which frames carry a glint is known from the same session rendered without them.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.calibration_data import calibration_data
from graytrack.core.diagnosis import diagnose
from graytrack.core.tracking import track
from graytrack.core.transients import find_transients
from graytrack.drivers.sim.scenarios import build_rig

CALIBRATION_S, RUN_S = 20.0, 10.0


def _session(scenario: str, effects: str, run: int, seconds: float):
    """A recording with ``effects`` and which of its frames a glint touched (same session, no glints)."""
    rec, _ = build_rig(scenario, effects, seed=3, run=run).record(seconds)
    base = ",".join(part for part in effects.split(",") if not part.startswith("glints"))
    plain, _ = build_rig(scenario, base, seed=3, run=run).record(seconds)
    touched = np.abs(rec.strip().astype(float) - plain.strip().astype(float)) > 0.35  # half a noise σ
    return rec, touched


@functools.lru_cache(maxsize=2)
def _sessions(scenario: str):
    """Calibration with glints on 5 % of frames, a second session with glints on 15 %."""
    cal, cal_touched = _session(scenario, "glints:p=0.05", 0, CALIBRATION_S)
    run, run_touched = _session(scenario, "glints:p=0.15", 1, RUN_S)
    return scenario, cal, cal_touched, run, run_touched


@functools.lru_cache(maxsize=2)
def _paper_model(scenario: str):
    """The paper model of the scenario's glint calibration and its tracking of the glint run: made once a
    process for the three tests that ask different things of them (which read them, and change nothing)."""
    _, cal, _, run, _ = _sessions(scenario)
    model = calibrate(cal, "paper").model
    return model, track(model, run, light="auto", robust=True)


@pytest.fixture(scope="module", params=["paper", "strip16"])
def sessions(request):
    return _sessions(request.param)


def test_calibration_sets_aside_the_glint_samples_not_the_pixels(sessions):
    scenario, cal, touched, _, _ = sessions
    data = calibration_data(cal)
    set_aside = data.transients
    assert set_aside is not None
    frames_found = set_aside.any(axis=(1, 2))
    assert np.array_equal(frames_found, touched.any(axis=(1, 2)))  # every glinted frame, no other
    assert (set_aside & ~touched).sum() <= 0.02 * set_aside.sum()  # hardly a sample a glint did not touch
    share = set_aside.sum() / touched.sum()
    assert share > 0.9  # the tails below half a noise σ may stay
    assert (data.weights[set_aside] == 0).all()
    # the noise is measured without them (σ = 0.7 gray on this rig)
    assert data.sigma_gray == pytest.approx(0.7, rel=0.04)
    summary = data.meta["transients"]
    assert summary["frames"] == int(frames_found.sum()) and summary["count"] >= 10


def test_clean_recordings_have_no_transients():
    rec, _ = build_rig("strip16", "prnu:sigma=0.01,telegraph_pixels:count=6,dust:count=6", seed=3).record(10.0)
    data = calibration_data(rec)
    assert data.transients is None and "transients" not in data.meta


@pytest.mark.parametrize("method", ["paper", "loop"])
def test_glints_calibrated_and_tracked_at_the_bound(sessions, method):
    """Acceptance (issue 15, item 1): clean frames ≤ 1.1×, glint frames ≤ 1.5× their bounds, and
    no good pixel masked, with the paper model and with the closed loop."""
    scenario, cal, _, run, run_touched = sessions
    if method == "paper":
        model, tracked = _paper_model(scenario)
    else:
        result = diagnose(cal)
        model = result.final_model
        findings = result.report()["findings"]
        assert findings["transients"]["count"] >= 10
        assert "bad_pixels" not in findings
        tracked = track(model, run, light="auto", robust=True)
    assert not model.info.get("bad_pixels")
    assert model.pixel_weight is None or model.pixel_weight.min() > 0
    assert model.info["transients"]["count"] >= 10
    error = tracked.error_um(run.reference)
    glinted = run_touched.any(axis=(1, 2))
    assert np.isfinite(error).all() and tracked.locked.all()
    for frames, limit in ((~glinted, 1.1), (glinted, 1.5)):
        bound = np.sqrt(np.mean((tracked.crlb_mm[frames] * 1e3) ** 2))
        assert np.std(error[frames]) <= limit * bound, (frames.sum(), np.std(error[frames]), bound)
    assert (tracked.transient_px[glinted] > 0).mean() > 0.9
    assert (tracked.transient_px[~glinted] == 0).all()
    assert tracked.stale.mean() < 0.01  # measured at the bound: not stale, for no family


def test_a_frame_a_transient_covers_too_much_of_is_unlocked_with_the_reason():
    cal, _ = build_rig("paper", "", seed=3).record(CALIBRATION_S)
    run, _ = build_rig("paper", "", seed=3, run=1).record(2.0)
    model = calibrate(cal, "paper").model
    frames = run.frames.astype(np.float64).copy()
    u = np.arange(frames.shape[-1])
    frames[50] += 150.0 * np.exp(-0.5 * ((u - 50) / 8.0) ** 2)  # a glint 40 px wide on a 100 px line
    tracked = track(model, frames, reference=run.reference, light="auto", robust=True)
    assert not tracked.locked[50] and tracked.locked[52:].all()
    reasons = [event.reason for event in tracked.events if event.frame == 50]
    assert reasons and "transient" in reasons[0]
    assert tracked.transient_px[50] > 25


def test_find_transients_names_frames_and_place():
    rec, touched = _session("paper", "glints:p=0.05", 0, CALIBRATION_S)
    found = find_transients(rec.strip().astype(float), rec.reference, 0.7, rec.meta["period_mm"],
                            rec.meta["pixel_pitch_mm"])
    first = found.events[0]
    k = first.frames[0]
    assert touched[k].any() and not touched[k - 1].any()
    peak_pixel = int(np.argmax(rec.strip()[k, 0] - np.median(rec.strip()[max(k - 20, 0):k, 0], axis=0)))
    assert abs(first.pixel - peak_pixel) <= 2
    assert "transients:" in found.line() and str(len(found.events)) in found.line()


def test_transient_watch_blames_transients_only_when_they_stop_being_rare():
    from graytrack.core.validity import FrameSign, Monitor
    from graytrack.core.watches.transients import TransientWatch

    monitor = Monitor([TransientWatch()])
    rng = np.random.default_rng(1)

    def glint(k: int, present: bool, at: float | None = None) -> FrameSign:
        place = float(rng.uniform(0, 100)) if at is None else at
        return FrameSign(k, transient_px=11 if present else 0, transient_at=place if present else float("nan"))

    rare = [monitor.observe(glint(k, rng.random() < 0.15)).stale for k in range(400)]
    assert not any(rare)  # 15 % of frames with a glint: set aside, not stale
    lasting = [monitor.observe(glint(400 + k, True)) for k in range(200)]
    assert lasting[-1].stale and lasting[-1].reason == "transients"
    assert sum(v.stale for v in lasting) > 130  # within about 60 frames
    cleared = [monitor.observe(glint(600 + k, False)).stale for k in range(200)]
    assert not cleared[-1]
    # a blob that keeps to the same pixels is no transient: stray light fixed to the camera (glare)
    fixed = Monitor([TransientWatch()])
    stays = [fixed.observe(glint(k, True, at=70.0 + rng.normal(0, 1))) for k in range(400)]
    assert stays[-1].stale and {v.reason for v in stays if v.stale} == {"light"}


def test_calibrate_and_diagnose_name_the_transients(tmp_path, capsys):
    from graytrack.core.recording import save
    from graytrack.service.cli import main

    rec, touched = _session("paper", "glints:p=0.05", 0, CALIBRATION_S)
    save(rec, tmp_path / "cal.npz")
    assert main(["calibrate", str(tmp_path / "cal.npz"), "--model", "paper", "--out", str(tmp_path / "m.json")]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "transients:" in line]
    events = calibration_data(rec).meta["transients"]
    assert len(lines) == 1 and f"{events['count']} (glints" in lines[0]
    assert f"in {events['frames']} frame(s)" in lines[0]
    assert main(["diagnose", str(tmp_path / "cal.npz"), "--out", str(tmp_path / "d")]) == 0
    assert "transients:" in capsys.readouterr().out
    import json

    report = json.loads((tmp_path / "d" / "report.json").read_text())
    found = report["findings"]["transients"]
    assert found["count"] == events["count"] and found["frames"] == int(touched.any(axis=(1, 2)).sum())
    first = found["events"][0]
    assert touched[first["frames"][0]].any() and 0 <= first["pixel"] < 100
    html = (tmp_path / "d" / "report.html").read_text()
    assert f"Transients: {found['count']} (glints" in html and f"pixel {first['pixel']}" in html


def test_on_a_strip_a_glint_costs_its_rows_not_whole_columns():
    """A row-averaged model on 16 rows: the glint's samples are set aside in the rows it covers, so
    a glint frame keeps nearly the bound and the position the same frame has without the glint."""
    scenario, _, _, _, run_touched = _sessions("strip16")
    model, with_glints = _paper_model(scenario)
    assert model.n_rows == 1  # the rows agree: the model sees their mean
    plain, _ = build_rig(scenario, "", seed=3, run=1).record(RUN_S)
    glinted = run_touched.any(axis=(1, 2))
    without = track(model, plain, light="auto", robust=True)
    ratio = with_glints.crlb_mm[glinted] / without.crlb_mm[glinted]
    assert np.median(ratio) < 1.04 and ratio.max() < 1.15
    moved = (with_glints.x_mm - without.x_mm)[glinted] * 1e3
    assert np.std(moved) < 0.35 * np.sqrt(np.mean((without.crlb_mm[glinted] * 1e3) ** 2))
    # counted in raw samples: a few rows of a few pixels, more than a column's worth
    assert np.median(with_glints.transient_px[glinted]) > 16


def test_live_tracking_sets_glints_aside_as_batch_tracking_does(sessions):
    from graytrack.core.tracking import LiveTracker

    scenario, _, _, run, run_touched = sessions
    model, batch = _paper_model(scenario)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fixes = [live.update(frame, float(ref)) for frame, ref in zip(run.frames, run.reference)]
    np.testing.assert_allclose([fix.x_mm for fix in fixes], batch.x_mm, atol=1e-9)
    assert [fix.transient_px for fix in fixes] == batch.transient_px.tolist()
    assert sum(fix.transient_px > 0 for fix in fixes) >= 0.9 * run_touched.any(axis=(1, 2)).sum()


def test_the_compiled_blob_search_finds_what_scipy_s_labelling_finds() -> None:
    """The flood fill every robust frame runs and scipy's labelling (the reference) agree sample
    for sample: blobs of every size and width, near edges, several per frame, on 1 to 16 rows."""
    from graytrack.core import transients

    rng = np.random.default_rng(2)
    for _ in range(200):
        shape = (int(rng.integers(1, 4)), int(rng.integers(1, 17)), int(rng.integers(5, 130)))
        z = np.abs(rng.normal(size=shape)) * rng.uniform(0.5, 2.5)
        for _ in range(int(rng.integers(0, 4))):
            k, r, c = (int(rng.integers(size)) for size in shape)
            z[k, max(r - 1, 0):r + 2, max(c - 2, 0):c + int(rng.integers(1, 40))] += rng.uniform(2, 15)
        for share in (0.25, 0.5):
            compiled = transients.compact_blobs(z, max_width_share=share)
            reference = transients._scipy_blobs(z, transients.CORE_Z, transients.GROW_Z, share)
            assert np.array_equal(compiled, reference)
