"""The command line: calibrate and track end to end, and one-line errors with exit status 2."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from graytrack.core.recording import save
from graytrack.service.cli import main
from tests.tables import read_columns


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    from tests.conftest import paper_recording

    folder = tmp_path_factory.mktemp("cli")
    return (save(paper_recording(n_frames=600, seed=31), folder / "cal.npz"),
            save(paper_recording(n_frames=300, seed=32, shift_mm=0.002), folder / "val.npz"))


def test_calibrate_then_track(tmp_path, recordings, capsys):
    cal, val = recordings
    assert main(["calibrate", str(cal), "--model", "paper", "--out", str(tmp_path / "m.json")]) == 0
    assert "rmse" in capsys.readouterr().out
    assert main(["track", str(val), "--model", str(tmp_path / "m.json"), "--out", str(tmp_path / "t.csv")]) == 0
    header = (tmp_path / "t.csv").read_text().splitlines()[0]
    assert header.startswith("t,x_mm")
    error_um = read_columns(tmp_path / "t.csv")["error_um"]
    assert error_um.shape[0] == 300 and np.std(error_um) < 2.5


@pytest.mark.parametrize(
    "argv, message",
    [
        (["calibrate", "{missing}", "--out", "{tmp}/m.json"], "no such file"),
        (["calibrate", "{garbage}", "--out", "{tmp}/m.json"], "not an .npz recording"),
        (["track", "{cal}", "--model", "{garbage}", "--out", "{tmp}/t.csv"], "not a JSON model file"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, recordings, argv, message):
    (tmp_path / "garbage.npz").write_bytes(b"\x00garbage")
    names = {"missing": tmp_path / "nope.npz", "garbage": tmp_path / "garbage.npz", "tmp": tmp_path,
             "cal": recordings[0]}
    argv = [arg.format(**names) for arg in argv]
    run = subprocess.run([sys.executable, "-m", "graytrack", *argv], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert message in run.stderr and "Traceback" not in run.stderr
    assert len([line for line in run.stderr.splitlines() if "error" in line]) == 1


HEAVY_MODULES = ("numpy", "scipy", "matplotlib", "cv2", "pydantic", "fastapi", "uvicorn", "graytrack.core")


def test_building_the_parser_imports_no_numerics_or_server():
    """Every invocation builds the whole parser: command modules import their work inside `run`."""
    code = ("import sys; from graytrack.service.cli import build_parser; build_parser(); "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY_MODULES!r} or "
            f"m.startswith({HEAVY_MODULES!r})))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert run.stdout.strip() == "[]", run.stdout
    help_run = subprocess.run([sys.executable, "-m", "graytrack", "track", "--help"], capture_output=True, text=True,
                              timeout=60)
    assert help_run.returncode == 0 and "--model" in help_run.stdout


def test_a_named_command_parses_as_with_every_command_registered():
    """``main`` registers only the command named first: its parse and its help are the full parser's."""
    from graytrack.service.cli import build_parser

    argv = ["track", "rec.npz", "--model", "m.json", "--out", "o.csv", "--light", "free", "--trim"]
    alone, full = build_parser("track").parse_args(argv), build_parser().parse_args(argv)
    assert {k: v for k, v in vars(alone).items() if k != "func"} == {k: v for k, v in vars(full).items() if k != "func"}
    assert alone.func is full.func
    assert build_parser("track")._subparsers._group_actions[0].choices["track"].format_help() == \
        build_parser()._subparsers._group_actions[0].choices["track"].format_help()
    assert "sim-controller" in build_parser("sim_controller")._subparsers._group_actions[0].choices
