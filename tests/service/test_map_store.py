"""The keeping shared by every learned map (service/daemon/map_store.py), for both the print's texture and the
sensor's map: written atomically beside the model for the active calibration only, restored for that calibration
and that model file only, a damaged file ignored with an event, a full disk the storage fault with the state kept
in memory (on a real small file system), and both files removed by the one model switch (and put back by its
undo). The daemon's own runs: tests/service/test_texture_store.py, test_sensor_map_store.py."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from graytrack.core.estimator.print_map import PrintMap
from graytrack.core.estimator.sensor_map import SensorMap
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.map_store import SAVE_EVERY_S, MapKind, MapSnapshot, MapStore, Stores
from graytrack.service.daemon.print_map_store import PRINT_MAP
from graytrack.service.daemon.sensor_map_store import SENSOR_MAP
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.texture_store import TEXTURE
from tests.service.test_disk_full import fill, small_disk

ACTIVE, OLD = "20260101T000000000000Z", "20250101T000000000000Z"


def texture_state(marks: int) -> dict[str, Any]:
    """A texture state as core/texture.py writes it, with ``marks`` placeholder marks (the store does not read them)."""
    return {"version": 1, "rows": 1, "pixels": 100, "grid": {"origin_mm": 0.0, "step_mm": 0.003, "scale": 1.0},
            "marks": [{"describe": {"x_mm": 3.0 + k, "from_mm": 2.9 + k, "to_mm": 3.1 + k, "depth": 0.3,
                                    "depth_sigma": 0.01, "frames": 40, "learned_at": 100 * k}} for k in range(marks)]}


def sensor_state(marks: int) -> dict[str, Any]:
    """A sensor map's state as core/estimator/sensor_map.py writes it, with ``marks`` resolved specks of 3 pixels."""
    sensor = SensorMap(100, np.array([4.0, 0.1, 5.0]), 1.0, 5.0, np.ones(4), 100.0, 0.5, 2, 100)
    for k in range(marks):
        where = np.arange(10 * k, 10 * k + 3)
        sensor.touched[where] = True
        sensor.f[where], sensor.sff[where], sensor.see[where], sensor.evidence[where] = -0.3, 1e-4, 0.25, 40.0
        sensor.rivalry[where], sensor.travel[where] = 40.0, 2.0
    return sensor.state()


def print_state(marks: int) -> dict[str, Any]:
    """A print map's state as core/estimator/print_map.py writes it, with ``marks`` resolved specks of 3 nodes."""
    printed = PrintMap(np.arange(100) * 0.01, 1, 100, 0.0025, 0.0, 5.0, np.array([4.0, 0.1, 5.0]), 1.0, 5.0,
                       np.ones(2), 4)
    for k in range(marks):
        where = np.arange(100 * k + 10, 100 * k + 13)
        printed.touched[where], printed.f[where], printed.s[where] = True, -0.3, 1e-4
        printed.evidence[where], printed.hi[where] = 40.0, 2.0
    return printed.state()


KINDS = [(TEXTURE, texture_state), (SENSOR_MAP, sensor_state), (PRINT_MAP, print_state)]
IDS = [kind.name for kind, _ in KINDS]


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def store_on(storage: Storage, kind: MapKind, clock: Callable[[], float] | None = None,
             faults: Callable[[str | None], None] = lambda reason: None) -> tuple[MapStore, list[tuple[str, str]]]:
    said: list[tuple[str, str]] = []
    health = DataDirHealth(storage.root, storage.home, faults)
    return MapStore(kind, storage, health, clock or Clock(), lambda event, message: said.append((event, message))), said


@pytest.mark.parametrize("kind,state", KINDS, ids=IDS)
def test_a_full_disk_keeps_the_map_in_memory_raises_the_storage_fault_and_writes_it_when_space_returns(
        tmp_path: Path, kind: MapKind, state: Callable[[int], dict[str, Any]]) -> None:
    with small_disk(tmp_path / "disk", "2m") as disk:
        storage = Storage(disk / "data")
        storage.set_active(ACTIVE)
        (disk / "data" / "model.json").write_text("{}")
        faults: list[str | None] = []
        clock = Clock()
        store, _ = store_on(storage, kind, clock, faults.append)
        filler = fill(disk)
        learned = MapSnapshot(ACTIVE, state(2))
        store.save(learned)  # ENOSPC: a fault naming the disk, nothing half-written, the state kept
        assert faults and faults[-1].startswith("disk full") and not store.path.exists()
        assert not [p for p in storage.root.iterdir() if p.name.startswith(f".{kind.name}")]
        assert store.status(learned)["saved"] is False and store.newest(ACTIVE) is learned.state
        filler.unlink()
        assert store.health.probe()
        store.save(learned)  # throttled: tried again only SAVE_EVERY_S after the failure
        assert not store.path.exists()
        clock.t += SAVE_EVERY_S
        store.save(learned)
        document = json.loads(store.path.read_text())
        assert store.path.name == f"{kind.name}.json"
        assert document["calibration"] == ACTIVE and len(document[kind.name]["marks"]) == 2
        assert store.status(learned)["saved"] is True and store.status(learned)["marks"] == 2
        written = store.path.stat().st_ino
        clock.t += SAVE_EVERY_S
        again = MapSnapshot(ACTIVE, state(2))  # refined to the same figures: not written again
        store.save(again)
        assert store.path.stat().st_ino == written and store.status(again)["saved"] is True


