"""The calibration sweep's plan and deadlines on a ManualClock: which frames a stop keeps, how long
it waits for them, the velocity a pass is planned at and how long it is allowed."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from graytrack.drivers.camera.base import Frame
from graytrack.service.daemon.acquisition import Sample
from graytrack.service.daemon.grating import Readings
from graytrack.service.daemon.jobs import JobRunner
from graytrack.service.daemon.manual_clock import ManualClock
from graytrack.service.daemon.settings import SweepConfig
from graytrack.service.daemon.sweep import Sweep, SweepError
from tests.service.fakes import FakeFeed, FakeStage, StatusFiles, new_job

pytestmark = pytest.mark.unit


class Rig:
    """A sweep on fake parts, run on its own thread as the daemon runs it."""

    def __init__(self, tmp_path: Path, config: SweepConfig, frame_rate_hz: float = 100.0, clock_scale: float = 1.0,
                 readings: Readings | None = None) -> None:
        self.clock = ManualClock()
        self.stage = FakeStage(self.clock)
        self.frames = FakeFeed(readings or Readings(1.0, 1e-3), frame_rate_hz)
        self.files = StatusFiles(tmp_path)
        job = new_job(config.positions, config.frames_per_position)
        self.runner = JobRunner(job, self.files, lambda model, job: None, lambda job: None, clock=self.clock)
        self.sweep = Sweep(self.runner, self.stage, self.frames, self.files, config, {"source": "test"},  # type: ignore[arg-type]
                           lambda t: None, clock_scale=clock_scale, clock=self.clock)
        self.outcome: list[object] = []
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            self.outcome.append(self.sweep.sweep())
        except Exception as exc:  # noqa: BLE001 - the test looks at it
            self.outcome.append(exc)

    def start(self) -> "Rig":
        self.thread.start()
        self.clock.settle()
        return self

    def frame(self, frame_id: int, t: float, exposure_s: float = 0.01, last: bool = False) -> None:
        """A frame of mid-exposure ``t`` into the sweep's subscription; unless it is the ``last`` the
        sweep needs, wait until the sweep has looked at it and waits again."""
        frame = Frame(np.full((1, 4), float(frame_id)), frame_id, t, exposure_s=exposure_s)
        self.clock.put(self.frames.feeds[0], Sample(frame, t, float("nan")))
        if not last:
            self.clock.settle()

    def end(self) -> object:
        self.thread.join(10.0)
        assert not self.thread.is_alive() and len(self.outcome) == 1
        return self.outcome[0]


def test_a_stop_keeps_the_frames_exposed_after_the_settle_at_the_rest_position(tmp_path: Path) -> None:
    rig = Rig(tmp_path, SweepConfig(kind="stops", positions=2, frames_per_position=3, margin_mm=0.5)).start()
    for stop in range(2):
        settled = rig.clock.now()  # the fake stage settles at once, stamped now
        rig.frame(10 * stop, settled - 0.001)  # mid-exposure before the settle: blurred by the move
        rig.frame(10 * stop + 1, settled + 0.004)  # began 1 ms before the settle (10 ms exposure)
        for k in range(2, 5):
            rig.clock.advance(0.01)
            rig.frame(10 * stop + k, rig.clock.now(), last=(stop, k) == (1, 4))
    recording = rig.end()
    assert not isinstance(recording, Exception), recording
    assert rig.stage.moves == [0.5, 9.5]  # margin_mm inside the limits [0, 10]
    assert list(recording.frames[:, 0]) == [2, 3, 4, 12, 13, 14]
    assert list(recording.reference) == [0.5, 0.5, 0.5, 9.5, 9.5, 9.5]
    assert (tmp_path / rig.runner.job.id / "recording.npz").is_file()


def test_a_stop_that_settles_away_from_its_plan_fails_the_sweep_with_where_it_was(tmp_path: Path) -> None:
    """Another command replaced the sweep's first move (it landed at 2 mm, not the planned 0.1 mm): the sweep
    fails saying so, before a frame is taken there, instead of recording the stop at the wrong place."""
    rig = Rig(tmp_path, SweepConfig(kind="stops", positions=2, frames_per_position=3, stop_tolerance_um=10.0))
    rig.stage.intruder_mm = 2.0
    rig.thread.start()  # it fails without waiting on the clock
    error = rig.end()
    assert isinstance(error, SweepError), error
    assert str(error) == ("the stop planned at 0.1000 mm was at 2.0000 mm settled (1900.0 µm off, more than [sweep] "
                          "stop_tolerance_um = 10): something else moved the stage during the calibration")
    assert not (tmp_path / rig.runner.job.id / "recording.npz").exists(), "no recording of the wrong place"


def test_a_stop_within_its_tolerance_is_recorded_where_it_settled(tmp_path: Path) -> None:
    rig = Rig(tmp_path, SweepConfig(kind="stops", positions=2, frames_per_position=3, stop_tolerance_um=10.0))
    rig.stage.intruder_mm = 0.1 + 9e-6  # 9 µm off the plan, inside 10
    rig.start()
    for stop in range(2):
        for k in range(3):
            rig.clock.advance(0.01)
            rig.frame(10 * stop + k, rig.clock.now(), last=(stop, k) == (1, 2))
    recording = rig.end()
    assert not isinstance(recording, Exception), recording
    assert list(recording.reference) == [0.1 + 9e-6] * 3 + [9.9] * 3


def test_a_stop_fails_after_frame_timeout_s_naming_how_many_frames_came(tmp_path: Path) -> None:
    rig = Rig(tmp_path, SweepConfig(kind="stops", positions=2, frames_per_position=3, frame_timeout_s=2.0)).start()
    rig.frame(1, rig.clock.now() + 0.01)
    rig.clock.advance(1.875)
    rig.clock.settle()
    assert rig.thread.is_alive(), "1.875 s of a 2 s wait"
    rig.clock.advance(0.125)
    error = rig.end()
    assert isinstance(error, SweepError)
    assert str(error) == "the camera delivered 1 of 3 frames within 2 s"


def scan_until_pass(tmp_path: Path, readings: Readings, **config: object) -> Rig:
    """A scan whose stage never reaches the end of its pass, stopped at the start of that pass."""
    rig = Rig(tmp_path, SweepConfig(kind="scan", scan_frames=200, frames_per_position=3, settle_timeout_s=5.0,
                                    **config), frame_rate_hz=100.0, readings=readings)
    rig.stage.arrives_moves = 1  # the first stop is reached, the end of the pass never
    rig.start()
    for k in range(3):  # the first stop, at rest
        rig.frame(k, rig.clock.now() + 0.01)
    return rig


def test_a_pass_is_planned_from_the_frame_rate_and_fails_after_twice_its_time_and_the_settle(tmp_path: Path) -> None:
    rig = scan_until_pass(tmp_path, Readings(1.0, 1e-3), margin_mm=0.1)
    # 2 passes over 9.8 mm giving 200 frames at 100 frames/s: 9.8 mm/s (the stage allows 20)
    assert rig.stage.velocities == [pytest.approx(9.8)]
    rig.clock.advance(6.875)  # a pass of 1 s is allowed 2 x 1 s + settle_timeout_s = 7 s
    rig.clock.settle()
    assert rig.thread.is_alive()
    rig.clock.advance(0.25)
    error = rig.end()
    assert isinstance(error, SweepError) and str(error) == "the pass did not reach 9.900 mm within 7 s"
    assert rig.stage.velocities[-1] == 20.0, "the stage's own velocity is restored"


def test_a_pass_slows_down_until_a_readings_instant_is_known_within_the_pairing_tolerance(tmp_path: Path) -> None:
    readings = Readings(1.0, 1e-3)
    readings.append(999.0, 0.1, latency_s=0.01)  # a 10 ms round trip: each reading's instant within ±5 ms
    rig = scan_until_pass(tmp_path, readings, margin_mm=0.1)
    # half the 1 µm tolerance over 5 ms: 0.1 mm/s, a pass of 98 s allowed 2 x 98 + 5 s
    assert rig.stage.velocities == [pytest.approx(0.1)]
    rig.clock.advance(200.875)
    rig.clock.settle()
    assert rig.thread.is_alive()
    rig.clock.advance(0.25)
    error = rig.end()
    assert isinstance(error, SweepError) and str(error) == "the pass did not reach 9.900 mm within 201 s"
