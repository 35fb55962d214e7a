"""One held-out validation (core/diagnosis/heldout.py) for every caller: `graytrack calibrate`, the
daemon's calibration sweep and a direct call hold out the same frames of the same recording and
report the same figures; `calibrate --model paper` reports them (it reported ``held_out: null``)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis.heldout import HELD_OUT_BLOCKS, held_out_blocks, loop_split, validate
from graytrack.core.holdout import HOLDOUT_BLOCK_FRAMES, HOLDOUT_EVERY, reading_blocks
from graytrack.core.errors import CalibrationError
from graytrack.core.recording import Recording, save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.sim.stage import FunctionTrajectory
from graytrack.service.batch.discover import Source
from graytrack.service.batch.jobs import Job, run_job
from graytrack.service.calibration_run import calibrate_recording
from graytrack.service.cli import main
from graytrack.service.daemon.jobs import JobRunner
from graytrack.service.daemon.manual_clock import ManualClock
from graytrack.service.daemon.settings import SweepConfig
from graytrack.service.daemon.sweep import Sweep
from graytrack.service.daemon.grating import Readings
from tests.service.fakes import FakeFeed, FakeStage, StatusFiles, new_job

STOPS, DWELL_S = 21, 0.05
UNTOLD = "gradient:per_10mm=0.05"  # an illumination gradient the paper model is not told about


def _stops(seed: int, run: int = 0, effects: str = UNTOLD) -> Recording:
    """A step-and-settle sweep of the paper rig (by default with an effect the model is not told
    about): 21 stops of 2-3 frames, each stop's frames sharing one grating reading (as the daemon's
    sweep records them)."""
    rig = build_rig("paper", effects, seed=seed, run=run)
    low, high = rig.config.stroke_mm

    def position(t: np.ndarray) -> np.ndarray:
        return low + (high - low) * np.minimum(np.floor(t / DWELL_S), STOPS - 1) / (STOPS - 1)

    recording, _ = rig.record(STOPS * DWELL_S, trajectory=FunctionTrajectory(position, np.zeros_like))
    return recording


@pytest.fixture(scope="module")
def stops() -> Recording:
    return _stops(seed=5)


@pytest.fixture(scope="module")
def direct(stops: Recording) -> dict:
    held = validate(stops, lambda part: calibrate(part, "paper").model, label="paper model")
    assert held is not None
    return held.as_dict()


def _cli_line(stops: Recording, tmp_path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    path = save(stops, tmp_path / "stops.npz")
    assert main(["calibrate", str(path), "--model", "paper", "--out", str(tmp_path / "m.json"), *extra]) == 0
    return next(line for line in capsys.readouterr().out.splitlines() if line.startswith("held"))


def test_calibrate_model_paper_reports_its_held_out_error_next_to_the_bound(stops, tmp_path, capsys) -> None:
    plain = _stops(seed=5, effects="")
    clean = calibrate_recording(plain, "paper").report["held_out"]
    assert clean is not None and clean["frames"] == plain.n_frames  # two-fold: every frame held out once
    assert 0.7 * clean["bound_um"] < clean["error_std_um"] < 1.5 * clean["bound_um"], clean
    run = calibrate_recording(stops, "paper")
    held = run.report["held_out"]
    # the gradient the paper model does not know: its held-out error says so, far above the bound
    assert held["error_std_um"] > 4.0 * held["bound_um"] and held["frames"] == stops.n_frames, held
    assert run.report["noise"]["crlb_um"] == held["bound_um"]
    assert "held-out error" in run.summary
    line = _cli_line(stops, tmp_path, capsys)
    assert f"error std {held['error_std_um']:.3f} um on {stops.n_frames} held-out frames" in line
    assert f"Cramer-Rao bound {held['bound_um']:.3f} um" in line


def test_the_cli_batch_the_daemons_sweep_and_a_direct_call_get_the_same_figures(stops, direct, tmp_path,
                                                                               capsys) -> None:
    clock = ManualClock()
    files = StatusFiles(tmp_path / "daemon")
    job = new_job(STOPS, 3)
    runner = JobRunner(job, files, lambda model, job: None, lambda job: None, clock=clock)
    sweep = Sweep(runner, FakeStage(clock), FakeFeed(Readings(1.0, 1e-3), 100.0), files,  # type: ignore[arg-type]
                  SweepConfig(), {"source": "test"}, lambda t: None, clock=clock)
    sweep.fit(stops)  # the daemon's fit of a recorded sweep, as after sweep()
    assert job.report["held_out"] == direct
    assert calibrate_recording(stops, "paper").report["held_out"] == direct
    source = Source(save(stops, tmp_path / "batch.npz"), "stops")
    assert run_job(Job("calibrate", source, str(tmp_path / "batch")))["status"] == "ok"
    assert json.loads((tmp_path / "batch" / "stops" / "report.json").read_text())["held_out"] == direct
    line = _cli_line(stops, tmp_path, capsys)
    printed = re.findall(r"(\d+\.\d+) um", line)  # the terminal shows three decimals
    assert printed == [f"{direct['error_std_um']:.3f}", f"{direct['bound_um']:.3f}"], (line, direct)


def test_a_block_keeps_each_stop_whole_and_a_scan_in_its_share_of_the_recording(stops) -> None:
    block = held_out_blocks(stops)
    for reading in np.unique(stops.reference):
        assert np.unique(block[stops.reference == reading]).size == 1  # no stop is cut
    assert int(block.max()) + 1 >= 8  # enough for two folds of at least four blocks
    n = 2000
    at_rest = np.full(10, 1.0)
    scan = Recording(np.zeros((n, 8), np.float32), np.arange(n) * 1e-3,
                     np.concatenate([at_rest, np.linspace(1.001, 9.0, n - 20), at_rest * 9.5]), {})
    block = held_out_blocks(scan)
    assert int(block.max()) + 1 == HELD_OUT_BLOCKS and np.all(np.diff(block) >= 0)
    assert np.unique(block[:10]).size == 1 and np.unique(block[-10:]).size == 1


def test_a_validation_recording_replaces_the_folds_and_must_share_the_roi(stops, tmp_path, capsys) -> None:
    validation = _stops(seed=5, run=1)  # the same rig, another session: the same fixed patterns, new noise
    run = calibrate_recording(stops, "paper", validation=validation)
    held = run.report["held_out"]
    assert held["method"].startswith(f"validation recording ({validation.n_frames} frames)")
    assert held["frames"] == validation.n_frames
    assert held["error_std_um"] > 4.0 * held["bound_um"], held  # the untold gradient, seen on the other session too
    line = _cli_line(stops, tmp_path, capsys, "--validate", str(save(validation, tmp_path / "val.npz")))
    assert f"error std {held['error_std_um']:.3f} um" in line
    narrow = Recording(validation.frames[:, :-1], validation.t, validation.reference, dict(validation.meta))
    with pytest.raises(CalibrationError, match="same camera ROI"):
        calibrate_recording(stops, "paper", validation=narrow)


def test_the_loop_holds_out_one_fold_of_the_same_reading_blocks(stops) -> None:
    """The closed loop compares its candidates on one fold none of them fitted (why one: heldout.py's docstring),
    a quarter of the frames; its blocks come from the same function as the two-fold's, so no stop is cut: a
    held-out frame never shares a grating reading with a fitted one. A scan whose every frame has its own
    reading (the demo's) gets blocks of HOLDOUT_BLOCK_FRAMES frames, as the loop always held out."""
    data, train, val, _ = loop_split(stops, None)
    assert len(train.x_mm) + len(val.x_mm) == len(data.x_mm) and len(val.x_mm) > 0
    assert not set(train.x_mm.tolist()) & set(val.x_mm.tolist())  # no stop cut between fit and held-out
    block = reading_blocks(data.x_mm, HOLDOUT_BLOCK_FRAMES)
    np.testing.assert_array_equal(val.x_mm, data.x_mm[block % HOLDOUT_EVERY == HOLDOUT_EVERY // 2])
    np.testing.assert_array_equal(block, np.maximum.accumulate(block))  # numbered in recording order
    assert np.array_equal(np.unique(block), np.arange(block.max() + 1))  # no number skipped: every 4th is a 4th
    scan = np.linspace(1.0, 9.0, 1000)
    np.testing.assert_array_equal(reading_blocks(scan, HOLDOUT_BLOCK_FRAMES), np.arange(1000) // HOLDOUT_BLOCK_FRAMES)
