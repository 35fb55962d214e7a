"""What the daemon learns on the print is part of the model of record (service/daemon/texture_store.py):
written beside the model (``DATA/texture.json``, tied to the active calibration), shown in
``/api/status``, restored into the tracker at a restart on the same calibration, and dropped, with
an event, when another model takes over (a rollback). Through a real daemon on the virtual rig
with dust settling on its print (the model was not told about the dust). The store's own rules (a full
disk, another calibration's file, a damaged one), shared by every learned map: tests/service/test_map_store.py."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path


from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings, wait_for, wait_job

# specks landing on the print after the start-up calibration's sweep (sim seconds; the test clock runs 10x)
DUST = {"camera": {"effects": "dust_settling:start_s=30,over_s=10"}}


def events(daemon: LiveServer, kind: str) -> list[str]:
    page, since = [], 0
    while batch := daemon.get("/api/events", params={"since": since, "limit": 500}).json():
        page += batch
        since = batch[-1]["id"]
    return [e["message"] for e in page if e["kind"] == kind]


def learn(daemon: LiveServer, at_least: int = 3) -> dict:
    """Pass the print under the camera (2 <-> 8 mm at 0.5 mm/s) until the tracker has learned ``at_least``
    marks and the daemon has written them; the status's ``texture`` then."""
    assert daemon.post("/api/stage/velocity", json={"velocity_mm_s": 0.5}, headers=daemon.auth()).status_code == 200
    for target in (8.0, 2.0, 8.0, 2.0, 8.0, 2.0):
        assert daemon.post("/api/stage/move", json={"target_mm": target}, headers=daemon.auth()).status_code == 202
        wait_for(lambda: abs((daemon.status()["grating_mm"] or -1.0) - target) < 0.01, 60.0, f"the move to {target}",
                 show=lambda: {key: daemon.status()[key] for key in ("state", "grating_mm", "position_mm", "texture")})
        texture = daemon.status()["texture"]
        if texture["marks"] >= at_least and texture["saved"]:
            return texture
    raise AssertionError(f"nothing learned on the dusty print: {daemon.status()['texture']}")


def test_marks_the_daemon_learned_survive_a_restart_and_a_rollback_drops_them(tmp_path: Path) -> None:
    data = tmp_path / "data"
    kept = data / "texture.json"
    settings = fast_settings(data, tables=DUST)
    with LiveServer(create_app(settings)) as daemon:
        first = daemon.wait_state("tracking", 60.0)["active_calibration"]["id"]
        texture = learn(daemon)
        assert texture["calibration"] == first and texture["restored"] == 0
        assert 0.0 < texture["footprint_scale"] and len(texture["newest"]) == min(3, texture["marks"])
        for mark in texture["newest"]:  # where on the print, how deep, how sure
            assert mark["from_mm"] <= mark["x_mm"] <= mark["to_mm"]
            assert 0.0 < mark["depth_sigma"] < abs(mark["depth"]) and mark["frames"] >= 10
        assert len(events(daemon, "texture_learned")) >= texture["marks"]
        saved = json.loads(kept.read_text())
        assert saved["calibration"] == first
        assert saved["model_sha256"] == hashlib.sha256((data / "model.json").read_bytes()).hexdigest()
        assert len(saved["texture"]["marks"]) >= 3
    on_disk = len(json.loads(kept.read_text())["texture"]["marks"])  # the shutdown's last write

    with LiveServer(create_app(settings)) as daemon:  # a restart on the same calibration: the marks come back
        assert daemon.wait_state("tracking", 60.0)["active_calibration"]["id"] == first
        texture = wait_for(lambda: daemon.status()["texture"], 10.0, "the restored tracker")
        assert texture["calibration"] == first and texture["restored"] == on_disk and texture["marks"] >= on_disk
        assert any(f"{on_disk} mark(s) learned on the print for calibration {first} restored" in message
                   for message in events(daemon, "texture_restored"))

        # a new calibration takes over: the file goes with the old model (or holds what the new one learns)
        job = daemon.post("/api/calibration", headers=daemon.auth()).json()["id"]
        wait_job(daemon.get, job, "done", 60.0)
        wait_for(lambda: (t := daemon.status()["texture"]) and t["calibration"] == job, 10.0, "the new tracker")
        assert not kept.exists() or json.loads(kept.read_text())["calibration"] == job
        # rolled back to the first calibration: what it had learned was dropped, it starts from its print
        assert daemon.post(f"/api/calibrations/{first}/activate", headers=daemon.auth()).status_code == 200
        texture = wait_for(lambda: (t := daemon.status()["texture"]) and t["calibration"] == first and t, 10.0,
                           "the first calibration's tracker")
        assert texture["restored"] == 0 and not kept.exists()

        # it learns again; activating the other calibration drops it, with the event, and removes the file
        learned = learn(daemon)
        assert learned["calibration"] == first and json.loads(kept.read_text())["calibration"] == first

        def switch_drops() -> list[str]:
            return [m for m in events(daemon, "texture_dropped") if f"(calibration {job} installed)" in m]

        before = len(switch_drops())
        assert daemon.post(f"/api/calibrations/{job}/activate", headers=daemon.auth()).status_code == 200
        wait_for(lambda: (t := daemon.status()["texture"]) and t["calibration"] == job, 10.0, "the other tracker")
        assert not kept.exists() or json.loads(kept.read_text())["calibration"] == job
        dropped = wait_for(lambda: switch_drops()[before:], 10.0, "the texture_dropped event of the rollback")
        assert re.match(r"\d+ mark\(s\) learned on the print dropped with the model", dropped[-1])
