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
from tests.service.helpers import LiveServer, ServeProcess, fast_settings, wait_for, wait_job


def _calibrate(daemon: LiveServer) -> str:
    job_id = daemon.post("/api/calibration", headers=daemon.auth()).json()["id"]
    wait_job(daemon.get, job_id, "done", 30.0)
    return job_id


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Iterator[LiveServer]:
    """A daemon with two calibrations: the automatic one of its first start (the run's, copied: tests/conftest.py
    calibrated) and one on request."""
    with LiveServer(create_app(fast_settings(calibrated(tmp_path_factory.mktemp("record"))))) as server:
        server.wait_state("tracking")
        _calibrate(server)
        yield server


def test_calibrations_are_listed_newest_first_with_their_quality_and_paginated(daemon: LiveServer) -> None:
    page = daemon.get("/api/calibrations").json()
    assert page["total"] == 2 and [c["id"] for c in page["items"]] == sorted((c["id"] for c in page["items"]),
                                                                             reverse=True)
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
    assert f"{row['error_std_um']:.3f} µm" in report.text and "<script" not in report.text
    policy = report.headers["content-security-policy"]
    assert "script-src" not in policy and "default-src 'none'" in policy
    assert daemon.get(f"{base}/report.json").json()["held_out"]["error_std_um"] == row["error_std_um"]
    assert daemon.get(f"{base}/model.json").json()["schema"] == "graytrack.model"
    assert daemon.get(f"{base}/recording.npz").content[:2] == b"PK"
    for path in (f"{base}/status.json", f"{base}/..%2F..%2Ftoken",
                 "/api/calibrations/20990101T000000000000Z/files/model.json"):
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
    # the rig's own events (frames lost on a busy host) may come between: the requests' are read
    newer = [e for e in daemon.get("/api/events", params={"since": cursor}).json() if e["kind"] in ("move", "stop")]
    assert [e["message"] for e in newer] == ["move to 4 mm", "stage stopped"]
    assert all(e["id"] > cursor for e in newer)
    moment = newer[0]["t_unix"]
    from datetime import datetime, timezone

    iso = datetime.fromtimestamp(moment - 2e-6, timezone.utc).isoformat()  # ISO keeps microseconds: round down
    since = daemon.get("/api/events", params={"since": iso}).json()
    assert [e["id"] for e in since if e["kind"] in ("move", "stop")] == [e["id"] for e in newer]
    assert all(e["t_unix"] >= moment - 2e-6 for e in since)
    assert daemon.get("/api/events", params={"since": "yesterday"}).status_code == 422
    # a steady rig, calibrated twice, rolled back and forth and moved: its model never flagged, not a frame
    flags = [e for e in daemon.get("/api/events").json() if e["kind"] in ("model_stale", "frame_flagged")]
    assert flags == [], flags


def test_history_survives_a_restart_and_a_kill_9(tmp_path: Path) -> None:
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as first:
        first.wait_state("idle")
        done = httpx.post(f"{first.base}/api/calibration", headers=first.auth(), timeout=5).json()["id"]
        wait_job(first.get, done, "done", 30.0)
        unfinished = httpx.post(f"{first.base}/api/calibration", headers=first.auth(), timeout=5).json()["id"]
        wait_job(first.get, unfinished, "sweeping", 30.0)
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
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, calibrated) -> None:
    from types import SimpleNamespace

    from graytrack.core import tracking

    real_update, flag = tracking.LiveTracker.update, {"stale": False}

    def update(self, frame, reference_mm=float("nan"), t=None):  # the tracker's per-frame fit figures, stale on demand
        fix = real_update(self, frame, reference_mm, t)
        return SimpleNamespace(**{**vars(fix), "gain": 1.01, "offset_gray": -0.2, "rejected_px": 2, "chi2": 1.04,
                                  "stale": flag["stale"], "stale_reason": "focus" if flag["stale"] else None})

    monkeypatch.setattr(tracking.LiveTracker, "update", update)
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
        flag["stale"] = True
        wait_for(lambda: "model_stale" in [e["kind"] for e in daemon.get("/api/events").json()], what="the stale flag")
        status = daemon.status()
        assert status["fit"] == {"gain": 1.01, "offset_gray": -0.2, "rejected_px": 2, "transient_px": 0, "chi2": 1.04,
                                 "focus_px2": None, "focus_sigma_px2": None, "stale": True, "stale_reason": "focus",
                                 "texture_px": 0}
        assert status["model_stale"] and status["stale_reason"] == "focus"
        health = daemon.get("/healthz")
        assert health.status_code == 503 and "focus" in health.json()["reason"], "a stale model is not healthy"
        metrics = daemon.get("/metrics").text
        assert "graytrack_fit_stale 1.0" in metrics and "graytrack_fit_rejected_pixels 2.0" in metrics
        assert 'graytrack_model_stale{reason="focus"} 1.0' in metrics
        assert 'graytrack_model_stale{reason="light"} 0.0' in metrics
        stale_event = [e for e in daemon.get("/api/events").json() if e["kind"] == "model_stale"][0]
        assert "focus" in stale_event["message"] and "lens" in stale_event["message"]
        flag["stale"] = False
        wait_for(lambda: "model_fresh" in [e["kind"] for e in daemon.get("/api/events").json()], what="fresh again")
        kinds = [e["kind"] for e in daemon.get("/api/events").json()]
        assert kinds.count("model_stale") == 1, "a flag is recorded when it changes, not per frame"


