"""Bad input never ends in a traceback: every case of issue #9 gets one line and exit status 2.

Each case runs the real command line (``main``), which lets only the expected errors through as
a one-line reason: anything unexpected would propagate and fail the test.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from graytrack.core.files import write_atomic
from graytrack.core.recording import BUDGET_ENV, save
from graytrack.service.cli import main
from tests.conftest import PAPER_META, paper_recording


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def raw_npy(header: str, body: bytes = b"") -> bytes:
    """A version-1.0 .npy member with a header we write by hand (padded as numpy pads it)."""
    text = header + " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode("latin1") + body


def npz(path: Path, frames: bytes, n: int = 4) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("frames.npy", frames)
        archive.writestr("t.npy", npy_bytes(np.arange(n, dtype=np.float64)))
        archive.writestr("reference.npy", npy_bytes(np.zeros(n)))
    return path


def unchecked_npz(path: Path, frames: np.ndarray, t: np.ndarray, reference: np.ndarray) -> Path:
    """A recording file written without the writer's validation (as another tool might)."""
    np.savez_compressed(path, frames=frames, t=t, reference=reference, meta=np.array(json.dumps(PAPER_META)))
    return path


def refused(argv: list[str], capsys: pytest.CaptureFixture[str], *expected: str) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"graytrack {argv[0]}: error: "), err
    for text in expected:
        assert text in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def cal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save(paper_recording(n_frames=200, seed=41), tmp_path_factory.mktemp("bad") / "cal.npz")


@pytest.fixture(scope="module")
def model(cal: Path) -> Path:
    path = cal.with_name("model.json")
    assert main(["calibrate", str(cal), "--out", str(path)]) == 0
    return path


