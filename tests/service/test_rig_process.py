"""The daemon on the virtual rig in its own process ([camera] rig_process, drivers/sim/process.py):
it tracks and streams as with the rig in process, the child ends with the daemon, and a child that
dies is a camera fault naming how it died, with the daemon still serving."""

from __future__ import annotations

import json
import os
import signal

import pytest
from websockets.sync.client import connect

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings, wait_for


def test_the_daemon_tracks_with_the_rig_apart_and_a_dead_rig_is_a_camera_fault(tmp_path) -> None:
    settings = fast_settings(tmp_path / "data", {"camera": {"rig_process": True}})
    with LiveServer(create_app(settings)) as daemon:
        daemon.wait_state("tracking", 60.0)  # calibrated on frames from the child, then tracking them
        rig_process = daemon.rig.hardware.controller.process
        child = rig_process.process
        assert child.poll() is None and child.pid != os.getpid()
        with connect(f"ws://127.0.0.1:{daemon.port}/ws/position", open_timeout=5) as ws:
            messages = [json.loads(ws.recv(timeout=5)) for _ in range(20)]
        assert [m["seq"] for m in messages] == list(range(messages[0]["seq"], messages[0]["seq"] + 20))
        assert all(m["x_mm"] is not None for m in messages)

        os.kill(child.pid, signal.SIGKILL)
        status = daemon.wait_state("fault", 20.0)
        wait_for(lambda: "killed by SIGKILL" in daemon.status()["faults"].get("camera", ""), 10.0,
                 "the camera fault to name the rig process's death", show=lambda: daemon.status()["faults"])
        assert "virtual rig's process" in daemon.status()["faults"]["camera"]
        assert daemon.get("/api/status").status_code == 200, "the daemon keeps serving"
        assert daemon.get("/metrics").status_code == 200
        assert status["state"] == "fault"
    assert child.poll() is not None


def test_the_rig_process_ends_with_the_daemon(tmp_path) -> None:
    settings = fast_settings(tmp_path / "data", {"camera": {"rig_process": True}}, auto_calibrate="never")
    with LiveServer(create_app(settings)) as daemon:
        wait_for(lambda: daemon.rig.hardware is not None, 60.0, "the hardware to open")
        child = daemon.rig.hardware.controller.process.process
        daemon.wait_state("idle", 30.0)
        assert child.poll() is None
    assert child.wait(5.0) == 0, "stopped by closing its socket, not killed"


@pytest.mark.parametrize("rig_process", [False, True])
def test_the_config_key_selects_where_the_rig_runs(tmp_path, rig_process: bool) -> None:
    from graytrack.drivers.factory import open_hardware

    settings = fast_settings(tmp_path / "data", {"camera": {"rig_process": rig_process}})
    hardware = open_hardware(settings.hardware)
    try:
        assert (getattr(hardware.camera, "source", None) is not None) == rig_process
        assert hardware.camera.read(5.0).pixels.shape[-1] == 100
    finally:
        hardware.close()
