"""The daemon's HTTP and WebSocket contract (docs/contracts.md) against the real app on the virtual rig."""

from __future__ import annotations

import stat

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graytrack.core.models import load_model
from graytrack.core.recording import load
from graytrack.service.daemon.app import create_app
from tests.service.helpers import fast_settings, wait_for, wait_job, wait_state


def test_status_and_health_follow_the_contract(tracking: TestClient) -> None:
    # a fresh tracked frame (a loaded machine may have left the newest one older than stale_after_s)
    status = wait_for(lambda: (s := tracking.get("/api/status").json())["position_mm"] is not None
                      and s["grating_mm"] is not None and s, 20.0, "a fresh position and grating reading")
    assert status["state"] == "tracking" and status["calibrated"] is True
    assert isinstance(status["position_mm"], float) and 0.0 <= status["position_mm"] <= 10.46
    assert status["reason"] is None and status["limits_mm"] == [0.0, 10.46]
    assert abs(status["position_mm"] - status["grating_mm"]) < 0.01
    assert tracking.get("/healthz").json() == {"ok": True, "state": "tracking", "reason": None}


def test_first_start_calibrated_itself_and_stored_everything(tracking: TestClient) -> None:
    latest = tracking.get("/api/calibration/latest").json()
    assert latest["state"] == "done" and latest["progress"] == 1.0
    report = latest["report"]
    assert report["rmse_gray"] < 1.0 and report["frames"] == 21 * 3
    assert report["sigma_gray"] == pytest.approx(0.7, rel=0.3), "noise from three frames per stop"
    recording = load(latest["files"]["recording"])
    assert recording.n_frames == 63 and np.isfinite(recording.reference).all()
    assert recording.meta["source"] == "graytrack serve" and recording.meta["scenario"] == "paper"
    assert load_model(latest["files"]["model"]).describe() == tracking.get("/api/status").json()["model"]
    storage = tracking.app.state.storage
    assert storage.model_path.is_file()
    assert stat.S_IMODE(storage.token_path.stat().st_mode) == 0o600
    assert tracking.get(f"/api/calibration/{latest['id']}").json()["id"] == latest["id"]


def test_websocket_streams_one_message_per_tracked_frame(tracking: TestClient) -> None:
    with tracking.websocket_connect("/ws/position") as ws:
        messages = [ws.receive_json() for _ in range(50)]
    seqs = [m["seq"] for m in messages]
    assert seqs == list(range(seqs[0], seqs[0] + 50)), "no gaps: every tracked frame is sent"
    assert all(isinstance(m["t"], float) and m["locked"] for m in messages)
    assert np.all(np.diff([m["t"] for m in messages]) > 0)
    paired = [m for m in messages if "reference_mm" in m]
    # 10x sim time leaves 20 ms of wall time to find a POS? reading near each frame; a loaded
    # machine misses many, which is fine: a frame without a close reading is sent without one
    assert len(paired) >= 5, "frames are paired with the grating read at their exposure time"
    errors = np.array([m["error_um"] for m in paired])
    # at rest: noise-limited (bound 1.5 um per frame) plus what a 21-stop calibration leaves
    assert np.std(errors) < 3.0 and np.max(np.abs(errors)) < 10.0, errors


def test_state_changes_need_the_token(tracking: TestClient, token: dict[str, str]) -> None:
    for path, body in (("/api/calibration", None), ("/api/stage/move", {"target_mm": 5.0}), ("/api/stage/stop", None)):
        response = tracking.post(path, json=body)
        assert response.status_code == 401 and "bearer token" in response.json()["error"]
        assert response.headers["www-authenticate"] == "Bearer"
        wrong = tracking.post(path, json=body, headers={"Authorization": "Bearer not-the-token-at-all"})
        assert wrong.status_code == 401 and wrong.json()["error"] == "invalid bearer token"