# -- recordings --------------------------------------------------------------------------------
def test_broken_npy_header(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = npz(tmp_path / "r.npz", raw_npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 3"))
    refused(["calibrate", str(rec), "--out", str(tmp_path / "m.json")], capsys, "frames: broken .npy header")


def test_a_declared_shape_of_a_trillion_frames_is_refused_before_any_allocation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = npz(tmp_path / "r.npz", raw_npy("{'descr': '|u1', 'fortran_order': False, 'shape': (1000000000000, 100), }"))
    refused(["calibrate", str(rec), "--out", str(tmp_path / "m.json")], capsys, "frames: declares", "beyond the budget")


def test_a_small_zip_inflating_beyond_the_memory_budget_is_refused_unread(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    frames = np.zeros((4000, 1000), np.uint8)  # 4 MB of zeros: a few kB compressed, 32 MB as float64
    rec = npz(tmp_path / "r.npz", npy_bytes(frames), n=4000)
    assert rec.stat().st_size < 50_000
    monkeypatch.setenv(BUDGET_ENV, "16")
    refused(["track", str(rec), "--model", "m.json", "--out", str(tmp_path / "t.csv")], capsys,
            "needing 32.0 MB in memory, beyond the budget of 16.8 MB")


def test_a_zip_entry_larger_than_its_declared_array_is_refused(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    body = bytes(4 * 3) + bytes(2_000_000)  # the array plus 2 MB nobody declared
    rec = npz(tmp_path / "r.npz", raw_npy("{'descr': '|u1', 'fortran_order': False, 'shape': (4, 3), }", body))
    refused(["calibrate", str(rec), "--out", str(tmp_path / "m.json")], capsys,
            "frames: the zip entry inflates to 2.0 MB")


def test_references_times_1e300_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = paper_recording(n_frames=50, seed=3)
    unchecked_npz(tmp_path / "r.npz", rec.frames, rec.t, rec.reference * 1e300)
    refused(["calibrate", str(tmp_path / "r.npz"), "--out", str(tmp_path / "m.json")], capsys,
            "reference: positions beyond")


@pytest.mark.parametrize("times", [np.arange(50.0)[::-1], np.r_[np.arange(25.0), np.arange(25.0)]],
                         ids=["reversed", "jumps-back"])
def test_reversed_or_non_monotonic_time_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   times: np.ndarray) -> None:
    rec = paper_recording(n_frames=50, seed=3)
    unchecked_npz(tmp_path / "r.npz", rec.frames, times, rec.reference)
    refused(["calibrate", str(tmp_path / "r.npz"), "--out", str(tmp_path / "m.json")], capsys,
            "t: times must increase frame by frame")


# -- models and configuration ------------------------------------------------------------------
def test_model_with_clip_gray_reversed(tmp_path: Path, cal: Path, model: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    document = json.loads(model.read_text())
    document["model"]["clip_gray"] = [255, 0]
    bad = tmp_path / "clip.json"
    bad.write_text(json.dumps(document))
    refused(["track", str(cal), "--model", str(bad), "--out", str(tmp_path / "t.csv")], capsys,
            "clip_gray must be [floor, ceiling] with floor < ceiling")


def test_model_json_nested_100000_deep(tmp_path: Path, cal: Path, capsys: pytest.CaptureFixture[str]) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    refused(["track", str(cal), "--model", str(deep), "--out", str(tmp_path / "t.csv")], capsys, "nested too deeply")


@pytest.mark.parametrize(("content", "message"), [
    (b"a = " + b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    (b"[camera]\nkind = \"sim\xff\"\n", "not UTF-8 text: byte 20 is 0xff"),
], ids=["nested-100000", "latin1"])
def test_config_nested_or_not_utf8(tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes,
                                   message: str) -> None:
    config = tmp_path / "graytrack.toml"
    config.write_bytes(content)
    refused(["serve", "--config", str(config), "--data-dir", str(tmp_path / "data")], capsys, "not valid TOML", message)
    assert not (tmp_path / "data").exists()


# -- arguments ---------------------------------------------------------------------------------
@pytest.mark.parametrize("seconds", ["inf", "nan", "-1", "0"])
def test_simulate_seconds_must_be_positive_and_finite(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      seconds: str) -> None:
    refused(["simulate", "--seconds", seconds, "--out", str(tmp_path / "r.npz")], capsys, "--seconds must be positive")
    assert not (tmp_path / "r.npz").exists()


def test_simulate_seconds_beyond_memory_names_the_longest_possible(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    refused(["simulate", "--seconds", "1e12", "--out", str(tmp_path / "r.npz")], capsys, "beyond the memory budget",
            "at most")


@pytest.mark.parametrize(("flag", "value", "limit"), [
    ("--harmonics", "500", "--harmonics 500: at most 69 here; a period of 8.6 mm sampled every 0.062 mm"),
    ("--pixel-degree", "200", "--pixel-degree 200: at most 9 here; 100 pixels support"),
    ("--harmonics", "0", "must be at least 1"),
])
def test_model_size_is_bounded_by_what_the_data_supports(tmp_path: Path, cal: Path, capsys: pytest.CaptureFixture[str],
                                                         flag: str, value: str, limit: str) -> None:
    refused(["calibrate", str(cal), flag, value, "--out", str(tmp_path / "m.json")], capsys, limit)


def test_harmonics_without_a_nominal_geometry_are_bounded_by_the_data(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    rec = save(paper_recording(n_frames=100, seed=4, meta={}), tmp_path / "r.npz")
    refused(["calibrate", str(rec), "--harmonics", "200", "--out", str(tmp_path / "m.json")], capsys,
            "--harmonics 200: at most 124 here; 10000 gray values with a reference determine 1000 coefficients")


# -- output paths ------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["calibrate", "simulate"])
def test_out_is_an_existing_folder(tmp_path: Path, cal: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    argv = ["calibrate", str(cal)] if command == "calibrate" else ["simulate", "--seconds", "0.1"]
    line = refused([*argv, "--out", str(tmp_path)], capsys, "is a folder; name the file to write")
    assert ".tmp" not in line and list(tmp_path.glob(".*")) == []


@pytest.mark.parametrize("command", ["calibrate", "track", "simulate", "diagnose"])
def test_out_in_a_missing_folder_is_refused_and_nothing_is_created(tmp_path: Path, cal: Path, model: Path,
                                                                   capsys: pytest.CaptureFixture[str],
                                                                   command: str) -> None:
    target = tmp_path / "missing" / "deeper" / "out.file"
    argv = {"calibrate": ["calibrate", str(cal)], "track": ["track", str(cal), "--model", str(model)],
            "simulate": ["simulate", "--seconds", "0.1"], "diagnose": ["diagnose", str(cal)]}[command]
    refused([*argv, "--out", str(target)], capsys, "does not exist (create it first")
    assert not (tmp_path / "missing").exists()


def test_atomic_writes_name_the_target_never_the_temporary_file(tmp_path: Path) -> None:
    folder = tmp_path / "taken"
    folder.mkdir()
    (folder / "inside").write_text("x")  # a non-empty folder cannot be replaced by a file
    with pytest.raises(OSError) as err:
        write_atomic(folder, "content")
    assert err.value.filename == str(folder) and ".tmp" not in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"], "the temporary file is removed"


def test_a_whole_process_shows_no_traceback(tmp_path: Path) -> None:
    rec = npz(tmp_path / "r.npz", raw_npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 3"))
    run = subprocess.run([sys.executable, "-m", "graytrack", "calibrate", str(rec), "--out", str(tmp_path / "m.json")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr and len(run.stderr.strip().splitlines()) == 1


def test_effect_counts_beyond_a_real_rig_are_refused_before_building_it(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    refused(["simulate", "--effects", "rows:n=1000000", "--out", str(tmp_path / "r.npz")], capsys,
            "effect 'rows': n (a sensor's ROI strip) must be 1..4096")
    refused(["simulate", "--effects", "dust:count=1e9", "--out", str(tmp_path / "r.npz")], capsys,
            "effect 'dust': count must be 0..10000")
