"""Devices and parts on a ManualClock, for the daemon's loops tested without the wall clock.

Each fake blocks only through the clock (a camera read waits on ``clock.get``), so a test moves
time with ``clock.advance``, hands over frames with ``camera.deliver`` and, after
``clock.settle()``, sees everything the loop did with them.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any

import numpy as np

from graytrack.drivers.camera.base import Camera, CameraError, CameraTimeout, Frame
from graytrack.drivers.stage.base import PositionReading
from graytrack.service.daemon.jobs import CalibrationJob
from graytrack.service.daemon.manual_clock import ManualClock
from graytrack.service.daemon.worker import Worker

STOP_ADVANCE_S = 0.25  # a worker blocked in a read or a pause is released by moving time this far


class ClockCamera(Camera):
    """Frames only when the test delivers them; a read with none waits on the clock and times out.
    ``fail_reads = n`` makes the next n reads fail as a pulled cable does."""

    def __init__(self, clock: ManualClock, width: int = 8) -> None:
        super().__init__()
        self.clock = clock
        self.width = width
        self.fail_reads = 0
        self.opens = 0
        self._frames: queue.Queue[Frame] = queue.Queue()

    def deliver(self, frame_id: int, t: float | None = None, exposure_s: float = 0.0,
                pixels: np.ndarray | None = None) -> Frame:
        """A frame exposed (mid-exposure) at ``t``, now by default, and wake the reader."""
        image = np.zeros((1, self.width)) if pixels is None else pixels
        frame = Frame(image, frame_id, self.clock.now() if t is None else t, exposure_s=exposure_s)
        self.clock.put(self._frames, frame)
        return frame

    def _open_device(self) -> None:
        self.opens += 1

    def _close_device(self) -> None:
        pass

    def _apply_settings(self) -> None:
        pass

    def _read(self, timeout_s: float) -> Frame:
        if self.fail_reads > 0:
            self.fail_reads -= 1
            raise CameraError("cable pulled")
        try:
            return self.clock.get(self._frames, timeout_s)
        except queue.Empty:
            raise CameraTimeout(f"no frame within {timeout_s:g} s") from None


class FaultTable:
    """The ``faults(source, reason)`` callback of a worker, keeping the faults standing now."""

    def __init__(self) -> None:
        self.now: dict[str, str] = {}

    def __call__(self, source: str, reason: str | None) -> None:
        if reason is None:
            self.now.pop(source, None)
        else:
            self.now[source] = reason


def stop_worker(worker: Worker, clock: ManualClock, most: int = 100) -> None:
    """Stop ``worker`` while it may be blocked on ``clock``: ask, then move time until it has ended."""
    stopper = threading.Thread(target=worker.stop)
    stopper.start()
    for _ in range(most):
        if not worker.alive:
            break
        clock.advance(STOP_ADVANCE_S)
        stopper.join(0.01)
    stopper.join(5.0)
    assert not worker.alive, f"{worker.name} did not stop"


class FakeStage:
    """An axis that settles at once (or never arrives, ``arrives = False``, or no longer from move number
    ``arrives_moves + 1`` on), stamping on the clock; ``intruder_mm`` makes the next move land there instead,
    as if another command had replaced it."""

    def __init__(self, clock: ManualClock, limits: tuple[float, float] = (0.0, 10.0), velocity_mm_s: float = 20.0,
                 arrives: bool = True) -> None:
        self.clock = clock
        self._limits = limits
        self._velocity = velocity_mm_s
        self.arrives = arrives
        self.at_mm = limits[0]
        self.arrives_moves: int | None = None
        self.intruder_mm: float | None = None
        self.moves: list[float] = []
        self.velocities: list[float] = []

    def limits(self) -> tuple[float, float]:
        return self._limits

    def velocity(self) -> float:
        return self._velocity

    def set_velocity(self, velocity_mm_s: float) -> None:
        self._velocity = velocity_mm_s
        self.velocities.append(velocity_mm_s)

    def move_to(self, target_mm: float) -> None:
        self.moves.append(target_mm)
        if self.arrives_moves is not None and len(self.moves) > self.arrives_moves:
            self.arrives = False
        if self.arrives:
            self.at_mm = target_mm if self.intruder_mm is None else self.intruder_mm
            self.intruder_mm = None

    def on_target(self) -> bool:
        return self.arrives

    def wait_on_target(self, timeout_s: float) -> PositionReading:
        return self.position()

    def position(self) -> PositionReading:
        return PositionReading(self.at_mm, self.clock.now(), 0.0)


class FakeFeed:
    """The frame loop as the sweep sees it: subscriptions, the grating readings, a frame rate."""

    def __init__(self, readings: Any, frame_rate_hz: float) -> None:
        self.readings = readings
        self.rate_hz = frame_rate_hz
        self.feeds: list[queue.Queue[Any]] = []

    def subscribe(self, maxsize: int = 1000) -> "queue.Queue[Any]":
        feed: queue.Queue[Any] = queue.Queue(maxsize)
        self.feeds.append(feed)
        return feed

    def unsubscribe(self, feed: "queue.Queue[Any]") -> None:
        self.feeds.remove(feed)

    def frame_rate_hz(self, stale_after_s: float) -> float:
        return self.rate_hz


class StatusFiles:
    """The storage a job and a sweep write to: every status document kept in order, folders in ``root``."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.documents: list[dict[str, Any]] = []

    def write_status(self, calibration_id: str, document: dict[str, Any]) -> None:
        self.documents.append(dict(document))

    def calibration_dir(self, calibration_id: str) -> Path:
        folder = self.root / calibration_id
        folder.mkdir(parents=True, exist_ok=True)
        return folder


def new_job(positions: int = 2, frames_per_position: int = 3) -> CalibrationJob:
    return CalibrationJob("20261123T000000000000Z", "paper", positions, frames_per_position)