def test_bad_moves_are_refused_with_a_clear_message(tracking: TestClient, token: dict[str, str]) -> None:
    outside = tracking.post("/api/stage/move", json={"target_mm": 12.0}, headers=token)
    assert outside.status_code == 422
    assert outside.json()["error"] == "target_mm 12 is outside the soft limits [0, 10.46] mm"
    # just past the limit: printed with the digits that show the difference, not "10.46 is outside [0, 10.46]"
    hair = tracking.post("/api/stage/move", json={"target_mm": 10.4600000001}, headers=token)
    assert hair.status_code == 422
    assert hair.json()["error"] == "target_mm 10.4600000001 is outside the soft limits [0, 10.46] mm"
    below = tracking.post("/api/stage/move", json={"target_mm": -1e-12}, headers=token)
    assert below.json()["error"] == "target_mm -1e-12 is outside the soft limits [0, 10.46] mm"
    fast = tracking.post("/api/stage/velocity", json={"velocity_mm_s": 50.00000001}, headers=token)
    assert fast.json()["error"] == "velocity_mm_s 50.00000001 is outside (0, 50] mm/s (the controller's limit)"
    broken = tracking.post("/api/stage/move", content=b"{target_mm: 3",
                           headers={**token, "Content-Type": "application/json"})
    assert broken.status_code == 422 and broken.json()["error"] == "request body is not valid JSON"
    missing = tracking.post("/api/stage/move", json={"target": 3.0}, headers=token)
    assert missing.status_code == 422 and "target_mm" in missing.json()["error"]
    text = tracking.post("/api/stage/move", json={"target_mm": "three"}, headers=token)
    assert text.status_code == 422 and "target_mm" in text.json()["error"]
    assert tracking.get("/api/calibration/no-such-id").status_code == 404
    assert tracking.get("/api/calibration/..%2F..%2Fetc").status_code == 404


def test_a_commanded_move_is_tracked_to_its_target(tracking: TestClient, token: dict[str, str]) -> None:
    response = tracking.post("/api/stage/move", json={"target_mm": 4.25}, headers=token)
    assert response.status_code == 202 and response.json()["target_mm"] == 4.25

    def arrived() -> dict | None:
        status = tracking.get("/api/status").json()
        return status if status["position_mm"] is not None and abs(status["position_mm"] - 4.25) < 0.003 else None

    status = wait_for(arrived, 10.0, "the tracked position to reach 4.25 mm")
    assert status["locked"] and status["state"] == "tracking"
    assert tracking.post("/api/stage/stop", headers=token).json()["stopped"] is True


def test_metrics_are_prometheus_text(tracking: TestClient) -> None:
    response = tracking.get("/metrics")
    assert response.headers["content-type"].startswith("text/plain; version=0.0.4")
    values = {}
    for line in response.text.splitlines():
        if not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    assert values['graytrack_state{state="tracking"}'] == 1.0
    assert values["graytrack_frames_tracked_total"] > 0 and values["graytrack_frame_rate_hertz"] > 100
    assert values['graytrack_calibrations_total{outcome="done"}'] >= 1
    assert 0.0 <= values["graytrack_position_meters"] <= 10.46e-3


def test_calibration_on_request_shows_progress_and_stop_aborts_it(tmp_path) -> None:
    settings = fast_settings(tmp_path, auto_calibrate="never")
    with TestClient(create_app(settings)) as client:
        status = wait_state(client, "idle")
        assert status["calibrated"] is False and status["position_mm"] is None
        assert client.get("/api/calibration/latest").status_code == 404
        auth = {"Authorization": f"Bearer {client.app.state.storage.token_path.read_text().strip()}"}

        started = client.post("/api/calibration", headers=auth)
        assert started.status_code == 202
        job_id = started.json()["id"]
        assert client.post("/api/calibration", headers=auth).status_code == 409
        assert client.post("/api/stage/move", json={"target_mm": 1.0}, headers=auth).status_code == 409
        wait_for(lambda: client.get(f"/api/calibration/{job_id}").json()["progress"] > 0.1, what="progress")
        assert client.get("/api/status").json()["state"] == "calibrating"
        assert client.post("/api/stage/stop", headers=auth).json()["aborted_calibration"] == job_id
        job = wait_job(client.get, job_id, ("aborted", "failed", "done", "fitting", "installing"), 10.0)  # not sweeping
        assert job["state"] == "aborted" and job["report"] is None
        assert wait_state(client, "idle")["calibrated"] is False

        again = client.post("/api/calibration", headers=auth).json()["id"]
        done = wait_job(client.get, again, "done", 20.0)
        assert done["report"]["rmse_gray"] < 1.0
        assert client.get("/api/calibration/latest").json()["id"] == again
        assert wait_state(client, "tracking")["calibrated"] is True


def test_a_restart_tracks_with_the_saved_model_without_calibrating(tmp_path) -> None:
    with TestClient(create_app(fast_settings(tmp_path))) as client:
        wait_state(client, "tracking", 20.0)
        first = client.get("/api/calibration/latest").json()
    storage_dir = tmp_path / "calibrations"
    before = sorted(p.name for p in storage_dir.iterdir())
    with TestClient(create_app(fast_settings(tmp_path))) as client:
        status = wait_state(client, "tracking")
        assert status["calibrated"] and status["model"] == first["report"]["model"]
        wait_for(lambda: client.get("/api/status").json()["position_mm"] is not None, what="a position")
    assert sorted(p.name for p in storage_dir.iterdir()) == before == [first["id"]]
