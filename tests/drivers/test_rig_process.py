"""The virtual rig in its own process (drivers/sim/process.py): the same frames as rendered in process,
a stage behind the real driver on its pty, a clean start and stop, and a child that dies or hangs
reported as a camera that fails or stops delivering (never a dead caller)."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator

import numpy as np
import pytest

from graytrack.drivers.camera.base import CameraError, CameraSettings, CameraTimeout, Roi
from graytrack.drivers.camera.sim import SimCamera
from graytrack.drivers.clock import ScaledClock
from graytrack.drivers.sim.frame_render import FrameRenderer
from graytrack.drivers.sim.process import RigProcess, RigProcessDied
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.stage.gcs_stage import GCSStage

EXPOSURE_S = 1e-3


@pytest.fixture
def clock() -> ScaledClock:
    return ScaledClock(5.0)


def _process(rig, clock: ScaledClock) -> Iterator[RigProcess]:
    process = RigProcess(rig, clock).start()
    try:
        yield process
    finally:
        process.stop()


# folded into the matrix / rendered directly / the camera's side, specks landing in the child while its stage rests
@pytest.mark.parametrize("effects", ["rows:n=4,flicker", "glints",
                                     "rows:n=4,window_dust:start_s=0:over_s=0:at_rest=1,veil:start_s=0,vignetting_change"])
def test_frames_are_those_rendered_in_process_draw_for_draw(effects: str) -> None:
    # the child exposes on its own frame clock; each frame it hands over is rendered here again, in order, by
    # the in-process renderer of an identical rig (same seed): bit for bit the same while no frame is lost
    clock = ScaledClock(1.0)
    here, there = build_rig("paper", effects, seed=7), build_rig("paper", effects, seed=7)
    truth = here.make_stage(t_s=clock.now())  # at rest at the stroke's start, as the child's is
    renderer = FrameRenderer(here)
    settings = CameraSettings(frame_rate_hz=50.0, exposure_us=EXPOSURE_S * 1e6, roi=Roi(0, here.n_rows), max_lag_s=1.0)
    for process in _process(there, clock):
        with SimCamera(there, None, settings, clock=clock, source=process) as camera:
            frames = [camera.read(5.0) for _ in range(12)]
    assert [f.frame_id for f in frames] == list(range(frames[0].frame_id, frames[0].frame_id + 12)), "none lost"
    assert frames[0].frame_id == 0, "the first exposure after opening is the first handed out"
    for frame in frames:
        t_mid = frame.t_device
        instants = np.array([t_mid - 0.5 * EXPOSURE_S, t_mid, t_mid + 0.5 * EXPOSURE_S])
        want = renderer.render(truth.position(instants), t_mid, EXPOSURE_S)
        assert frame.pixels.dtype == want.dtype and frame.pixels.shape == want.shape
        assert np.array_equal(frame.pixels, want)
        assert frame.pixels.flags.writeable
        assert clock.to_host(t_mid) == pytest.approx(frame.t_host, abs=1e-9)
    if here.camera_side is not None:  # the window's specks landed on the first frame, in both processes alike
        assert np.all(here.camera_side.landed_s == frames[0].t_device)


def test_the_stage_is_driven_through_its_pty_and_the_frames_follow_it(clock: ScaledClock) -> None:
    rig = build_rig("paper", "", seed=0)
    for process in _process(rig, clock):
        assert process.path is not None and os.path.exists(process.path)
        with GCSStage(process.path, timeout_s=5.0, velocity_mm_s=20.0) as stage, \
                SimCamera(rig, None, CameraSettings(frame_rate_hz=200.0), clock=clock, source=process) as camera:
            assert "simulated" in stage.identify()
            before = camera.read(5.0).pixels.astype(float)
            stage.move_to(0.7)
            assert stage.wait_on_target(5.0).position_mm == pytest.approx(0.7, abs=1e-3)
            arrived = clock.now()
            # (frames exposed before the stage arrived may still wait in the camera's queue on a loaded machine)
            frame = camera.read(5.0)
            for _ in range(400):
                if frame.t_device >= arrived:
                    break
                frame = camera.read(5.0)
            assert frame.t_device >= arrived, "a frame exposed after the stage arrived"
            assert not np.allclose(frame.pixels.astype(float), before, atol=5.0), "the image moved with the stage"
            assert frame.pixels.shape == (rig.n_rows, rig.n_pixels)
            assert clock.to_host(frame.t_device) == pytest.approx(frame.t_host, abs=1e-9)


def test_stop_ends_the_child_by_itself(clock: ScaledClock) -> None:
    process = RigProcess(build_rig("paper", "", seed=0), clock).start()
    child = process.process
    assert child is not None and process.alive
    process.stop()
    assert child.returncode == 0, "the child ended on its socket's EOF, not killed"
    assert not process.alive
    with pytest.raises(RigProcessDied, match="stopped|exited"):
        process.next_frame(1.0)
    process.stop()  # twice: harmless


def test_a_child_that_dies_is_a_camera_error_naming_it_and_the_camera_cannot_reopen(clock: ScaledClock) -> None:
    rig = build_rig("paper", "", seed=0)
    for process in _process(rig, clock):
        camera = SimCamera(rig, None, CameraSettings(frame_rate_hz=200.0, roi=Roi(0, 1)), clock=clock, source=process)
        with camera:
            camera.read(5.0)
            os.kill(process.pid, signal.SIGKILL)
            process.process.wait(5.0)
            with pytest.raises(CameraError, match="killed by SIGKILL") as died:
                for _ in range(16):  # frames the child had rendered before it died are still delivered (a busy machine)
                    camera.read(5.0)
            assert not isinstance(died.value, CameraTimeout)
        with pytest.raises(CameraError, match="virtual rig's process .*killed by SIGKILL"):
            camera.open()


def test_a_child_that_stops_answering_is_a_camera_timeout_and_it_resumes(clock: ScaledClock) -> None:
    rig = build_rig("paper", "", seed=0)
    for process in _process(rig, clock):
        with SimCamera(rig, None, CameraSettings(frame_rate_hz=200.0), clock=clock, source=process) as camera:
            first = camera.read(5.0)
            os.kill(process.pid, signal.SIGSTOP)
            try:
                with pytest.raises(CameraTimeout, match="no frame from the virtual rig's process"):
                    for _ in range(1000):  # what it sent before it stopped is still handed out
                        camera.read(0.1)
            finally:
                os.kill(process.pid, signal.SIGCONT)
            # exposures resume; the time it stood still is a gap in the frame ids (after the one frame a loaded child
            # may have rendered and not yet sent when it was stopped: frame 1 right after frame 0, under load)
            ids = [first.frame_id] + [camera.read(5.0).frame_id for _ in range(2)]
            assert max(b - a for a, b in zip(ids, ids[1:])) > 1, ids
            assert camera.stats.timeouts == 1
