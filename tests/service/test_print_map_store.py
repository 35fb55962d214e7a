"""What the estimator learns on the print is part of the model of record (service/daemon/map_store.py,
print_map_store.py): through a real daemon with ``[daemon] engine = "estimator"`` on the virtual rig, dust settles
on the print (the model was not told about it); the print's map learns it once the motion has carried it across
the pixels, says so in the event log, shows it in ``/api/status`` and ``/api/maps``, and writes it beside the model
(``DATA/print_map.json``). The daemon restarted on the same data directory, with the dust still on the print,
restores the map and tracks with it, losing no frame; a new calibration drops it with its model, and a rollback to
the first calibration starts that model from the print as calibrated, its file gone. Nothing of the print's dust is
learned into the sensor's map."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings, wait_for
from tests.service.hostile import StreamReader
from tests.service.test_sensor_map_store import (LANDS, events, logged, lost_and_flagged, passes,
                                                 restored_and_passed, switched_away_and_back)

# specks settle on the print after the daemon's first calibration, while the stage rests (LANDS, rig seconds) ...
SETTLING = {"camera": {"effects": f"dust_settling:start_s={LANDS[0]:g},over_s={LANDS[1] - LANDS[0]:g}"}}
# ... and, for the daemon started again, the same specks (the effect's own random stream) on the print from the start
ON_THE_PRINT = {"camera": {"effects": "dust_settling:start_s=0,over_s=0"}}
LEARNED_MARKS = 3  # marks the map has learned before the first session is measured (thirty specks over the stroke)
# a restored session's first pass decides again the specks the first session had not (they come back as candidates
# just landed: core/estimator/print_map.py restore): issue #49's share for dust on the print, not a steady run's
DUST_FLAGS = 0.05


def one_pixel(told: list[str]) -> bool:
    """Whether every mark told on the sensor's side is a single pixel. Known: in ~2 of 10 sessions with dust on the
    print, one pixel is told for a while as a contrast change (gain ≈ 1.1-1.25, offset ≈ −13 to −18 gray), its
    evidence over both the calibration and the print's candidate far past the test (the frames at that pixel do
    beat both accounts: not yet traced); counted in docs/daemon.md. Anything wider is a failure."""
    return all(re.search(r"pixels (\d+)-\1:", message) for message in told)


def learn(daemon: LiveServer, stream: StreamReader | None = None) -> dict:
    """Passes of the print until the map has learned ``LEARNED_MARKS`` and the daemon has written it: the status's
    ``print_map`` then."""
    for _ in range(8):
        passes(daemon, 1, stream)
        if daemon.status()["print_map"]["marks"] >= LEARNED_MARKS:  # at rest, the map settles and is written
            return wait_for(lambda: (m := daemon.status()["print_map"])["saved"] and m, 20.0, "the map written",
                            show=lambda: daemon.status()["print_map"])
    raise AssertionError(f"nothing learned of the print's dust: {daemon.status()['print_map']}")


def test_the_print_map_survives_a_restart_and_a_rollback_drops_it(tmp_path: Path, calibrated) -> None:
    data = calibrated(tmp_path / "data")  # the daemon's first calibration, done: the dust settles after it
    kept = data / "print_map.json"
    with LiveServer(create_app(fast_settings(data, tables=SETTLING, engine="estimator"))) as daemon:
        first = daemon.after_calibration(LANDS)["active_calibration"]["id"]
        assert daemon.status()["texture"] is None  # the estimator's print is its print map
        with StreamReader(daemon.port) as stream:
            learn(daemon, stream)
            lost_before, flagged_before = lost_and_flagged(passes(daemon, 1, stream))
        learned = daemon.status()["print_map"]
        assert learned["calibration"] == first and learned["restored"] == 0 and learned["marks"] >= LEARNED_MARKS
        assert learned["touched_nodes"] >= learned["learned_nodes"] > 0 and 0.0 < learned["node_mm"] < 0.1
        stroke = daemon.get("/api/maps").json()["stroke_mm"]
        for mark in learned["shown"]:  # where on the print (the stroke and the field beyond it: 100 px of 62 µm),
            # how much, how sure: dust takes light
            assert stroke[0] - 1.0 < mark["from_mm"] <= mark["x_mm"] <= mark["to_mm"] < stroke[1] + 7.5
            assert 0.0 < mark["reflectance_sigma"] < 1.0 - mark["reflectance"]
        said = events(daemon, "print_map_learned")
        assert len(said) >= learned["marks"] and "on the print" in said[0] and "+/-" in said[0]
        # told apart: the print's dust is not held on the sensor's side
        assert daemon.status()["sensor_map"]["learned_samples"] == 0
        assert one_pixel(events(daemon, "sensor_map_learned"))
        along = daemon.get("/api/maps").json()["print_map"]
        assert len(along["x_mm"]) == len(along["reflectance"]) == len(along["reflectance_sigma"]) == \
            len(along["learned"]) == len(set(along["x_mm"]))
        assert sum(along["learned"]) >= 1 and min(along["reflectance"]) < 0.9
        assert along["marks"] and all(m["from_mm"] <= m["x_mm"] <= m["to_mm"] for m in along["marks"])
        assert daemon.get("/api/maps", params={"row": 1}).status_code == 422  # the model has one row
        saved = json.loads(kept.read_text())
        assert saved["calibration"] == first
        assert saved["model_sha256"] == hashlib.sha256((data / "model.json").read_bytes()).hexdigest()
        first_session = logged(daemon)[-1]["id"]
    on_disk = json.loads(kept.read_text())["print_map"]  # the shutdown's last write
    assert len(on_disk["marks"]) >= LEARNED_MARKS

    # started again on the same data directory, the dust still on the print: the map comes back and is used
    with LiveServer(create_app(fast_settings(data, tables=ON_THE_PRINT, engine="estimator"))) as daemon:
        assert lost_before == 0.0
        restored_and_passed(daemon, "print_map", "the print", first, len(on_disk["marks"]), flagged_before,
                            DUST_FLAGS)
        assert daemon.status()["print_map"]["learned_nodes"] >= 0.75 * sum(on_disk["learned"])
        assert one_pixel(events(daemon, "sensor_map_learned", after=first_session))

        assert switched_away_and_back(daemon, "print_map", "the print", kept, first)["learned_nodes"] == 0
