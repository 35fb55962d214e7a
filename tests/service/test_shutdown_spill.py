"""A shutdown while the data directory cannot be written: what was kept in memory for it (a job's final
status, events) goes to the log in full, so it is still on record (the journal) rather than gone."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from graytrack.service.daemon.datadir import DataDirHealth, identity
from graytrack.service.daemon.event_log import EventLog
from graytrack.service.daemon.history import LabHistory

pytestmark = pytest.mark.unit
NO_DISK_HAS_THIS_MUCH = 1 << 62  # the directory reads as full however much it has free


def _logged(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


def test_a_final_status_kept_for_a_full_disk_is_logged_whole_at_shutdown(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    faults: list[str | None] = []
    health = DataDirHealth(tmp_path, identity(tmp_path), faults.append, min_free_bytes=NO_DISK_HAS_THIS_MUCH)
    written: list[dict] = []
    final = {"id": "20261127-030000", "state": "failed", "error": "disk full: the data directory ..."}
    health.defer("calibration 20261127-030000's final status (failed)", lambda: written.append(final), final)
    assert not health.probe() and health.pending == 1 and faults[-1].startswith("disk full")

    with caplog.at_level(logging.ERROR, logger="graytrack.daemon"):
        assert health.abandon() == 1
    assert health.pending == 0 and written == []
    (line,) = [m for m in _logged(caplog) if "final status" in m]
    assert json.loads(line.split("its content: ", 1)[1]) == final


def test_events_the_record_could_not_take_are_logged_with_their_times_at_shutdown(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    why: list[str | None] = ["the data directory was removed"]
    events = EventLog(LabHistory(tmp_path / "record.sqlite"), lambda: why[0], lambda reason: None,
                      max_age_days=30, max_count=1000)
    events.write("model_stale", "cause: scale", frame=1234)
    events.write("shutdown", "daemon stopped")
    assert events.pending == 2

    with caplog.at_level(logging.ERROR, logger="graytrack.daemon"):
        assert events.abandon() == 2
    kept = [json.loads(m.split("shutdown: ", 1)[1]) for m in _logged(caplog) if m.startswith("event not written")]
    assert [(e["kind"], e["message"]) for e in kept] == [("model_stale", "cause: scale"),
                                                         ("shutdown", "daemon stopped")]
    assert kept[0]["frame"] == 1234 and kept[0]["t_unix"] <= kept[1]["t_unix"]
    assert events.pending == 0
