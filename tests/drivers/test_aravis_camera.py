"""What only the Aravis driver has, against Aravis's in-process fake ``Fake_1``: lazy ``gi``,
16-bit frame-id wrap, newest-only skipping, software trigger, Mono16, gain. The camera contract
(timestamps, exposure, ROI, timeouts, reopen; also the GigE Vision fake on loopback) is in
test_camera_contract.py. They skip only where PyGObject is absent; CI installs it (.ci/run,
Makefile's aravis extra), so there they run.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from graytrack.drivers.camera import aravis as aravis_driver
from graytrack.drivers.camera.aravis import AravisCamera, frames_between
from graytrack.drivers.camera.base import CameraNotFound, CameraSettings, CameraUnavailable, Roi


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


def test_with_no_lag_budget_a_late_read_skips_to_the_newest_and_counts_the_rest_as_dropped() -> None:
    settings = CameraSettings(frame_rate_hz=200.0, roi=Roi(row=0, rows=1, col=0, cols=64), max_lag_s=0.0)
    with AravisCamera("Fake_1", settings, n_buffers=32) as camera:
        first = camera.read(1.0)
        time.sleep(0.2)  # ~40 frames arrive; the pool holds up to 32 of them
        asked = time.monotonic()
        fresh = camera.read(1.0)
    assert frames_between(first.frame_id, fresh.frame_id) >= 20
    assert camera.stats.dropped >= 20
    # When the read was asked for, the oldest queued frame was over 150 ms old and the newest a frame period;
    # the frame handed out is at least as new as the newest then (measured from the asking, not from the
    # return: a loaded scheduler may hold the test's thread after the read as long as it likes).
    assert asked - fresh.t_host < 0.1, "the handed-out frame is the newest, not the oldest queued"


def test_software_trigger_produces_one_frame_per_read_and_mono16_is_uint16() -> None:
    settings = CameraSettings(roi=Roi(row=5, rows=2, col=0, cols=32))
    with AravisCamera("Fake_1", settings, trigger="software", pixel_format="Mono16") as camera:
        frames = [camera.read(1.0) for _ in range(3)]
        assert camera.bit_depth == 16  # (its readout's ceiling, stated in recordings)
    assert [f.pixels.dtype for f in frames] == [np.dtype(np.uint16)] * 3
    assert all(f.pixels.shape == (2, 32) for f in frames)
    assert len({f.frame_id for f in frames}) == 3


def test_gain_is_applied_and_a_missing_camera_is_not_found() -> None:
    """ROI, exposure, timestamps, timeouts: the camera contract suite (test_camera_contract.py)."""
    with AravisCamera("Fake_1", CameraSettings(roi=Roi(row=3, rows=2, col=4, cols=10))) as camera:
        plain = camera.read(1.0).pixels
        camera.set_gain(2.0)  # the fake sensor scales its ramp with gain
        assert camera._camera.get_gain() == pytest.approx(2.0)
        assert camera.read(1.0).pixels.mean() > 1.5 * plain.mean()
    with pytest.raises(CameraNotFound):
        AravisCamera("No-Such-Camera-42").open()
