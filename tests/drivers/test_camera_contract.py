"""One contract, every camera: the simulated camera on a clock running 5x wall time, OpenCV on a
video file played as a live camera, Aravis's in-process ``Fake_1`` and its GigE Vision fake on
loopback. Each case says only how to build its camera and what it can have; the tests are the
same: mid-exposure timestamps on ``time.monotonic`` (within the stated uncertainty of the
delivery time minus half the exposure), ``exposure_s``, frame ids, the ROI, timeouts,
close and reopen.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from graytrack.drivers.camera.base import (
    Camera,
    CameraError,
    CameraNotFound,
    CameraSettingError,
    CameraSettings,
    CameraTimeout,
    Frame,
    Roi,
)
from graytrack.drivers.camera.opencv import OpenCVCamera
from graytrack.drivers.camera.sim import SimCamera
from graytrack.drivers.clock import ScaledClock
from graytrack.drivers.sim.scenarios import build_rig
from tests.drivers.videos import write_video

SLACK_S = 0.25  # scheduling delay a loaded machine may add between a frame's end and its delivery
N_FRAMES = 8


@dataclass
class Case:
    """How to build one camera and what it can have."""

    build: Callable[[CameraSettings], Camera]
    sensor: tuple[int, int]  # (height, width) of the full image
    rate_hz: float  # a frame rate the camera runs at (set where settable)
    exposure_us: float | None  # an exposure to set; None where exposure cannot be set
    exposure_host_s: float  # the exposure frames then carry, on the host clock
    host_period_s: float  # frame period on the host clock
    check_pixels: Callable[[Frame, Roi], None]

    def settings(self, roi: Roi | None = None) -> CameraSettings:
        return CameraSettings(exposure_us=self.exposure_us, frame_rate_hz=self.rate_hz if self.settable_rate else None,
                              roi=roi or Roi())

    @property
    def settable_rate(self) -> bool:
        return self.exposure_us is not None  # the file stand-in has neither


# -- the cases ---------------------------------------------------------------------------------
SIM_SCALE = 5.0


def sim_case() -> Case:
    rig = build_rig("paper", "rows:n=4", seed=0)
    clock = ScaledClock(SIM_SCALE)
    truth = rig.make_stage(position_mm=1.0, t_s=clock.now())

    def check(frame: Frame, roi: Roi) -> None:
        cols = rig.n_pixels - roi.col if roi.cols is None else roi.cols
        assert frame.pixels.shape == (roi.rows, cols)
        assert frame.t_device is not None and clock.to_host(frame.t_device) == pytest.approx(frame.t_host, abs=1e-9)

    return Case(lambda s: SimCamera(rig, truth, s, clock=clock), (rig.n_rows, rig.n_pixels), 20.0, 2000.0,
                2000e-6 / SIM_SCALE, 1 / (20.0 * SIM_SCALE), check)


# (128 frames, 5 s: a late reader's test may read its first frames again after a stall of the machine)
VIDEO_FRAMES, VIDEO_W, VIDEO_H, VIDEO_FPS, VIDEO_EXPOSURE_S = 128, 96, 20, 25.0, 0.01


def video_frame(index: int) -> np.ndarray:
    """Gray steps with the frame index, ramps along x and y: every pixel and frame distinct."""
    x, y = np.meshgrid(np.arange(VIDEO_W), np.arange(VIDEO_H))
    return ((2 * x + 3 * y + 5 * index) % 256).astype(np.uint8)


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_video(tmp_path_factory.mktemp("video") / "camera.mkv", map(video_frame, range(VIDEO_FRAMES)),
                       VIDEO_FPS)


def opencv_case(video: Path) -> Case:
    def check(frame: Frame, roi: Roi) -> None:
        cols = VIDEO_W - roi.col if roi.cols is None else roi.cols
        want = video_frame(frame.frame_id)[roi.row : roi.row + roi.rows, roi.col : roi.col + cols]
        assert np.abs(frame.pixels.astype(int) - want).max() <= 1

    def build(settings: CameraSettings) -> Camera:
        return OpenCVCamera(str(video), settings, live=True, realtime=True, exposure_s=VIDEO_EXPOSURE_S)

    return Case(build, (VIDEO_H, VIDEO_W), VIDEO_FPS, None, VIDEO_EXPOSURE_S, 1 / VIDEO_FPS, check)


def fake_pattern(frame: Frame, roi: Roi) -> None:
    """Aravis's fake sensor draws a diagonal ramp: +1 per column and per row, wrapping at 255."""
    rows, cols = frame.pixels.shape
    assert rows == roi.rows and (roi.cols is None or cols == roi.cols)
    ramp = (np.arange(rows)[:, None] + np.arange(cols)[None, :]) % 255
    assert np.array_equal((frame.pixels.astype(int) - int(frame.pixels[0, 0])) % 255, ramp)


def aravis_case(device: str) -> Case:
    pytest.importorskip("gi")
    from graytrack.drivers.camera.aravis import AravisCamera

    def build(settings: CameraSettings) -> Camera:
        return AravisCamera(device, settings, n_buffers=8)

    return Case(build, (2048, 2048), 20.0, 10000.0, 10000e-6,
                1 / 20.0, fake_pattern)


