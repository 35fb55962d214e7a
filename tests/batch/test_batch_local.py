"""``graytrack batch`` on an in-process Dask cluster: rows, failures, resume, the three kinds of work."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from graytrack.core.models import load_model
from graytrack.service.batch.summary import COLUMNS, read_summary
from graytrack.service.cli import main

from tests.batch.conftest import without_time
from tests.tables import read_columns

pytest.importorskip("distributed")


def run_batch(kind: str, paths: list[str], out: Path, scheduler: str, *extra: str) -> tuple[int, list[dict]]:
    code = main(["batch", kind, *paths, "--out", str(out), "--scheduler", scheduler, *extra])
    return code, read_summary(out / "summary.csv")


def test_calibrate_batch_rows_failure_and_outputs(calibrated):
    code, rows, out = calibrated["code"], calibrated["rows"], calibrated["out"]
    assert code == 1  # one recording failed; the batch still finished every other one
    assert list(rows[0]) == list(COLUMNS)
    by_name = {row["name"]: row for row in rows}
    assert sorted(by_name) == sorted(["rig-a-20260105T080000000000Z", "rig-a-20260112T080000000000Z",
                                      "rig-b-20260105T080000000000Z", "rig-b-20260112T080000000000Z",
                                      "sweep", "corrupt"])
    corrupt = by_name["corrupt"]
    assert corrupt["status"] == "failed" and "not a readable .npz recording" in corrupt["reason"]
    assert "\n" not in corrupt["reason"] and not (out / "corrupt").exists()
    for name, row in by_name.items():
        if name == "corrupt":
            continue
        assert row["status"] == "ok", row["reason"]
        assert row["frames"] == "100" and row["rows_x_pixels"] == "1x100"
        model = load_model(out / name / "model.json")  # as `graytrack calibrate` writes it
        assert float(row["tau_w_mm"]) == pytest.approx(model.period_mm, rel=1e-6)
        assert 0 < float(row["tau_w_u_mm"]) < 2e-3 and 0 < float(row["alpha_d_u_mm"]) < 2e-4
        assert float(row["noise_gray"]) == pytest.approx(0.7, rel=0.05)
    a = by_name["rig-a-20260112T080000000000Z"]
    assert (a["rig"], a["calibrated_at"]) == ("rig-a", "2026-01-12T08:00:00Z")
    assert by_name["sweep"]["rig"] == "loose"
    stretched = float(by_name["rig-b-20260112T080000000000Z"]["tau_w_mm"])
    assert stretched / float(by_name["rig-b-20260105T080000000000Z"]["tau_w_mm"]) == pytest.approx(1.003, abs=3e-4)
    assert "batch: 6/6 done, 1 failed" in calibrated["stderr"] and "rec/s" in calibrated["stderr"]


def test_resume_skips_finished_recordings_and_force_redoes_them(archive, in_process_scheduler, tmp_path, capsys):
    paths = [str(archive["rig-a"]), str(archive["loose"])]
    _, first = run_batch("calibrate", paths, tmp_path, in_process_scheduler)
    markers = {row["name"]: (tmp_path / row["name"] / "batch.json").stat().st_mtime_ns for row in first}
    capsys.readouterr()
    _, again = run_batch("calibrate", paths, tmp_path, in_process_scheduler)
    out = capsys.readouterr().out
    assert "3 recording(s), 0 run, 3 skipped" in out
    assert again == first  # the very rows, times included: nothing was redone
    assert {name: (tmp_path / name / "batch.json").stat().st_mtime_ns for name in markers} == markers
    (tmp_path / first[0]["name"] / "batch.json").unlink()  # an incomplete output is redone
    _, partial = run_batch("calibrate", paths, tmp_path, in_process_scheduler)
    assert "1 run, 2 skipped" in capsys.readouterr().out and without_time(partial) == without_time(first)
    replaced = Path(first[1]["path"])
    times = (replaced.stat().st_atime_ns, replaced.stat().st_mtime_ns)
    os.utime(replaced, ns=(times[0], times[1] + 1))  # as if a new recording had been written there
    try:
        run_batch("calibrate", paths, tmp_path, in_process_scheduler)
    finally:
        os.utime(replaced, ns=times)  # the archive is shared with other tests
    assert "1 run, 2 skipped" in capsys.readouterr().out
    _, forced = run_batch("calibrate", paths, tmp_path, in_process_scheduler, "--force")
    assert "3 run, 0 skipped" in capsys.readouterr().out and without_time(forced) == without_time(first)
    _, ideal = run_batch("calibrate", paths, tmp_path, in_process_scheduler, "--model", "ideal")
    assert "3 run, 0 skipped" in capsys.readouterr().out  # other work, not the finished one
    assert all(row["model"].startswith("ideal") for row in ideal)


def test_track_batch_uses_the_model_beside_each_calibration(archive, in_process_scheduler, tmp_path):
    code, rows = run_batch("track", [str(archive["rig-a"]), str(archive["loose"])], tmp_path, in_process_scheduler)
    assert code == 1
    by_name = {row["name"]: row for row in rows}
    assert by_name["sweep"]["status"] == "failed" and "no model" in by_name["sweep"]["reason"]
    for name in ("rig-a-20260105T080000000000Z", "rig-a-20260112T080000000000Z"):
        row = by_name[name]
        assert row["status"] == "ok" and row["locked"] == "100" and row["lock_events"] == "0"
        # tracked against its own sweep: noise-limited, within 1.5x the Cramér-Rao bound
        assert float(row["error_std_after_um"]) < 1.5 * float(row["crlb_after_um"])
        header = (tmp_path / name / "track.csv").read_text().splitlines()[0]
        assert header.startswith("t,x_mm,locked")


def test_diagnose_batch_writes_the_closed_loop_outputs(archive, in_process_scheduler, tmp_path):
    recording = archive["rig-b"] / "calibrations" / "20260105T080000000000Z" / "recording.npz"
    code, rows = run_batch("diagnose", [str(recording)], tmp_path, in_process_scheduler)
    assert code == 0
    (row,) = rows
    folder = tmp_path / row["name"]
    report = json.loads((folder / "report.json").read_text())
    assert {p.name for p in folder.iterdir()} >= {"report.json", "report.html", "model.json", "batch.json"}
    assert float(row["error_std_after_um"]) == pytest.approx(report["after"]["error_std_um"], rel=1e-5)
    assert float(row["crlb_after_um"]) == pytest.approx(report["noise"]["crlb_um"], rel=1e-5)
    assert row["effects"] == ";".join(step["effect"] for step in report["steps"])
    assert math.isfinite(float(row["tau_w_u_mm"]))


def test_chunked_track_command_equals_sequential(archive, in_process_scheduler, tmp_path):
    import numpy as np

    folder = archive["rig-a"] / "calibrations" / "20260105T080000000000Z"
    common = ["track", str(folder / "recording.npz"), "--model", str(folder / "model.json"), "--no-reference"]
    assert main([*common, "--out", str(tmp_path / "seq.csv")]) == 0
    assert main([*common, "--out", str(tmp_path / "chunked.csv"), "--chunk-frames", "30", "--overlap", "10",
                 "--scheduler", in_process_scheduler]) == 0
    seq, chunked = (read_columns(tmp_path / f"{n}.csv") for n in ("seq", "chunked"))
    both = (seq["locked"] == 1) & (chunked["locked"] == 1)
    assert both.sum() >= 95
    assert np.max(np.abs(seq["x_mm"][both] - chunked["x_mm"][both])) < 1e-6  # 1 nm
    # no grating read: the chunks' bounds carry the slide as the sequential run's do (core/slide.py)
    assert np.all(chunked["slide_sigma_um"][both] > 0) and np.all(chunked["crlb_um"] >= chunked["slide_sigma_um"])


BLOCK_DASK = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('dask', 'distributed'):
            raise ImportError('blocked for the test: ' + name)
sys.meta_path.insert(0, Block())
from graytrack.service.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("command", [["batch", "calibrate"], ["track", "--model", "m.json", "--out", "t.csv",
                                                              "--chunk-frames", "50"]])
def test_without_dask_one_line_says_how_to_install(archive, tmp_path, command):
    args = [*command, str(archive["loose"])] + (["--out", str(tmp_path / "out")] if command[0] == "batch" else [])
    done = subprocess.run([sys.executable, "-c", BLOCK_DASK, *args], capture_output=True, text=True, cwd=tmp_path,
                          timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'graytrack[cluster]'" in lines[0], done.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "t.csv").exists()
