"""The job runner on a ManualClock: the states it persists, the outcome and the duration it records."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from graytrack.core.errors import GraytrackError
from graytrack.service.daemon.jobs import CalibrationJob, JobRunner
from graytrack.service.daemon.manual_clock import ManualClock
from tests.service.fakes import StatusFiles, new_job

pytestmark = pytest.mark.unit
MODEL = object()  # what the fit hands to install; the runner only passes it on


class TimedSteps:
    """A sweep and a fit that take ``sweep_s`` and ``fit_s`` of the clock's time; the fit may fail or be aborted."""

    def __init__(self, runner: JobRunner, clock: ManualClock, sweep_s: float, fit_s: float,
                 fail: Exception | None = None, abort: str | None = None) -> None:
        self.runner, self.clock = runner, clock
        self.sweep_s, self.fit_s, self.fail, self.abort = sweep_s, fit_s, fail, abort

    def sweep(self) -> str:
        self.runner.enter("sweeping", 0.0, "sweeping")
        self.clock.advance(self.sweep_s)
        return "recording"

    def fit(self, recording: Any) -> Any:
        self.runner.enter("fitting", 0.8, f"fitting {recording}")
        self.clock.advance(self.fit_s)
        if self.abort is not None:
            self.runner.job.request_abort(self.abort)
        if self.fail is not None:
            raise self.fail
        return MODEL


def run(tmp_path: Path, **steps: Any) -> tuple[CalibrationJob, StatusFiles, list[Any], list[CalibrationJob]]:
    clock, files, installed, finished = ManualClock(), StatusFiles(tmp_path), [], []
    runner = JobRunner(new_job(), files, lambda model, job: installed.append(model), finished.append, clock=clock)
    runner.run(TimedSteps(runner, clock, **steps))
    return runner.job, files, installed, finished


def test_a_job_that_succeeds_is_installed_then_done_with_the_clocks_duration(tmp_path: Path) -> None:
    job, files, installed, finished = run(tmp_path, sweep_s=3.5, fit_s=1.25)
    assert [d["state"] for d in files.documents] == ["sweeping", "fitting", "installing", "done"]
    assert installed == [MODEL] and finished == [job]
    assert (job.state, job.progress, job.duration_s, job.error) == ("done", 1.0, 4.75, None)
    assert files.documents[-1]["duration_s"] == 4.75, "status.json says what memory says"


def test_a_job_whose_fit_fails_ends_failed_with_the_reason_and_installs_nothing(tmp_path: Path) -> None:
    job, files, installed, _ = run(tmp_path, sweep_s=2.0, fit_s=0.5, fail=GraytrackError("the geometry is refused"))
    assert installed == []
    assert (job.state, job.duration_s, job.error) == ("failed", 2.5, "the geometry is refused")
    assert job.message == "failed: the geometry is refused" and files.documents[-1]["state"] == "failed"


def test_a_stop_during_the_fit_aborts_the_job_without_a_new_model(tmp_path: Path) -> None:
    job, files, installed, _ = run(tmp_path, sweep_s=1.0, fit_s=0.25, abort="calibration aborted by a stop request")
    assert installed == []
    assert (job.state, job.duration_s, job.error) == ("aborted", 1.25, "calibration aborted by a stop request")
    assert [d["state"] for d in files.documents] == ["sweeping", "fitting", "aborted"]


class SteppedSweep(TimedSteps):
    """A sweep of 41 stops, each reported as the daemon's sweep reports it (sweep.py)."""

    def sweep(self) -> str:
        self.runner.enter("sweeping", 0.0, "moving to the first of 41 stops")
        for i in range(41):
            self.runner.update(0.8 * (i + 1) / 41, f"stop {i + 1}/41 at {0.25 * i:.3f} mm")
        return "recording"


def test_the_log_follows_the_job_a_line_per_state_and_per_tenth_of_the_progress(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    clock, files = ManualClock(), StatusFiles(tmp_path)
    runner = JobRunner(new_job(), files, lambda model, job: None, lambda job: None, clock=clock)
    with caplog.at_level("INFO", logger="graytrack.daemon"):
        runner.run(SteppedSweep(runner, clock, sweep_s=0.0, fit_s=1.0))
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith(f"calibration {runner.job.id}: ")]
    # sweeping 0 %, then 10 … 80 % over 41 updates (8 lines, not 41), fitting 80 %, installing
    assert len(lines) == 1 + 8 + 1 + 1, lines
    assert lines[0].endswith("sweeping 0 % · moving to the first of 41 stops")
    assert lines[1].endswith("sweeping 12 % · stop 6/41 at 1.250 mm")  # the first update past 10 %
    assert lines[8].endswith("sweeping 80 % · stop 41/41 at 10.000 mm")
    assert "fitting 80 % · fitting recording" in lines[9] and "installing" in lines[10]
