"""The frame loop's timing decisions on a ManualClock: camera silence, the frame rate, gaps, the reopen pause.

Every figure here is the clock's: the test moves time by the amount it means and then looks, so
the outcome cannot depend on how busy the machine is.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from graytrack.service.daemon import acquisition as acquisition_module
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

    def deliver(self, frame_id: int, t: float | None = None, pixels: np.ndarray | None = None) -> None:
        self.camera.deliver(frame_id, t, pixels=pixels)
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


def _sine_model(dc: float):
    """A small model of the camera's 8 pixels (a frame of it is its prediction)."""
    from graytrack.core.models.fourier import FourierModel

    model = FourierModel(8.0, 0.06, 8)
    coefficients = np.zeros(model.coeff_shape)
    coefficients[0, 0], coefficients[1, 0], coefficients[2, 0] = dc, 80.0, 30.0
    return model.with_changes(coeffs=coefficients, noise_gray=0.7)


def _wait_for(condition, what: str, timeout_s: float = 60.0) -> None:
    """Wait on a thread that computes (a tracker build), not on time: poll until ``condition``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} did not happen within {timeout_s:g} s"
        time.sleep(0.002)


def _held_tracker(held_model, gate: threading.Event) -> type:
    """The real LiveTracker, whose build for ``held_model`` waits for ``gate``: a build that takes
    as long as the test wants."""

    class HeldTracker(acquisition_module.LiveTracker):
        def __init__(self, model, *args, **kwargs):
            if model is held_model:
                assert gate.wait(60.0)
            super().__init__(model, *args, **kwargs)

    return HeldTracker


def test_a_new_model_is_built_off_the_frame_loop_which_tracks_every_frame_meanwhile_and_says_with_which(
        loop: Loop, monkeypatch: pytest.MonkeyPatch) -> None:
    old, new = _sine_model(128.0), _sine_model(120.0)
    gate = threading.Event()  # holds the new model's build: a build that takes as long as the test wants

    monkeypatch.setattr(acquisition_module, "LiveTracker", _held_tracker(new, gate))

    def image(model, frame_id: int) -> np.ndarray:  # the stage 1 µm further each frame (a repeat is no fix)
        return model.predict(np.array([2.0 + 1e-3 * frame_id]))[0].reshape(1, -1)

    acquisition = loop.acquisition
    acquisition.install_model(old, 2.0, calibration="20261124T000001000001Z")
    _wait_for(lambda: acquisition._pending is not None, "the first model's build")
    loop.deliver(1, pixels=image(old, 1))
    assert acquisition.tracker is not None and acquisition.tracker.model is old
    try:
        acquisition.install_model(new, 2.0, calibration="20261124T000002000002Z")
        for frame_id in range(2, 12):  # the new tracker is still being built: the old one tracks every frame
            loop.deliver(frame_id, pixels=image(old, frame_id))
        assert acquisition.stats.tracked == 11 and acquisition.stats.dropped == 0
        assert acquisition.tracker.model is old and len(loop.published) == 11
        assert loop.published[-1]["x_mm"] == pytest.approx(2.011, abs=1e-9)
        # each message names the calibration whose model placed it: the old one until the switch
        assert {message["calibration"] for message in loop.published} == {"20261124T000001000001Z"}
    finally:
        gate.set()
    _wait_for(lambda: acquisition._pending is not None, "the new model's build")
    loop.deliver(12, pixels=image(new, 12))
    assert acquisition.tracker.model is new and acquisition.stats.tracked == 12
    assert loop.published[-1]["x_mm"] == pytest.approx(2.012, abs=1e-9)
    assert loop.published[-1]["calibration"] == "20261124T000002000002Z"
    assert loop.faults.now == {}


def test_a_build_overtaken_by_a_later_install_is_dropped(loop: Loop, monkeypatch: pytest.MonkeyPatch) -> None:
    first, second = _sine_model(128.0), _sine_model(120.0)
    gate = threading.Event()

    monkeypatch.setattr(acquisition_module, "LiveTracker", _held_tracker(first, gate))
    acquisition = loop.acquisition
    acquisition.install_model(first)
    try:
        acquisition.install_model(second)  # asked for later, built first
        _wait_for(lambda: acquisition._pending is not None, "the second model's build")
    finally:
        gate.set()
    _wait_for(lambda: not any(t.name == "tracker-build" for t in threading.enumerate()), "the first build's end")
    loop.deliver(1, pixels=second.predict(np.array([1.0]))[0].reshape(1, -1))
    assert acquisition.tracker.model is second
    loop.deliver(2, pixels=second.predict(np.array([1.0]))[0].reshape(1, -1))
    assert acquisition.tracker.model is second  # the older build, finished last, never replaces it


def test_a_models_grating_skew_is_taken_out_of_the_pairing_while_moving_and_left_in_for_recorders(
        loop: Loop) -> None:
    """A model whose calibration found the grating latched off mid-exposure (``reference_skew_s``,
    the closed loop's reference_timing) is compared with the grating at the exposure, as `graytrack
    track` compares it; the samples handed to subscribers (the sweep's recorder) keep the raw pairing,
    so that the next calibration measures the skew again instead of finding none."""
    skew_s, speed_mm_s = 0.002, 10.0
    model = _sine_model(128.0)
    model = model.with_changes(info={**model.info, "reference_skew_s": skew_s})
    acquisition = loop.acquisition
    recorder = acquisition.subscribe()
    acquisition.install_model(model, 2.0, calibration="20261126T000001000001Z")
    _wait_for(lambda: acquisition._pending is not None, "the model's build")
    for k in range(12):  # the stage at 10 mm/s, each reading stamped t describing it at t + skew
        t = 0.005 * k
        acquisition.readings.append(t, 2.0 + speed_mm_s * (t + skew_s), latency_s=1e-5)
    exposed = [0.0126, 0.0313, 0.0472]
    for frame_id, t in enumerate(exposed, start=1):
        loop.deliver(frame_id, t=t, pixels=model.predict(np.array([2.0 + speed_mm_s * t]))[0].reshape(1, -1))
    assert len(loop.published) == len(exposed)
    for message, t in zip(loop.published, exposed):
        assert message["reference_mm"] == pytest.approx(2.0 + speed_mm_s * t, abs=1e-9)
        assert abs(message["error_um"]) < 1e-3  # 20 µm (v · skew) with the raw pairing
    raw = [recorder.get_nowait().reference_mm for _ in exposed]
    assert raw == pytest.approx([2.0 + speed_mm_s * (t + skew_s) for t in exposed], abs=1e-9)
