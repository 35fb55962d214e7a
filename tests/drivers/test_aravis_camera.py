"""The Aravis driver against Aravis's own fake cameras: the in-process ``Fake_1`` and the GigE
Vision fake (``arv-fake-gv-camera-0.8``) on loopback. They skip only where PyGObject is absent;
CI installs it (.ci/run, Makefile's aravis extra), so there they run.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest

from graytrack.drivers.camera import aravis as aravis_driver
from graytrack.drivers.camera.aravis import AravisCamera, frames_between
from graytrack.drivers.camera.base import CameraNotFound, CameraSettingError, CameraSettings, CameraUnavailable, Roi


def test_importing_the_driver_does_not_import_gi() -> None:
    code = "import sys, graytrack.drivers.camera.aravis, graytrack.drivers.camera; assert 'gi' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=30)


def test_missing_pygobject_is_a_clear_camera_unavailable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(aravis_driver, "_aravis_module", None)
    monkeypatch.setitem(sys.modules, "gi", None)  # what Python does for a module that is not installed
    with pytest.raises(CameraUnavailable, match="gir1.2-aravis-0.8"):
        AravisCamera("Fake_1").open()


def test_frame_id_gaps_count_drops_across_the_16_bit_wrap() -> None:
    assert frames_between(None, 7) == 0
    assert frames_between(7, 8) == 0
    assert frames_between(7, 10) == 2
    assert frames_between(65534, 2) == 2  # 65535, 1 (GVSP skips 0)
    assert frames_between(65535, 1) == 0


gi = pytest.importorskip("gi")


def assert_fake_pattern(pixels: np.ndarray) -> None:
    """Aravis's fake sensor draws a diagonal ramp: +1 per column and per row, wrapping at 255."""
    rows, cols = pixels.shape
    ramp = (np.arange(rows)[:, None] + np.arange(cols)[None, :]) % 255
    assert np.array_equal((pixels.astype(int) - int(pixels[0, 0])) % 255, ramp)


def test_fake_camera_free_run_delivers_roi_strips_with_ids_and_timestamps() -> None:
    settings = CameraSettings(exposure_us=10000.0, frame_rate_hz=200.0, roi=Roi(row=100, rows=4, col=13, cols=200))
    with AravisCamera("Fake_1", settings, n_buffers=8, latest_only=False) as camera:
        assert camera._camera.get_exposure_time() == pytest.approx(10000.0)
        frames = [camera.read(1.0) for _ in range(8)]
        now = time.monotonic()
    for frame in frames:
        assert frame.pixels.shape == (4, 200) and frame.pixels.dtype == np.uint8
        assert_fake_pattern(frame.pixels)
    ids = [f.frame_id for f in frames]
    assert all(b > a for a, b in zip(ids, ids[1:])) or 1 in ids  # increasing unless the 16-bit id wrapped
    spacing = np.diff([f.t_device for f in frames])
    # The fake camera's frame thread is paced by the host scheduler: single intervals jitter under
    # load (the suite runs in parallel), their median does not.
    assert (spacing > 0).all() and np.median(spacing) == pytest.approx(1 / 200.0, rel=0.3), spacing
    assert all(now - 2.0 < f.t_host <= now for f in frames)
    assert camera.stats.delivered == 8 and camera.stats.incomplete == 0 and camera.stats.timeouts == 0


def test_latest_only_skips_the_backlog_and_counts_it_as_dropped() -> None:
    settings = CameraSettings(frame_rate_hz=200.0, roi=Roi(row=0, rows=1, col=0, cols=64))
    with AravisCamera("Fake_1", settings, n_buffers=32) as camera:
        first = camera.read(1.0)
        time.sleep(0.2)  # ~40 frames arrive; the pool holds up to 32 of them
        fresh = camera.read(1.0)
        received = time.monotonic()
    assert frames_between(first.frame_id, fresh.frame_id) >= 20
    assert camera.stats.dropped >= 20
    # The oldest queued frame would be over 150 ms old; the newest is a few ms old plus whatever
    # the scheduler adds under the parallel suite's load.
    assert received - fresh.t_host < 0.1, "the handed-out frame is the newest, not the oldest queued"


def test_software_trigger_produces_one_frame_per_read_and_mono16_is_uint16() -> None:
    settings = CameraSettings(roi=Roi(row=5, rows=2, col=0, cols=32))
    with AravisCamera("Fake_1", settings, trigger="software", pixel_format="Mono16") as camera:
        frames = [camera.read(1.0) for _ in range(3)]
    assert [f.pixels.dtype for f in frames] == [np.dtype(np.uint16)] * 3
    assert all(f.pixels.shape == (2, 32) for f in frames)
    assert len({f.frame_id for f in frames}) == 3


def test_settings_the_camera_cannot_have_are_refused_clearly() -> None:
    with pytest.raises(CameraSettingError, match="does not fit"):
        AravisCamera("Fake_1", CameraSettings(roi=Roi(row=2047, rows=4))).open()
    with AravisCamera("Fake_1") as camera:
        with pytest.raises(CameraSettingError):
            camera.set_exposure(-5.0)
        camera.set_roi(Roi(row=3, rows=2, col=4, cols=10))
        plain = camera.read(1.0).pixels
        assert plain.shape == (2, 10)
        camera.set_gain(2.0)  # the fake sensor scales its ramp with gain
        assert camera._camera.get_gain() == pytest.approx(2.0)
        assert camera.read(1.0).pixels.mean() > 1.5 * plain.mean()
    with pytest.raises(CameraNotFound):
        AravisCamera("No-Such-Camera-42").open()


@pytest.fixture
def gige_fake() -> Iterator[str]:
    binary = shutil.which("arv-fake-gv-camera-0.8")
    if binary is None:
        pytest.fail("arv-fake-gv-camera-0.8 missing: install aravis-tools (see .ci/run)")
    process = subprocess.Popen([binary, "-i", "127.0.0.1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield "127.0.0.1"
    finally:
        process.terminate()
        process.wait(timeout=5)


def test_gige_vision_fake_camera_on_loopback(gige_fake: str) -> None:
    camera = AravisCamera(gige_fake, CameraSettings(frame_rate_hz=100.0, roi=Roi(row=10, rows=2, col=0, cols=256)))
    deadline = time.monotonic() + 3.0
    while True:  # the fake device needs a moment before it answers GVCP
        try:
            camera.open()
            break
        except CameraNotFound:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    try:
        assert camera._camera.is_gv_device()
        frames = [camera.read(2.0) for _ in range(5)]
    finally:
        camera.close()
    for frame in frames:
        assert frame.pixels.shape == (2, 256)
        assert_fake_pattern(frame.pixels)
    assert camera.stats.delivered == 5 and camera.stats.incomplete == 0
