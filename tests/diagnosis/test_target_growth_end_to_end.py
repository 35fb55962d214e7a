"""A print that grows after calibration, seen against the grating: flagged fast, trimmed to the bound.

Calibrated on one run of the virtual rig, the measured run is another session in which the paper
target has grown 250 ppm (humidity) about its centre; the grating (the stage's own scale) has not.
The image alone cannot tell (χ² stays at 1); the camera against the grating can. Runs without a
growth, also with the grating's rounding and interpolation error and a vibration the camera and the
grating see differently, must stay unflagged. Error: rms against the true stage position, over the
rms of the frames' Cramér–Rao bounds.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from graytrack.core.recording import save
from graytrack.core.reference_monitor import ReferenceMonitor, follow
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model
from graytrack.service.cli import main

GROWTH = "target_growth:ppm=250"


def _model(scenario: str):
    return rig_model(scenario, "", seed=3, seconds=20.0)


@lru_cache(maxsize=None)
def _tracked(scenario: str, effects: str, seconds: float):
    """A run tracked by the seed model: (grating readings, true positions, tracking result), once a process
    (seeded: the same numbers each time; the tests read them and change nothing): the trim's test follows
    the grown runs the flagging test tracked, with and without the trim, rather than tracking them again."""
    run, truth = build_rig(scenario, effects, seed=3, run=1).record(seconds)
    result = track(_model(scenario), run, light="auto", robust=True)
    return run.reference, truth.x_mm, float(run.meta.get("grating_resolution_mm", 0.0)), result


def _followed(scenario: str, effects: str, seconds: float = 10.0, trim: bool = False):
    model = _model(scenario)
    reference, truth_mm, step, result = _tracked(scenario, effects, seconds)
    followed = follow(ReferenceMonitor.for_model(model, step), result.x_mm, reference, result.crlb_mm,
                      result.locked, trim=trim)
    error = (followed.x_mm - truth_mm) * 1e3
    bound = np.sqrt(np.nanmean(np.square(result.crlb_mm))) * 1e3
    return followed, error, bound, result


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_a_grown_target_is_flagged_within_500_frames_and_most_of_the_run(scenario):
    followed, error, bound, result = _followed(scenario, GROWTH)
    assert np.nanmedian(result.chi2) < 1.1  # the images alone do not tell
    first = int(np.argmax(followed.stale))
    assert followed.stale.any() and first < 500
    assert followed.stale.mean() >= 0.9
    line = followed.final
    assert abs(line.scale_ppm + 250.0) < 50.0 + 4 * line.scale_sigma_ppm  # the growth, seen as a scale
    # the tracker's validity monitor names it too (core/watches/scale.py), from the same frame on; the
    # image's stretch that comes with it is the line's scale, not a lens's magnification (the scale
    # watch's _grown: on a 16-row strip 391 of 500 frames had been named magnification)
    assert (result.stale_reason == "scale").mean() >= 0.9 and result.stale_reason[first] == "scale"
    assert not (result.stale_reason == "magnification").any()


def test_a_growth_during_the_run_is_flagged_within_500_frames_of_its_onset():
    onset_s = 10.0
    followed, error, bound, _ = _followed("strip16", f"{GROWTH}:start_s={onset_s}", seconds=30.0)
    onset = int(onset_s * 50)
    assert not followed.stale[:onset].any()
    assert followed.stale[onset:onset + 500].any()


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
def test_the_trim_brings_a_grown_target_back_to_its_bound(scenario):
    _, plain, bound, _ = _followed(scenario, GROWTH)
    followed, error, _, _ = _followed(scenario, GROWTH, trim=True)
    trimmed = followed.trim_um != 0
    assert trimmed.mean() > 0.85  # in force from the first evidence on
    assert np.sqrt(np.nanmean(error[trimmed] ** 2)) <= 1.2 * bound
    assert np.sqrt(np.nanmean(error ** 2)) < np.sqrt(np.nanmean(plain ** 2))
    # against the trim in force the line holds; before it, the first frames are 4+ bounds off and flagged
    # (the strip's frames 1-5 of 500: the trim's follower watches the calibration's line until a trim)
    assert followed.stale.mean() <= 0.01


@pytest.mark.parametrize("scenario,effects", [
    ("paper", ""), ("paper", "vibration:um=2"), ("paper", "grating_resolution,cyclic_error"),
    ("strip16", ""), ("strip16", "vibration:um=2,grating_resolution,cyclic_error"),
])
def test_a_steady_target_is_not_flagged_nor_trimmed(scenario, effects):
    followed, error, bound, result = _followed(scenario, effects, trim=True)
    assert followed.stale.mean() < 0.01 and not (result.stale_reason == "scale").any()
    assert not followed.events and np.all(followed.trim_um == 0)


def test_track_warns_on_stderr_and_writes_the_columns_at_the_end(tmp_path, capsys):
    cal, run = tmp_path / "cal.npz", tmp_path / "run.npz"
    save(build_rig("strip16", seed=3).record(20.0)[0], cal)
    save(build_rig("strip16", GROWTH, seed=3, run=1).record(10.0)[0], run)
    assert main(["calibrate", str(cal), "--model", "paper", "--out", str(tmp_path / "m.json")]) == 0
    capsys.readouterr()
    assert main(["track", str(run), "--model", str(tmp_path / "m.json"), "--out", str(tmp_path / "t.csv")]) == 0
    err = capsys.readouterr().err
    assert "warning: scale:" in err and "camera against grating drifted" in err
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["t", "x_mm"] and header[-3:] == ["scale_stale", "trim_um", "trim_sigma_um"]
    assert main(["track", str(run), "--model", str(tmp_path / "m.json"), "--out", str(tmp_path / "t2.csv"),
                 "--trim"]) == 0
    out = capsys.readouterr().out
    assert "trim applied" in out
    rows = np.genfromtxt(tmp_path / "t2.csv", delimiter=",", names=True)
    plain = np.genfromtxt(tmp_path / "t.csv", delimiter=",", names=True)
    assert np.nanstd(rows["error_um"]) < 0.8 * np.nanstd(plain["error_um"])