@pytest.fixture(scope="module")
def gige_fake() -> Iterator[str]:
    """``arv-fake-gv-camera-0.8`` on loopback, for the module; stopped by its pid."""
    pytest.importorskip("gi")
    binary = shutil.which("arv-fake-gv-camera-0.8")
    if binary is None:
        pytest.fail("arv-fake-gv-camera-0.8 missing: install aravis-tools (see .ci/run)")
    process = subprocess.Popen([binary, "-i", "127.0.0.1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield "127.0.0.1"
    finally:
        process.terminate()
        process.wait(timeout=5)


# The GigE Vision fake answers on 127.0.0.1's GVCP port and lets one application control it; run
# beside the parallel suite it missed control packets for seconds (write_register timeout). Its
# cases are marked `alone`: make test runs them after the parallel suite, by themselves.
@pytest.fixture(params=["sim", "opencv-file", "aravis-fake", pytest.param("aravis-gige", marks=pytest.mark.alone)])
def case(request: pytest.FixtureRequest, video: Path) -> Case:
    if request.param == "sim":
        return sim_case()
    if request.param == "opencv-file":
        return opencv_case(video)
    if request.param == "aravis-fake":
        return aravis_case("Fake_1")
    return aravis_case(request.getfixturevalue("gige_fake"))


def opened(case: Case, settings: CameraSettings) -> Camera:
    """Open, retrying briefly: the GigE fake needs a moment before it answers GVCP."""
    camera = case.build(settings)
    deadline = time.monotonic() + 3.0
    while True:
        try:
            camera.open()
            return camera
        except CameraNotFound:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def timed_reads(camera: Camera, n: int) -> list[tuple[float, Frame, float]]:
    reads = []
    for _ in range(n):
        before = time.monotonic()
        frame = camera.read(2.0)
        reads.append((before, frame, time.monotonic()))
    return reads


# -- the contract ------------------------------------------------------------------------------
def test_frames_are_stamped_mid_exposure_on_the_host_monotonic_clock(case: Case) -> None:
    roi = Roi(row=2, rows=2, col=3, cols=40)
    camera = opened(case, case.settings(roi))
    try:
        reads = timed_reads(camera, N_FRAMES)
    finally:
        camera.close()
    frames = [frame for _, frame, _ in reads]
    for before, frame, after in reads:
        case.check_pixels(frame, roi)
        assert frame.exposure_s == pytest.approx(case.exposure_host_s, rel=0.02)
        assert 0 <= frame.t_uncertainty_s < 1.0, "stated, finite and sane"
        # The exposure ended before the frame was handed out, and not long before the read began
        # (a frame older than a period would be a stale, queued one).
        lag = after - frame.exposure_end
        assert lag >= -frame.t_uncertainty_s, f"stamped {-lag * 1e3:.2f} ms after its own delivery"
        assert frame.exposure_end >= before - case.host_period_s - SLACK_S - frame.t_uncertainty_s
    assert all(b.t_host > a.t_host for a, b in zip(frames, frames[1:]))
    assert all(b.frame_id > a.frame_id for a, b in zip(frames, frames[1:]))
    spacing = np.diff([f.t_host for f in frames]) / case.host_period_s
    assert np.all(np.abs(spacing - np.round(spacing)) < 0.5) and np.median(spacing) == pytest.approx(1, abs=0.5)
    assert camera.stats.delivered == N_FRAMES and camera.stats.timeouts == 0


def test_exposure_is_set_and_carried_or_refused(case: Case) -> None:
    camera = opened(case, case.settings())
    try:
        if case.exposure_us is None:
            with pytest.raises(CameraSettingError):
                camera.set_exposure(500.0)
            assert camera.read(2.0).exposure_s == pytest.approx(case.exposure_host_s)
            return
        camera.set_exposure(case.exposure_us / 2)
        frame = camera.read(2.0)
        assert frame.exposure_s == pytest.approx(case.exposure_host_s / 2, rel=0.02)
        with pytest.raises(CameraSettingError):
            camera.set_exposure(-1.0)
        assert camera.read(2.0).exposure_s == pytest.approx(case.exposure_host_s / 2, rel=0.02), "refusal kept it"
    finally:
        camera.close()


def test_roi_is_applied_and_one_that_does_not_fit_is_refused_keeping_the_old(case: Case) -> None:
    height, width = case.sensor
    camera = opened(case, case.settings())
    try:
        assert camera.read(2.0).pixels.shape == (1, width), "default ROI: the first row, full width"
        strip = Roi(row=height // 100, rows=2, col=width // 100, cols=30)
        camera.set_roi(strip)
        case.check_pixels(camera.read(2.0), strip)
        with pytest.raises(CameraSettingError, match="does not fit"):
            camera.set_roi(Roi(row=height - 1, rows=2))
        assert camera.settings.roi == strip
        assert camera.read(2.0).pixels.shape == (2, 30)
    finally:
        camera.close()
    with pytest.raises(CameraSettingError):
        opened(case, case.settings(Roi(col=width - 1, cols=2)))


def test_no_frame_within_the_timeout_raises_camera_timeout(case: Case) -> None:
    camera = opened(case, case.settings())
    try:
        camera.read(2.0)
        # Right after a frame, the next is most of a period away. On a loaded machine the frame
        # just read may itself have come late, with the next one close behind: try again then.
        for _ in range(5):
            start = time.monotonic()
            try:
                camera.read(case.host_period_s / 8)
            except CameraTimeout:
                break
        else:
            pytest.fail("five reads with an eighth of a period to wait all got a frame")
        assert time.monotonic() - start < case.host_period_s / 8 + SLACK_S
        assert camera.stats.timeouts == 1
        camera.read(2.0)  # and frames keep coming
    finally:
        camera.close()


def test_close_then_reopen_delivers_fresh_frames(case: Case) -> None:
    camera = opened(case, case.settings())
    first = camera.read(2.0)
    camera.close()
    camera.close()  # twice is harmless
    assert not camera.is_open
    with pytest.raises(CameraError, match="not open"):
        camera.read(0.1)
    camera.open()
    try:
        before = time.monotonic()
        again = camera.read(6.0)  # the GigE fake at times takes a few seconds to stream again
        assert again.t_host > first.t_host and again.exposure_end >= before - case.host_period_s - SLACK_S
        assert camera.stats.delivered == 1, "statistics restart with the session"
    finally:
        camera.close()


BUDGET_PERIODS = 12  # the lag budget of the next test, in frame periods
CATCH_UP_TRIES = 3  # times the next test lets its reader fall behind within the budget: a loaded machine that
# stalls the reader itself beyond the budget meanwhile voids a try (the policy then rightly skips), not the test


def test_a_late_reader_loses_no_frame_within_the_lag_budget_and_skips_beyond_it(case: Case) -> None:
    """The read policy (backlog.py): frames taken while the reader was late come in order, none
    lost; a reader later than the budget skips the frames delivered before it (counted as
    dropped; a camera's own pool may have lost more meanwhile) and is current again at once."""
    period = case.host_period_s
    settings = case.settings()
    settings.max_lag_s = BUDGET_PERIODS * period
    camera = opened(case, settings)
    try:
        for tried in range(CATCH_UP_TRIES):
            first = camera.read(2.0)
            behind = time.monotonic()
            time.sleep(3 * period)  # about three frames finish while nobody reads
            caught_up = [camera.read(2.0) for _ in range(4)]
            if time.monotonic() - behind < settings.max_lag_s - period:
                break  # (the reader was late by the three periods and the reads' own time: within the budget)
        else:
            pytest.fail(f"the machine stalled the reader beyond the budget in each of {CATCH_UP_TRIES} tries")
        ids = [first.frame_id] + [f.frame_id for f in caught_up]
        assert np.all(np.diff(ids) == 1), f"frames lost while the reader was late: ids {ids}"
        dropped = camera.stats.dropped  # (a try the machine voided may have skipped frames: counted from here)
        assert tried or dropped == 0
        time.sleep(3 * BUDGET_PERIODS * period)  # far beyond the budget
        skipped_to = camera.read(2.0)
        before = time.monotonic()
        current = camera.read(2.0)
    finally:
        camera.close()
    gap = skipped_to.frame_id - caught_up[-1].frame_id - 1
    assert gap >= BUDGET_PERIODS // 2, "the oldest frames beyond the budget were skipped"
    assert camera.stats.dropped - dropped == gap + current.frame_id - skipped_to.frame_id - 1
    assert before - current.exposure_end <= (BUDGET_PERIODS + 1) * period + SLACK_S + current.t_uncertainty_s


def test_flip_reverses_the_pixel_axis_of_every_frame_handed_out(case: Case) -> None:
    """``[camera] flip``: for a camera mounted the other way round, applied once for every driver."""
    roi = Roi(row=1, rows=2, col=2, cols=30)
    settings = case.settings(roi)
    settings.flip = True
    camera = opened(case, settings)
    try:
        frame = camera.read(2.0)
    finally:
        camera.close()
    assert frame.pixels.shape == (2, 30)
    case.check_pixels(dataclasses.replace(frame, pixels=frame.pixels[:, ::-1]), roi)  # as delivered, reversed


def test_a_frame_stays_within_the_readout_the_camera_states(case: Case) -> None:
    """``bit_depth``: what recordings state of the camera's readout, where calibration and tracking set aside the
    samples clipped at 2^bits − 1 (known once a frame is read where the driver learns it from its frames)."""
    camera = opened(case, case.settings(Roi(row=1, rows=2, col=2, cols=30)))
    try:
        frames = [camera.read(2.0) for _ in range(3)]
        bits = camera.bit_depth
    finally:
        camera.close()
    if isinstance(camera, SimCamera):  # the virtual rig's camera: its recordings state the rig's sensor instead
        assert bits is None
        return
    assert bits in (8, 10, 12, 16)
    for frame in frames:
        assert frame.pixels.dtype.kind == "u" and frame.pixels.dtype.itemsize * 8 >= bits
        assert int(frame.pixels.max()) <= 2**bits - 1
