"""The OpenCV camera on a lossless video file the test writes with OpenCV itself."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from graytrack.drivers.camera.base import (
    CameraEndOfStream,
    CameraNotFound,
    CameraSettingError,
    CameraSettings,
    Roi,
)
from graytrack.drivers.camera.opencv import OpenCVCamera
from tests.drivers.videos import write_video

N_FRAMES, WIDTH, HEIGHT, FPS = 24, 96, 20, 25.0


def bgr_frame(index: int) -> np.ndarray:
    """Blue steps with the frame index, green ramps along x, red ramps along y: every pixel distinct."""
    blue = np.full((HEIGHT, WIDTH), 10 * index, np.uint8)
    green = np.tile((np.arange(WIDTH) * 2).astype(np.uint8), (HEIGHT, 1))
    red = np.tile((np.arange(HEIGHT) * 9).astype(np.uint8)[:, None], (1, WIDTH))
    return np.dstack([blue, green, red])


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_video(tmp_path_factory.mktemp("video") / "strip.mkv", map(bgr_frame, range(N_FRAMES)), FPS)


def expected_gray(index: int) -> np.ndarray:
    b, g, r = (bgr_frame(index)[..., k].astype(float) for k in range(3))
    return 0.114 * b + 0.587 * g + 0.299 * r


def test_file_frames_come_in_order_as_mono_roi_strips_with_ids_and_media_time(video: Path) -> None:
    roi = Roi(row=5, rows=3, col=10, cols=64)
    with OpenCVCamera(str(video), CameraSettings(roi=roi)) as camera:
        assert camera.bit_depth is None  # (before a frame: not known)
        frames = list(camera.frames())
        assert camera.bit_depth == 8  # its readout's ceiling, 255, stated in recordings
    assert [f.frame_id for f in frames] == list(range(N_FRAMES))
    assert [f.t_device for f in frames] == pytest.approx([i / FPS for i in range(N_FRAMES)])
    for frame in frames:
        assert frame.pixels.shape == (3, 64) and frame.pixels.dtype == np.uint8
        want = expected_gray(frame.frame_id)[5:8, 10:74]
        assert np.abs(frame.pixels.astype(float) - want).max() <= 1.0
    assert camera.stats.delivered == N_FRAMES and camera.stats.dropped == 0
    hosts = [f.t_host for f in frames]
    assert hosts == sorted(hosts)


def test_live_source_with_no_lag_budget_hands_out_the_newest_frame(video: Path) -> None:
    """Treated as live, the file plays at full speed; by the time we read, only the newest is left."""
    camera = OpenCVCamera(str(video), CameraSettings(max_lag_s=0.0), live=True)
    with camera:
        deadline = time.monotonic() + 2.0
        while not camera.source_ended and time.monotonic() < deadline:
            time.sleep(0.005)
        assert camera.source_ended
        newest = camera.read(timeout_s=0.5)
        assert newest.frame_id == N_FRAMES - 1
        assert camera.stats.dropped == N_FRAMES - 1
        assert newest.pixels.shape == (1, WIDTH), "default ROI: the first row, full width"
        assert np.abs(newest.pixels.astype(float) - expected_gray(N_FRAMES - 1)[:1]).max() <= 1.0
        with pytest.raises(CameraEndOfStream):
            camera.read(timeout_s=0.2)


def test_callback_delivery_gets_every_file_frame(video: Path) -> None:
    received: list[int] = []
    with OpenCVCamera(str(video)) as camera:
        runner = camera.start_callback(lambda frame: received.append(frame.frame_id))
        deadline = time.monotonic() + 2.0
        while runner.running and time.monotonic() < deadline:
            time.sleep(0.005)
        runner.stop()
    assert runner.error is None
    assert received == list(range(N_FRAMES))


def test_a_missing_file_is_not_found_and_a_video_file_has_no_exposure(video: Path, tmp_path: Path) -> None:
    """ROI, exposure, timestamps, timeouts of a live-played file: the camera contract suite."""
    with pytest.raises(CameraNotFound):
        OpenCVCamera(str(tmp_path / "nope.mkv")).open()
    with OpenCVCamera(str(video)) as camera:
        frame = camera.read()
    # No exposure known: 0, and the stated uncertainty widens to 1.5 frame periods.
    assert frame.exposure_s == 0.0 and frame.t_uncertainty_s == pytest.approx(1.5 / FPS)
    with pytest.raises(CameraSettingError):
        Roi(rows=0)


def test_readout_and_exposure_move_the_stamp_back_from_the_grab(video: Path) -> None:
    from graytrack.drivers.config import parse_hardware
    from graytrack.drivers.factory import make_real_camera

    config = parse_hardware({"camera": {"kind": "opencv", "device": str(video), "readout_us": 4000.0}})
    camera = make_real_camera(config.camera)
    assert isinstance(camera, OpenCVCamera) and camera.readout_s == pytest.approx(0.004)
    camera.nominal_exposure_s = 0.01
    with camera:
        before = time.monotonic()
        frame = camera.read()
        after = time.monotonic()
    # grab time lies in [before, after]; mid-exposure is 4 ms of readout and 5 ms of exposure earlier
    assert before - 0.009 <= frame.t_host <= after - 0.009
    assert frame.exposure_s == 0.01 and frame.t_uncertainty_s == pytest.approx(1 / FPS)