def _damage(database: Path, how: str) -> None:
    if how == "header":
        with open(database, "r+b") as fh:
            fh.write(b"this is not SQLite")
    elif how == "truncated":
        with open(database, "r+b") as fh:
            fh.truncate(min(40 * 1024, database.stat().st_size // 2))
    elif how == "empty":
        database.write_bytes(b"")
    elif how == "missing":
        database.unlink()


@pytest.mark.parametrize("how", ["header", "truncated", "empty", "missing"])
def test_a_damaged_record_is_set_aside_and_rebuilt_from_the_calibration_folders(
        tmp_path: Path, how: str, two_calibrations: list[str]) -> None:
    done = two_calibrations
    database = tmp_path / "data" / "record.sqlite"
    for suffix in ("-wal", "-shm"):
        database.with_name(database.name + suffix).unlink(missing_ok=True)
    _damage(database, how)
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as second:
        status = second.wait_state("tracking")
        assert status["active_calibration"]["id"] == done[-1]
        page = httpx.get(f"{second.base}/api/calibrations", timeout=5).json()
        assert [c["id"] for c in page["items"]] == done[::-1], "every finished calibration listed again"
        assert all(c["error_std_um"] is not None for c in page["items"])
        assert httpx.post(f"{second.base}/api/calibrations/{done[0]}/activate", headers=second.auth(),
                          timeout=5).status_code == 200
        kinds = [e["kind"] for e in httpx.get(f"{second.base}/api/events", timeout=5).json()]
        assert "record_restored" in kinds
        if how == "empty":  # a 0-byte record is said, not silently taken as an empty history
            events = httpx.get(f"{second.base}/api/events", timeout=5).json()
            rebuilt = [e for e in events if e["kind"] == "record_rebuilt"]
            assert len(rebuilt) == 1 and "empty file (0 bytes" in rebuilt[0]["message"], rebuilt
        if how in ("header", "truncated"):
            assert "record_rebuilt" in kinds
            kept = [p.name for p in database.parent.iterdir() if ".damaged-" in p.name]
            assert kept, "the damaged file is kept for inspection"


def test_an_event_log_that_cannot_be_written_is_a_fault_not_a_line_on_stderr(tmp_path: Path) -> None:
    with LiveServer(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as daemon:
        daemon.wait_state("idle")
        history = daemon.rig.history
        real_db = history._db
        history._db = sqlite3.connect(":memory:", check_same_thread=False)  # no tables: every write fails
        daemon.rig.event("test", "an event that cannot be written")
        status = daemon.status()
        assert "record" in status["faults"] and "cannot be written" in status["faults"]["record"]
        assert "graytrack_faults_total 1.0" in daemon.get("/metrics").text
        history._db = real_db
        daemon.rig.event("test", "written again")
        assert "record" not in daemon.status()["faults"]


def test_the_event_log_is_compacted_by_age_and_count_keeping_the_newest_of_each_kind(tmp_path: Path) -> None:
    from graytrack.service.daemon.history import LabHistory

    history = LabHistory(tmp_path / "record.sqlite")
    day = 86_400.0
    history.event("start", "daemon started", t_unix=0.0)
    history.event("fault", "camera: no frame", t_unix=1.0 * day)
    for i in range(30):
        history.event("move", f"move to {i} mm", t_unix=2.0 * day + i)
    assert history.compact(max_age_s=10 * day, max_count=1000, now=5.0 * day) == 0
    assert history.compact(max_age_s=10 * day, max_count=10, now=5.0 * day) == 20  # by count
    kept = history.events(limit=100)
    assert [e["kind"] for e in kept] == ["start", "fault"] + ["move"] * 10, "the newest of each kind stays"
    assert kept[-1]["message"] == "move to 29 mm"
    assert history.compact(max_age_s=1.0 * day, max_count=1000, now=3.0 * day + 25) == 5  # by age: 2 d + 0..24 s
    assert [e["message"] for e in history.events(limit=100)][-5:] == [f"move to {i} mm" for i in range(25, 30)]
    assert [e["kind"] for e in history.events(limit=100)][:2] == ["start", "fault"]
    history.close()
