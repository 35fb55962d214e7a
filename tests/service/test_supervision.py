"""Supervision through a real uvicorn server: every injected failure becomes a fault with its
reason, /healthz answers 503 while frames are not tracked, and the daemon recovers by itself."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graytrack.core.validity import FAMILIES
from graytrack.service.daemon import grating, sweep
from graytrack.service.daemon.app import create_app
from tests.service.helpers import GatedFactory, LiveServer, fast_settings, wait_for, wait_job


def test_frames_of_another_width_are_a_tracking_fault_not_a_dead_loop(tmp_path, calibrated) -> None:
    factory = GatedFactory()
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)), factory)) as daemon:
        daemon.wait_state("tracking")
        # (healthy once a frame has been tracked since: on a loaded machine the first may come after the state)
        assert wait_for(lambda: daemon.get("/healthz").status_code == 200, what="healthy")
        factory.hardware.camera.narrow_by = 7  # an ROI change on the camera
        status = daemon.wait_state("fault")
        assert status["faults"]["tracking"].startswith("frame ") and "cannot be tracked" in status["faults"]["tracking"]
        health = daemon.get("/healthz")
        assert health.status_code == 503 and "tracking" in health.json()["reason"]
        wait_for(lambda: daemon.status()["position_mm"] is None, what="the stale position withdrawn")
        assert daemon.status()["stale"] is True
        factory.hardware.camera.narrow_by = 0
        daemon.wait_state("tracking")
        assert wait_for(lambda: daemon.get("/healthz").status_code == 200, what="healthy again")


def test_a_crashing_frame_loop_is_reported_and_restarted(tmp_path, monkeypatch: pytest.MonkeyPatch,
                                                          calibrated) -> None:
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
        real_at, calls = grating.Readings.at, {"n": 0}

        def explode_once(self, t):  # an unexpected bug inside the loop, once
            calls["n"] += 1
            if calls["n"] == 1:
                raise RuntimeError("injected")
            return real_at(self, t)

        monkeypatch.setattr(grating.Readings, "at", explode_once)
        reasons = []
        daemon.rig.faults.listeners.append(lambda source, reason, previous, seconds: reasons.append((source, reason)))
        wait_for(lambda: daemon.rig.acquisition.crashes == 1, what="the crash")
        # reported before it is counted (a busy machine had the count seen before the report)
        assert ("acquisition", "acquisition crashed: RuntimeError: injected") in reasons
        daemon.wait_state("tracking")
        metrics = daemon.get("/metrics").text
        assert "graytrack_worker_crashes_total 1.0" in metrics and "graytrack_healthy 1.0" in metrics


def test_an_unusable_saved_model_is_a_fault_with_its_reason_and_a_calibration_replaces_it(tmp_path) -> None:
    nested = "[" * 100_000 + "]" * 100_000
    (tmp_path / "model.json").write_text('{"kind": "fourier", "coefficients": ' + nested + "}")
    with LiveServer(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as daemon:
        status = daemon.wait_state("fault")
        assert status["faults"]["model"].startswith(f"the saved model {tmp_path / 'model.json'} cannot be used")
        assert status["reason"].startswith("model: the saved model") and status["calibrated"] is False
        assert daemon.get("/healthz").status_code == 503
        started = daemon.post("/api/calibration", headers=daemon.auth())
        assert started.status_code == 202, started.text
        daemon.wait_state("tracking")
        assert json.loads((tmp_path / "model.json").read_text())["schema"] == "graytrack.model"


def test_a_model_the_tracker_cannot_evaluate_is_a_fault(tmp_path, calibrated) -> None:
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
    # the model of record is the active calibration's own (DATA/model.json is its copy)
    of_record = tmp_path / "calibrations" / (tmp_path / "active").read_text().strip() / "model.json"
    document = json.loads(of_record.read_text())
    document["model"]["clip_gray"] = [255, 0]
    of_record.write_text(json.dumps(document))
    with LiveServer(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as daemon:
        status = daemon.wait_state("fault")
        assert set(status["faults"]) & {"model", "tracking"}, status
        assert daemon.get("/healthz").status_code == 503
        assert daemon.get("/metrics").status_code == 200


@pytest.mark.parametrize("failure, reason", [
    (np.linalg.LinAlgError("SVD did not converge"), "LinAlgError: SVD did not converge"),
    (OSError(28, "No space left on device"), "No space left on device"),
])
def test_an_unexpected_error_in_a_calibration_fails_the_job_and_restores_the_daemon(
        tmp_path, monkeypatch: pytest.MonkeyPatch, failure: Exception, reason: str, calibrated) -> None:
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
        model_before = (tmp_path / "model.json").read_text()
        if isinstance(failure, OSError):  # the disk fills while the new model is installed
            monkeypatch.setattr(daemon.rig.storage, "switch_model", lambda job_id: (_ for _ in ()).throw(failure))
        else:
            monkeypatch.setattr(sweep, "calibrate_recording", lambda *a, **k: (_ for _ in ()).throw(failure))
        job_id = daemon.post("/api/calibration", headers=daemon.auth()).json()["id"]
        job = wait_job(daemon.get, job_id, ("failed", "done"), 10.0)
        assert job["state"] == "failed", job
        if isinstance(failure, OSError):  # the disk full fault's sentence, with the system's words in it
            assert job["error"].startswith("disk full: a write to the data directory") and reason in job["error"], job
        else:
            assert job["error"] == reason, job
        on_disk = json.loads((tmp_path / "calibrations" / job_id / "status.json").read_text())
        assert on_disk["state"] == "failed"
        status = daemon.wait_state("tracking")
        assert status["calibration"]["state"] == "failed"
        assert (tmp_path / "model.json").read_text() == model_before, "the old model stays in use"
        assert daemon.post("/api/stage/move", json={"target_mm": 2.0}, headers=daemon.auth()).status_code == 202
        monkeypatch.undo()
        again = daemon.post("/api/calibration", headers=daemon.auth())
        assert again.status_code == 202
        done = wait_job(daemon.get, again.json()["id"], "done", 10.0)
        assert done["progress"] == 1.0


def test_a_shutdown_during_the_fit_aborts_the_job_and_installs_nothing(tmp_path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    real_calibrate, fitting = sweep.calibrate_recording, []

    def slow_fit(*args, **kwargs):  # a fit that is still running when the shutdown comes
        fitting.append(True)
        wait_for(lambda: daemon.rig.job.abort.is_set(), 20.0, "the shutdown to reach the job")
        return real_calibrate(*args, **kwargs)

    monkeypatch.setattr(sweep, "calibrate_recording", slow_fit)
    with LiveServer(create_app(fast_settings(tmp_path))) as daemon:
        job_id = wait_for(lambda: daemon.rig.job and fitting and daemon.rig.job.id, 20.0, "the fit")
    on_disk = json.loads((tmp_path / "calibrations" / job_id / "status.json").read_text())
    assert on_disk["state"] == "aborted" and on_disk["message"] == "calibration aborted: the daemon is shutting down"
    assert not (tmp_path / "model.json").exists() and not (tmp_path / "active").exists()


def test_a_fault_is_two_events_however_long_it_lasts_and_its_text_changes() -> None:
    """A camera silent for an hour describes its silence anew every check: still one fault raised
    and one recovery, the recovery carrying how long it lasted (an injected clock, no waiting)."""
    from graytrack.service.daemon.supervision import Faults

    now = [100.0]
    faults = Faults(clock=lambda: now[0])
    heard = []
    faults.listeners.append(lambda source, reason, previous, seconds: heard.append((source, reason, seconds)))
    for second in range(3600):
        now[0] = 100.0 + second
        faults.set("camera", f"no frame for {second + 0.3:.1f} s")
        faults.set("stage", None)  # a source that was never in fault says nothing
    assert faults.snapshot() == {"camera": "no frame for 3599.3 s"}, "the status shows the text as it is now"
    now[0] = 3700.0
    faults.set("camera", None)
    assert heard == [("camera", "no frame for 0.3 s", 0.0), ("camera", None, 3600.0)]
    assert faults.raised == 1


def test_no_room_for_a_sweep_is_refused_before_anything_is_written(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil
    from collections import namedtuple

    with LiveServer(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as daemon:
        daemon.wait_state("idle")
        wait_for(lambda: daemon.rig.acquisition.latest is not None, what="a frame")
        before = sorted(p.name for p in (tmp_path / "calibrations").iterdir())
        usage = namedtuple("usage", "total used free")
        monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 100_000, 100_000))
        answer = daemon.post("/api/calibration", headers=daemon.auth())
        assert answer.status_code == 507 and "MB free" in answer.json()["error"]
        assert sorted(p.name for p in (tmp_path / "calibrations").iterdir()) == before, "no empty folder"
        kinds = [e["kind"] for e in daemon.get("/api/events").json()]
        assert "calibration_refused" in kinds
        monkeypatch.undo()
        assert daemon.post("/api/calibration", headers=daemon.auth()).status_code == 202


def test_a_valid_but_wrong_model_is_not_healthy(tmp_path, calibrated) -> None:
    """A model whose period is 5 % off loads and tracks, but the images are not what it describes:
    the model is flagged stale, /healthz answers 503 and the status says so. Near the stroke's
    start the scale's error is small in µm and the per-frame nuisances name a cause of their own;
    mid-stroke the camera sits hundreds of bounds off the grating and ``scale`` is named, whatever
    the nuisances suggest (core/watches/far_off.py)."""
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
        model = daemon.rig.model
        daemon.rig.install(model.with_changes(period_mm=model.period_mm * 1.05, coeffs=model.coeffs))
        status = wait_for(lambda: (s := daemon.status())["model_stale"] and s, 20.0, "the stale flag")
        assert status["stale_reason"] in FAMILIES
        health = daemon.get("/healthz")
        assert health.status_code == 503 and "stale" in health.json()["reason"]
        assert "model_stale" in [e["kind"] for e in daemon.get("/api/events").json()]
        daemon.post("/api/stage/move", json={"target_mm": 5.0}, headers=daemon.auth())
        status = wait_for(lambda: (s := daemon.status())["stale_reason"] == "scale" and not s["moving"] and s,
                          20.0, "the scale named mid-stroke")
        assert status["model_stale"] and abs(status["position_mm"] - status["grating_mm"]) > 0.2
        assert daemon.get("/healthz").status_code == 503