@pytest.mark.parametrize("kind,state", KINDS, ids=IDS)
def test_a_map_of_another_calibration_or_model_or_a_damaged_file_is_never_restored(
        tmp_path: Path, kind: MapKind, state: Callable[[int], dict[str, Any]]) -> None:
    storage = Storage(tmp_path / "data")
    storage.set_active(ACTIVE)
    storage.model_path.write_text("{}")
    store, said = store_on(storage, kind)
    store.save(MapSnapshot(OLD, state(2)))  # an old model's tracker after the switch
    assert not store.path.exists()
    store.save(MapSnapshot(ACTIVE, state(1)), force=True)
    assert len(store.load(ACTIVE)["marks"]) == 1 and said[-1][0] == f"{kind.name}_restored"
    assert f"1 {kind.marks} for calibration {ACTIVE} restored from {kind.name}.json" in said[-1][1]
    assert store.status(MapSnapshot(ACTIVE, state(1)))["restored"] == 1
    assert store.status(MapSnapshot(OLD, state(1)))["restored"] == 0  # restored for another calibration
    storage.model_path.write_text('{"another": "model"}')  # the same id, another model.json: not its map
    assert store.load(ACTIVE) is None and said[-1][0] == f"{kind.name}_ignored"
    assert store.load(OLD) is None and "not for the model in use" in said[-1][1]
    for damaged, why in (("{not json", "cannot be read"), ('{"calibration": 1}', f"is not a {kind.name} this daemon"),
                         (json.dumps({kind.name: {"marks": 3}}), "is not a")):
        store.path.write_text(damaged)
        assert store.load(ACTIVE) is None and said[-1][0] == f"{kind.name}_ignored" and why in said[-1][1]
    store.ignored(ACTIVE, "100 samples, the map has 200")  # the tracker refused what was restored
    assert said[-1] == (f"{kind.name}_ignored", f"the {kind.marks} saved in {kind.name}.json do not fit the model of "
                                                f"calibration {ACTIVE} (100 samples, the map has 200): not restored")


def test_the_model_switch_removes_every_map_and_its_undo_puts_them_back(tmp_path: Path) -> None:
    """Activate and install share one switch (storage.switch_model): every map goes with the old model, or, when
    the switch is taken back (a record row that cannot be written), stays with it. Every kind's file is one the
    switch takes."""
    storage = Storage(tmp_path / "data")
    for calibration in (ACTIVE, "20260102T000000000000Z"):
        storage.calibration_dir(calibration).mkdir()
        (storage.calibration_dir(calibration) / "model.json").write_text(json.dumps({"id": calibration}))
    storage.switch_model(ACTIVE).commit()
    files = tuple(kind.file(storage) for kind, _ in KINDS)
    assert set(files) == set(storage.learned_map_paths)
    for path in files:
        path.write_text(json.dumps({"calibration": ACTIVE}))
    switch = storage.switch_model("20260102T000000000000Z")
    assert not any(path.exists() for path in files) and storage.active_id() == "20260102T000000000000Z"
    switch.undo()
    assert all(json.loads(path.read_text())["calibration"] == ACTIVE for path in files)
    assert storage.active_id() == ACTIVE
    storage.switch_model("20260102T000000000000Z").commit()
    assert not any(path.exists() for path in files)


def test_no_save_of_either_map_slips_in_while_the_switch_runs(tmp_path: Path) -> None:
    """The switch holds every store's lock: a save begun meanwhile writes after it, and then finds its calibration
    no longer active (nothing written), and neither store says it restored anything any more."""
    storage = Storage(tmp_path / "data")
    storage.set_active(ACTIVE)
    storage.model_path.write_text("{}")
    stores = [store_on(storage, kind)[0] for kind, _ in KINDS]
    for store, (_, state) in zip(stores, KINDS):
        store.save(MapSnapshot(ACTIVE, state(1)), force=True)
        assert store.load(ACTIVE) is not None
    inside, release = threading.Event(), threading.Event()
    saves = []

    def switch_model() -> str:
        inside.set()
        for store, (_, state) in zip(stores, KINDS):
            saving = threading.Thread(target=store.save, args=(MapSnapshot(ACTIVE, state(3)), True))
            saving.start()
            saves.append(saving)
        release.wait(0.2)  # time for a save that took no lock to write (none does: they wait on the locks)
        assert all(saving.is_alive() for saving in saves)
        for store in stores:
            store.path.unlink()
        storage.set_active(OLD)
        return "switched"

    assert Stores(*stores).switch(switch_model) == "switched"
    for saving in saves:
        saving.join(5.0)
    assert inside.is_set() and not any(store.path.exists() for store in stores)
    assert all(store.status(MapSnapshot(ACTIVE, state(1)))["restored"] == 0 for store, (_, state) in zip(stores, KINDS))
