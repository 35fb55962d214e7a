"""``graytrack history``: each rig's calibrations against time; changes beyond the uncertainty pointed out."""

from __future__ import annotations

import re
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from graytrack.service.batch.history import QUANTITIES, RigCalibration, changes
from graytrack.service.cli import main

START = datetime(2026, 1, 1, tzinfo=timezone.utc)


def series(tau_mm: list[float], tau_u_mm: float = 1e-4, rig: str = "rig") -> list[RigCalibration]:
    """A rig whose other quantities stay put; only τ_w follows ``tau_mm``."""
    return [RigCalibration(rig, START + timedelta(days=day), f"{rig}/{day}.npz",
                        {"tau_w_mm": tau, "alpha_d_mm": 0.062, "noise_gray": 0.7, "error_std_after_um": 1.5},
                        {"tau_w_mm": tau_u_mm, "alpha_d_mm": 1e-5, "noise_gray": 0.005, "error_std_after_um": 0.1},
                        ()) for day, tau in enumerate(tau_mm)]


def test_scatter_within_the_uncertainty_is_not_a_change():
    rng = np.random.default_rng(3)
    assert changes(series(list(8.62 + 1e-4 * rng.standard_normal(30)))) == []


def test_a_step_is_pointed_out_against_the_previous_calibration():
    found = changes(series([8.62, 8.62, 8.6206, 8.6206]))
    assert [(c.quantity.key, c.since.when.day, c.at.when.day, c.against) for c in found] == [
        ("tau_w_mm", 2, 3, "previous")]
    assert found[0].z == pytest.approx(6e-4 / np.hypot(1e-4, 1e-4))
    assert "+0.6 µm" in found[0].text()


def test_slow_drift_is_pointed_out_against_the_level_before_it():
    found = changes(series([8.62 + 1e-4 * day for day in range(14)]))  # 0.7 σ per step, never between neighbours
    # 6e-4 / 1.41e-4 = 4.2 > 4 after six days, then again six days after that new level
    assert [(c.against, c.since.when.day, c.at.when.day) for c in found] == [("baseline", 1, 7), ("baseline", 7, 13)]
    assert "drift over several calibrations" in found[0].text()


def test_history_of_a_batch_points_out_the_stretched_target(calibrated, tmp_path, capsys):
    out = tmp_path / "history.html"
    assert main(["history", str(calibrated["out"] / "summary.csv"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    changed = [line for line in printed.splitlines() if line.startswith("  changed")]
    assert len(changed) == 1 and "rig-b: target period τ_w changed by +2" in changed[0]  # 0.3 % of 8.62 mm
    assert "3 rig(s)" in printed  # rig-a, rig-b and the loose recording's folder; the corrupt row is left out
    page = out.read_text()
    assert re.search(r'<ul id="changes"><li class=flag>rig-b: target period', page)
    assert 'src="data:image/png;base64,' in page and "http" not in page  # self-contained
    for q in QUANTITIES:
        assert q.label in page


def test_history_of_a_data_directory_says_what_to_run(archive, capsys):
    assert main(["history", str(archive["rig-a"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "graytrack batch diagnose" in err[0]
