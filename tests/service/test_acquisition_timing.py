"""The frame loop's timing decisions on a ManualClock: camera silence, the frame rate, gaps, the reopen pause.

Every figure here is the clock's: the test moves time by the amount it means and then looks, so
the outcome cannot depend on how busy the machine is.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from graytrack.service.daemon.acquisition import READ_TIMEOUT_S, Acquisition
from graytrack.service.daemon.grating import Readings
from graytrack.service.daemon.manual_clock import ManualClock
from tests.service.fakes import ClockCamera, FaultTable, stop_worker

pytestmark = pytest.mark.unit
FAULT_AFTER_S = 1.0
REOPEN_S = 0.5


class Loop:
    def __init__(self) -> None:
        self.clock = ManualClock()
        self.camera = ClockCamera(self.clock)
        self.camera.open()
        self.faults = FaultTable()
        self.published: list[dict] = []
        self.acquisition = Acquisition(self.camera, Readings(1.0, 1e-3), self.published.append, self.faults,
                                       FAULT_AFTER_S, REOPEN_S, clock=self.clock)

    def step(self, seconds: float) -> None:
        """Move time on and wait until the loop blocks again having seen it."""
        self.clock.advance(seconds)
        self.clock.settle()

    def deliver(self, frame_id: int, t: float | None = None) -> None:
        self.camera.deliver(frame_id, t)
        self.clock.settle()


@pytest.fixture
def loop() -> Iterator[Loop]:
    loop = Loop()
    loop.acquisition.start()
    loop.clock.settle()
    yield loop
    stop_worker(loop.acquisition, loop.clock)


def test_a_camera_silent_for_longer_than_fault_after_s_is_a_fault_and_a_frame_clears_it(loop: Loop) -> None:
    assert READ_TIMEOUT_S == 0.25
    for _ in range(4):  # 1.0 s of silence: not yet longer than camera_fault_after_s
        loop.step(READ_TIMEOUT_S)
    assert loop.faults.now == {}
    assert loop.acquisition.seconds_since_frame() == 1.0
    loop.step(READ_TIMEOUT_S)
    assert loop.faults.now == {"camera": "no frame for 1.2 s"}  # 1.25 s, one decimal
    loop.deliver(1)
    assert loop.faults.now == {}
    assert loop.acquisition.stats.frames == 1 and loop.acquisition.seconds_since_frame() == 0.0


def test_the_frame_rate_is_the_exposures_rate_and_zero_once_the_newest_is_stale(loop: Loop) -> None:
    start = loop.clock.now()
    for k in range(11):  # 11 exposures 1/16 s apart: 16 Hz, whenever the loop happens to get them
        loop.deliver(k + 1, t=start + k / 16)
    loop.step(10 / 16)
    assert loop.acquisition.frame_rate_hz(stale_after_s=1.0) == 16.0
    loop.step(1.0)  # the newest exposure is now 1 s old: not older than stale_after_s
    assert loop.acquisition.frame_rate_hz(stale_after_s=1.0) == 16.0
    loop.step(1 / 16)
    assert loop.acquisition.frame_rate_hz(stale_after_s=1.0) == 0.0


def test_gaps_in_the_cameras_frame_ids_are_counted_as_dropped(loop: Loop) -> None:
    for frame_id in (7, 8, 9, 12, 13, 20):
        loop.deliver(frame_id)
    assert loop.acquisition.stats.frames == 6
    assert loop.acquisition.stats.dropped == 2 + 6


def test_a_camera_error_closes_the_camera_and_reopens_it_after_reopen_interval_s(loop: Loop) -> None:
    loop.camera.fail_reads = 1
    loop.step(READ_TIMEOUT_S)  # the read in progress times out; the next one fails
    assert loop.faults.now == {"camera": "camera error: cable pulled"}
    assert not loop.camera.is_open and loop.camera.opens == 1
    loop.step(0.375)
    assert not loop.camera.is_open, "0.375 s into a 0.5 s pause"
    loop.step(0.125)
    assert loop.camera.is_open and loop.camera.opens == 2
    assert loop.acquisition.stats.camera_reopens == 1 and loop.acquisition.stats.camera_errors == 1
    loop.deliver(1)
    assert loop.faults.now == {}
