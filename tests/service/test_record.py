"""The record through a real uvicorn server: calibrations newest first with their files, the event
log with ``since``, rolling back a model, and history that survives a restart and a kill -9."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, ServeProcess, fast_settings, wait_for


def _calibrate(daemon: LiveServer) -> str:
    job_id = daemon.post("/api/calibration", headers=daemon.auth()).json()["id"]
    wait_for(lambda: daemon.get(f"/api/calibration/{job_id}").json()["state"] == "done", 30.0, f"calibration {job_id}")
    return job_id


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    """A daemon with two calibrations: the automatic one at start and one on request."""
    with LiveServer(create_app(fast_settings(tmp_path_factory.mktemp("record")))) as server:
        server.wait_state("tracking")
        _calibrate(server)
        yield server


def test_calibrations_are_listed_newest_first_with_their_quality_and_paginated(daemon: LiveServer) -> None:
    page = daemon.get("/api/calibrations").json()
    assert page["total"] == 2 and [c["id"] for c in page["items"]] == sorted((c["id"] for c in page["items"]), reverse=True)
    newest, oldest = page["items"]
    assert newest["active"] and not oldest["active"]
    for row in page["items"]:
        assert row["model_kind"] == "paper" and row["frames"] == 63
        # held-out error near the Cramér–Rao bound of the same frames (noise-limited tracking)
        assert 0.7 * row["bound_um"] < row["error_std_um"] < 2.5 * row["bound_um"], row
        assert set(row["files"]) == {"model.json", "recording.npz", "report.json", "report.html"}
    second = daemon.get("/api/calibrations", params={"limit": 1, "offset": 1}).json()
    assert [c["id"] for c in second["items"]] == [oldest["id"]] and second["total"] == 2
    assert daemon.get("/api/calibrations", params={"limit": 0}).status_code == 422
    assert daemon.status()["active_calibration"]["id"] == newest["id"]
    assert daemon.status()["active_calibration"]["error_std_um"] == newest["error_std_um"]


def test_each_calibrations_files_are_served(daemon: LiveServer) -> None:
    row = daemon.get("/api/calibrations").json()["items"][0]
    base = f"/api/calibrations/{row['id']}/files"
    report = daemon.get(f"{base}/report.html")
    assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")
    assert f"{row['error_std_um']:.2f} µm" in report.text and "<script" not in report.text
    assert "script-src" not in report.headers["content-security-policy"] and "default-src 'none'" in report.headers["content-security-policy"]
    assert daemon.get(f"{base}/report.json").json()["held_out"]["error_std_um"] == row["error_std_um"]
    assert daemon.get(f"{base}/model.json").json()["schema"] == "graytrack.model"
    assert daemon.get(f"{base}/recording.npz").content[:2] == b"PK"
    for path in (f"{base}/status.json", f"{base}/..%2F..%2Ftoken", "/api/calibrations/20990101T000000000000Z/files/model.json"):
        assert daemon.get(path).status_code == 404, path


def test_activate_rolls_back_to_an_earlier_model_and_needs_the_token(daemon: LiveServer) -> None:
    newest, oldest = daemon.get("/api/calibrations").json()["items"]
    path = f"/api/calibrations/{oldest['id']}/activate"
    assert daemon.post(path).status_code == 401
    assert daemon.post("/api/calibrations/20990101T000000000000Z/activate", headers=daemon.auth()).status_code == 404
    response = daemon.post(path, headers=daemon.auth())
    assert response.status_code == 200 and response.json()["active"] == oldest["id"]
    status = daemon.status()
    assert status["active_calibration"]["id"] == oldest["id"] and status["model"] == oldest["model"]
    stored = json.loads(Path(daemon.rig.storage.model_path).read_text())
    assert stored == daemon.get(f"/api/calibrations/{oldest['id']}/files/model.json").json()
    assert [c["active"] for c in daemon.get("/api/calibrations").json()["items"]] == [False, True]
    daemon.wait_state("tracking")
    daemon.post(f"/api/calibrations/{newest['id']}/activate", headers=daemon.auth())


def test_events_are_recorded_and_read_since_a_cursor(daemon: LiveServer) -> None:
    events = daemon.get("/api/events").json()
    kinds = [e["kind"] for e in events]
    assert kinds[0] == "start" and kinds.count("calibration_done") == 2 and kinds.count("model_installed") >= 2
    cursor = events[-1]["id"]
    daemon.post("/api/stage/move", json={"target_mm": 4.0}, headers=daemon.auth())
    daemon.post("/api/stage/stop", headers=daemon.auth())
    newer = daemon.get("/api/events", params={"since": cursor}).json()
    assert [e["message"] for e in newer] == ["move to 4 mm", "stage stopped"]
    assert all(e["id"] > cursor for e in newer)
    moment = newer[0]["t_unix"]
    from datetime import datetime, timezone

    iso = datetime.fromtimestamp(moment - 2e-6, timezone.utc).isoformat()  # ISO keeps microseconds: round down
    assert [e["id"] for e in daemon.get("/api/events", params={"since": iso}).json()] == [e["id"] for e in newer]
    assert daemon.get("/api/events", params={"since": "yesterday"}).status_code == 422


def test_history_survives_a_restart_and_a_kill_9(tmp_path: Path) -> None:
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as first:
        first.wait_state("idle")
        done = httpx.post(f"{first.base}/api/calibration", headers=first.auth(), timeout=5).json()["id"]
        wait_for(lambda: httpx.get(f"{first.base}/api/calibration/{done}", timeout=5).json()["state"] == "done", 30.0,
                 "the calibration")
        unfinished = httpx.post(f"{first.base}/api/calibration", headers=first.auth(), timeout=5).json()["id"]
        wait_for(lambda: httpx.get(f"{first.base}/api/calibration/{unfinished}", timeout=5).json()["state"] == "sweeping",
                 30.0, "the second sweep")
        first.process.kill()
        first.process.wait()
    database = tmp_path / "data" / "record.sqlite"
    assert sqlite3.connect(database).execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as second:
        status = second.wait_state("tracking")
        assert status["active_calibration"]["id"] == done, "the active calibration after the restart"
        page = httpx.get(f"{second.base}/api/calibrations", timeout=5).json()
        assert [c["id"] for c in page["items"]] == [done], "no row for a job that never finished as done"
        kinds = [e["kind"] for e in httpx.get(f"{second.base}/api/events", timeout=5).json()]
        assert kinds.count("start") == 2 and "calibration_done" in kinds and "calibration_interrupted" in kinds
        assert second.terminate() == 0
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as third:  # a clean restart keeps it all
        third.wait_state("tracking")
        kinds = [e["kind"] for e in httpx.get(f"{third.base}/api/events", timeout=5).json()]
        assert kinds.count("start") == 3 and kinds.count("shutdown") == 1


def test_the_trackers_fit_figures_and_stale_model_flags_reach_status_metrics_and_events(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from types import SimpleNamespace

    from graytrack.core import tracking

    real_update, flag = tracking.LiveTracker.update, {"stale": False}

    def update(self, frame, reference_mm=float("nan")):  # the tracker's per-frame fit figures, stale on demand
        fix = real_update(self, frame, reference_mm)
        return SimpleNamespace(**{**vars(fix), "gain": 1.01, "offset_gray": -0.2, "rejected_px": 2, "chi2": 1.04,
                                  "stale": flag["stale"]})

    monkeypatch.setattr(tracking.LiveTracker, "update", update)
    with LiveServer(create_app(fast_settings(tmp_path))) as daemon:
        daemon.wait_state("tracking")
        flag["stale"] = True
        wait_for(lambda: "model_stale" in [e["kind"] for e in daemon.get("/api/events").json()], what="the stale flag")
        fit = daemon.status()["fit"]
        assert fit == {"gain": 1.01, "offset_gray": -0.2, "rejected_px": 2, "chi2": 1.04, "stale": True}
        metrics = daemon.get("/metrics").text
        assert "graytrack_fit_stale 1.0" in metrics and "graytrack_fit_rejected_px 2.0" in metrics
        flag["stale"] = False
        wait_for(lambda: "model_fresh" in [e["kind"] for e in daemon.get("/api/events").json()], what="fresh again")
        kinds = [e["kind"] for e in daemon.get("/api/events").json()]
        assert kinds.count("model_stale") == 1, "a flag is recorded when it changes, not per frame"
