"""What the daemon learns on the print is part of the model of record (service/daemon/texture_store.py):
written beside the model (``DATA/texture.json``, tied to the active calibration), shown in
``/api/status``, restored into the tracker at a restart on the same calibration, and dropped, with
an event, when another model takes over (a rollback). Through a real daemon on the virtual rig
with dust settling on its print (the model was not told about the dust), and, for a full disk, a
real small file system."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path


from graytrack.service.daemon.app import create_app
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.texture_store import SAVE_EVERY_S, TextureSnapshot, TextureStore
from tests.service.helpers import LiveServer, fast_settings, wait_for, wait_job
from tests.service.test_disk_full import fill, small_disk

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


def test_a_model_switch_removes_the_texture_and_its_undo_puts_it_back(tmp_path: Path) -> None:
    """Activate and install share one switch (storage.switch_model): the texture goes with the old model, or,
    when the switch is taken back (a record row that cannot be written), stays with it."""
    storage = Storage(tmp_path / "data")
    for calibration in ("20260101T000000000000Z", "20260102T000000000000Z"):
        storage.calibration_dir(calibration).mkdir()
        (storage.calibration_dir(calibration) / "model.json").write_text(json.dumps({"id": calibration}))
    storage.switch_model("20260101T000000000000Z").commit()
    storage.texture_path.write_text('{"calibration": "20260101T000000000000Z"}')
    switch = storage.switch_model("20260102T000000000000Z")
    assert not storage.texture_path.exists() and storage.active_id() == "20260102T000000000000Z"
    switch.undo()
    assert json.loads(storage.texture_path.read_text())["calibration"] == storage.active_id()
    assert storage.active_id() == "20260101T000000000000Z"
    storage.switch_model("20260102T000000000000Z").commit()
    assert not storage.texture_path.exists()


def snapshot(calibration: str | None, marks: int) -> TextureSnapshot:
    """A texture state as core/texture.py writes it, with ``marks`` placeholder marks (the store does not read them)."""
    return TextureSnapshot(calibration, {"version": 1, "rows": 1, "pixels": 100,
                                         "grid": {"origin_mm": 0.0, "step_mm": 0.003, "scale": 1.0},
                                         "marks": [{"describe": {"x_mm": 3.0 + k, "from_mm": 2.9 + k, "to_mm": 3.1 + k,
                                                                 "depth": 0.3, "depth_sigma": 0.01, "frames": 40,
                                                                 "learned_at": 100 * k}} for k in range(marks)]})


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_full_disk_keeps_the_texture_in_memory_raises_the_storage_fault_and_writes_it_when_space_returns(
        tmp_path: Path) -> None:
    with small_disk(tmp_path / "disk", "2m") as disk:
        storage = Storage(disk / "data")
        calibration = "20260101T000000000000Z"
        storage.set_active(calibration)
        (disk / "data" / "model.json").write_text("{}")
        faults: list[str | None] = []
        said: list[tuple[str, str]] = []
        health = DataDirHealth(storage.root, storage.home, faults.append)
        clock = Clock()
        store = TextureStore(storage, health, clock, lambda kind, message: said.append((kind, message)))
        filler = fill(disk)
        learned = snapshot(calibration, 2)
        store.save(learned)  # ENOSPC: a fault naming the disk, nothing half-written, the state kept
        assert faults and faults[-1].startswith("disk full") and not storage.texture_path.exists()
        assert not [p for p in storage.root.iterdir() if p.name.startswith(".texture")]
        assert store.status(learned)["saved"] is False and store.newest(calibration) is learned.state
        filler.unlink()
        assert health.probe()
        store.save(learned)  # throttled: tried again only SAVE_EVERY_S after the failure
        assert not storage.texture_path.exists()
        clock.t += SAVE_EVERY_S
        store.save(learned)
        document = json.loads(storage.texture_path.read_text())
        assert document["calibration"] == calibration and len(document["texture"]["marks"]) == 2
        assert store.status(learned)["saved"] is True
        written = storage.texture_path.stat().st_ino
        clock.t += SAVE_EVERY_S
        again = snapshot(calibration, 2)  # refined to the same figures: not written again
        store.save(again)
        assert storage.texture_path.stat().st_ino == written and store.status(again)["saved"] is True


def test_a_texture_of_another_calibration_is_neither_written_nor_restored(tmp_path: Path) -> None:
    storage = Storage(tmp_path / "data")
    storage.set_active("20260101T000000000000Z")
    storage.model_path.write_text("{}")
    said: list[tuple[str, str]] = []
    health = DataDirHealth(storage.root, storage.home, lambda reason: None)
    store = TextureStore(storage, health, Clock(), lambda kind, message: said.append((kind, message)))
    store.save(snapshot("20250101T000000000000Z", 2))  # an old model's tracker after the switch
    assert not storage.texture_path.exists()
    store.save(snapshot("20260101T000000000000Z", 1), force=True)
    assert store.load("20260101T000000000000Z")["marks"] and said[-1][0] == "texture_restored"
    storage.model_path.write_text('{"another": "model"}')  # the same id, another model.json: not its marks
    assert store.load("20260101T000000000000Z") is None and said[-1][0] == "texture_ignored"
    assert store.load("20250101T000000000000Z") is None and "not for the model in use" in said[-1][1]
    storage.texture_path.write_text("{not json")
    assert store.load("20260101T000000000000Z") is None and "cannot be read" in said[-1][1]
