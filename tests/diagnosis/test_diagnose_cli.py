"""``graytrack diagnose`` writes the report contract, an HTML report with plots, and a model that tracks."""

from __future__ import annotations

import json

import numpy as np

from graytrack.service.cli import main
from tests.tables import read_columns


def test_diagnose_writes_contract_files(tmp_path, capsys):
    rec = tmp_path / "cal.npz"
    assert main(["simulate", "--scenario", "paper", "--effects", "gradient", "--seconds", "16", "--seed", "2",
                 "--out", str(rec)]) == 0
    assert main(["diagnose", str(rec), "--out", str(tmp_path / "diag")]) == 0
    out = capsys.readouterr().out
    assert "before" in out and "after" in out and "stroke" in out
    report = json.loads((tmp_path / "diag" / "report.json").read_text())
    assert set(report["noise"]) >= {"gray", "crlb_um"}
    for key in ("before", "after"):
        assert set(report[key]) >= {"model", "rmse_gray", "error_std_um", "error_max_um"}
    assert report["steps"] and set(report["steps"][0]) >= {"effect", "evidence", "rmse_gray", "error_std_um"}
    page = (tmp_path / "diag" / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 3 and "noise floor" not in page and "<b>Bound</b>" in page
    val = tmp_path / "val.npz"
    assert main(["simulate", "--scenario", "paper", "--effects", "gradient", "--seconds", "6", "--seed", "2",
                 "--out", str(val)]) == 0
    assert main(["track", str(val), "--model", str(tmp_path / "diag" / "model.json"), "--out",
                 str(tmp_path / "t.csv")]) == 0
    assert np.nanstd(read_columns(tmp_path / "t.csv")["error_um"]) < 1.3 * report["noise"]["crlb_um"] * 1.2


def test_calibrate_auto_saves_the_loops_model(tmp_path):
    rec = tmp_path / "cal.npz"
    assert main(["simulate", "--scenario", "paper", "--effects", "prnu:sigma=0.02", "--seconds", "12",
                 "--out", str(rec)]) == 0
    assert main(["calibrate", str(rec), "--model", "auto", "--out", str(tmp_path / "m.json")]) == 0
    model = json.loads((tmp_path / "m.json").read_text())["model"]
    assert model["pixel_gain"] is not None


def test_validation_of_another_roi_is_refused(tmp_path, capsys):
    single, strip = tmp_path / "one.npz", tmp_path / "strip.npz"
    assert main(["simulate", "--scenario", "paper", "--seconds", "4", "--out", str(single)]) == 0
    assert main(["simulate", "--scenario", "strip16", "--seconds", "4", "--out", str(strip)]) == 0
    assert main(["diagnose", str(strip), "--validate", str(single), "--out", str(tmp_path / "d")]) == 2
    assert "same camera ROI" in capsys.readouterr().err
    assert not (tmp_path / "d" / "report.json").exists()


def test_report_names_the_pixels_set_aside_and_the_noise_curve(tmp_path):
    rec = tmp_path / "cal.npz"
    assert main(["simulate", "--scenario", "paper", "--effects",
                 "bad_pixels:stuck=1:dead=0:hot=0:row=0:pixel=33,photon_transfer:full_well=10000:read_e=10:bits=8",
                 "--seconds", "12", "--out", str(rec)]) == 0
    assert main(["diagnose", str(rec), "--out", str(tmp_path / "diag")]) == 0
    page = (tmp_path / "diag" / "report.html").read_text()
    assert "row 0, pixel 33: stuck" in page
    assert "Noise grows with the signal" in page and "1/σ²(y)" in page
