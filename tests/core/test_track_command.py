"""`graytrack track` after the light changed and a pixel went bad: the new CSV columns, the
light re-solved by default, and the stale-model line on stderr."""

from __future__ import annotations

import re

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.models import save_model
from graytrack.core.recording import Recording, save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.cli import main
from tests.core.test_tracking_light_weights import run_of
from tests.tables import read_columns


def test_track_command_follows_changed_light_and_reports_validity(tmp_path, capsys):
    rig = build_rig("paper", seed=7)
    cal, _ = rig.record(seconds=12.0)
    save_model(calibrate(cal, "paper").model, tmp_path / "m.json")
    frames, x_true = run_of(rig, 200, light_gain=0.85, light_offset=8.0)
    frames = frames.copy()
    frames[50:, 12] = 255.0
    save(Recording(frames, np.arange(200) / 50.0, x_true, rig.meta()), tmp_path / "run.npz")
    args = ["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "m.json"), "--out", str(tmp_path / "t.csv")]
    assert main(args) == 0
    out = capsys.readouterr()
    assert "chi2 per pixel" in out.out and "stale" not in out.err
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["t", "x_mm"] and {"chi2", "rejected_px", "gain", "offset_gray", "stale"} <= set(header)
    column = read_columns(tmp_path / "t.csv")
    assert column["locked"].all() and np.abs(column["error_um"]).max() < 10.0
    assert (column["rejected_px"][50:] == 1).all() and (column["rejected_px"][:50] == 0).all()
    np.testing.assert_allclose(column["gain"], 0.85, atol=0.02)

    assert main(args + ["--light", "fixed", "--no-robust"]) == 0
    assert not read_columns(tmp_path / "t.csv")["locked"].all()  # the old behaviour: blind under the new light
    capsys.readouterr()

    changed = build_rig("paper", "harmonics:h2=0.02", seed=7)
    frames, x_true = run_of(changed, 300)
    save(Recording(frames, np.arange(300) / 50.0, x_true, rig.meta()), tmp_path / "run.npz")
    assert main(args) == 0
    err = capsys.readouterr().err
    # a print the model does not know, named geometry first: the stretch a grown harmonic reads as while the stage
    # sees less than a period (17000-25000 ppm) is no lens's (core/watches/magnification.py LENS_PPM)
    assert "model stale on" in err and "recalibrate" in err and "on, for geometry (" in err
    named = re.search(r"magnification \((\d+) frames\)", err)
    assert named is None or int(named.group(1)) <= 10  # 162 of 300 frames had been named magnification


def test_single_frames_off_the_grating_are_named_not_blamed_on_the_model(tmp_path, capsys):
    """Two grating readings gone wrong in a clean run: those two frames are flagged, and the line
    on stderr names them as single frames instead of advising a recalibration."""
    rig = build_rig("paper", seed=7)
    cal, _ = rig.record(seconds=12.0)
    save_model(calibrate(cal, "paper").model, tmp_path / "m.json")
    run, _ = build_rig("paper", seed=7, run=1).record(6.0)
    reference = run.reference.copy()
    reference[[120, 200]] += 0.5
    save(Recording(run.frames, run.t, reference, run.meta), tmp_path / "run.npz")
    assert main(["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "m.json"),
                 "--out", str(tmp_path / "t.csv")]) == 0
    err = capsys.readouterr().err
    assert "2 single frame(s) flagged" in err and "frame 120, 200" in err and "recalibrate" not in err
    assert np.flatnonzero(read_columns(tmp_path / "t.csv")["stale"]).tolist() == [120, 200]
