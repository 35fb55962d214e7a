"""The daemon's calibration sweep on a virtual rig whose camera is mounted the other way round:
it fails with the cause and the fix in the job's error and the event log, and with
``[camera] flip = true`` the same rig calibrates and tracks."""

from __future__ import annotations

from fastapi.testclient import TestClient

from graytrack.core.recording import load
from graytrack.service.daemon.app import create_app
from tests.service.helpers import activate_refused, fast_settings, wait_for, wait_state


def _finished_job(client: TestClient) -> dict:
    def done() -> dict | None:
        response = client.get("/api/calibration/latest")
        if response.status_code != 200:
            return None
        job = response.json()
        return job if job["state"] in ("done", "failed", "aborted") else None

    return wait_for(done, 60.0, "the first calibration to finish")


def test_a_mirrored_camera_fails_the_sweep_with_the_cause_and_flip_true_calibrates(tmp_path) -> None:
    mirrored = fast_settings(tmp_path / "mirrored", {"camera": {"effects": "mirrored"}})
    with TestClient(create_app(mirrored)) as client:
        job = _finished_job(client)
        assert job["state"] == "failed"
        assert "pixel axis looks reversed" in job["error"] and "[camera] flip = true" in job["error"]
        events = client.get("/api/events").json()
        failed = [e for e in events if e["kind"] == "calibration_failed"]
        assert failed and "pixel axis looks reversed" in failed[-1]["message"]
        assert client.get("/api/status").json()["calibrated"] is False

    flipped = fast_settings(tmp_path / "flipped", {"camera": {"effects": "mirrored", "flip": True}})
    with TestClient(create_app(flipped)) as client:
        job = _finished_job(client)
        assert job["state"] == "done", job.get("error")
        assert job["report"]["geometry"]["status"] == "ok"
        assert job["report"]["geometry"]["residual_ratio"] < 1.3
        assert load(job["files"]["recording"]).meta["pixel_axis_reversed"] is True
        wait_state(client, "tracking", 20.0)
        assert client.app.state.rig.model.info["camera_flip"] is True

    # The same data directory, the camera's flip switched off again: the saved model is refused.
    unflipped = fast_settings(tmp_path / "flipped", {"camera": {"effects": "mirrored", "flip": False}})
    with TestClient(create_app(unflipped)) as client:
        status = wait_state(client, "fault", 20.0)
        assert status["calibrated"] is False
        # Activating that calibration again is a conflict with the camera's configuration (409), not "not ready"
        refusal = activate_refused(client, "geometry",
                                   "calibrated with [camera] flip = true and the camera now has flip = false")
        assert "recalibrate or set flip back" in refusal["error"]
