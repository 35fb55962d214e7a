"""Faults: the daemon reports them as state "fault" with a reason, keeps serving, and recovers."""

from __future__ import annotations

from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.service.helpers import GatedFactory, fast_settings, wait_for, wait_state


def test_camera_silence_and_camera_errors_are_faults_that_clear(tmp_path, calibrated) -> None:
    factory = GatedFactory()
    with TestClient(create_app(fast_settings(calibrated(tmp_path)), factory)) as client:
        wait_state(client, "tracking", 20.0)
        camera = factory.hardware.camera

        camera.gate_open = False  # frames stop coming
        status = wait_state(client, "fault")
        assert status["reason"].startswith("camera: no frame for")
        wait_for(lambda: client.get("/api/status").json()["position_mm"] is None, what="the stale position withdrawn")
        health = client.get("/healthz")
        assert health.status_code == 503 and health.json()["ok"] is False
        assert health.json()["reason"].startswith("camera: no frame for")
        auth = {"Authorization": f"Bearer {client.app.state.storage.token_path.read_text().strip()}"}
        refused = client.post("/api/calibration", headers=auth)
        assert refused.status_code == 503 and "fault" in refused.json()["error"]
        camera.gate_open = True
        assert wait_state(client, "tracking")["reason"] is None

        opens = camera.opens
        camera.fail_reads = 1  # a hard error: the loop closes and reopens the camera
        wait_for(lambda: camera.opens > opens, what="the camera to be reopened")
        status = wait_state(client, "tracking")
        assert isinstance(wait_for(lambda: client.get("/api/status").json()["position_mm"], what="a position"), float)
        metrics = client.get("/metrics").text
        assert "graytrack_camera_errors_total 1.0" in metrics and "graytrack_faults_total 2.0" in metrics


def test_a_vanished_serial_port_is_a_stage_fault_until_it_returns(tmp_path, calibrated) -> None:
    factory = GatedFactory()
    with TestClient(create_app(fast_settings(calibrated(tmp_path)), factory)) as client:
        wait_state(client, "tracking", 20.0)
        controller = factory.hardware.controller
        controller.vanish()
        status = wait_state(client, "fault")
        assert status["reason"].startswith("stage: grating readout failed")
        auth = {"Authorization": f"Bearer {client.app.state.storage.token_path.read_text().strip()}"}
        move = client.post("/api/stage/move", json={"target_mm": 2.0}, headers=auth)
        assert move.status_code == 503 and move.json()["error"].startswith("stage: ")
        controller.reappear()
        wait_state(client, "tracking")
        assert client.post("/api/stage/move", json={"target_mm": 2.0}, headers=auth).status_code == 202


def test_hardware_that_cannot_be_opened_is_retried(tmp_path) -> None:
    factory = GatedFactory(plugged=False)
    with TestClient(create_app(fast_settings(tmp_path), factory)) as client:
        status = wait_state(client, "fault")
        assert status["reason"].startswith("hardware: cannot open the hardware: no such device")
        assert status["calibrated"] is False and status["limits_mm"] is None
        wait_for(lambda: factory.attempts >= 2, what="a second attempt")
        factory.plugged = True
        wait_state(client, "tracking", 20.0)


def test_a_silent_controller_is_a_fault_within_the_cameras_time_and_its_figure_is_withdrawn(tmp_path,
                                                                                             calibrated) -> None:
    """The controller stops answering (every POS? dropped): the serial timeout is 5 s in these tests,
    but the daemon calls the silence a fault after camera_fault_after_s (1 s), and the last
    grating figure is withdrawn after stale_after_s instead of shown frozen."""
    from graytrack.drivers.stage.sim_controller import Fault

    factory = GatedFactory()
    with TestClient(create_app(fast_settings(calibrated(tmp_path)), factory)) as client:
        wait_state(client, "tracking", 20.0)
        assert client.get("/api/status").json()["grating_mm"] is not None
        controller = factory.hardware.controller
        controller.inject(Fault("drop", command="POS?", count=10_000))
        status = wait_state(client, "fault", 10.0)
        assert "stage" in status["faults"] and "has not answered" in status["faults"]["stage"]
        assert status["grating_mm"] is None and status["grating_age_ms"] > 1000
        assert client.get("/healthz").status_code == 503
        with controller._lock:
            controller._faults.clear()
        status = wait_state(client, "tracking", 20.0)
        assert status["grating_mm"] is not None
        events = [e for e in client.get("/api/events").json() if e["details"].get("source") == "stage"]
        assert [e["kind"] for e in events] == ["fault", "recovered"], "one event raised, one on recovery"
        assert events[1]["details"]["duration_s"] > 1.0
