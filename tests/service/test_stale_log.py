"""The event log's account of the stale flag (service/daemon/stale_log.py): a single flagged frame is
named as one, a model gone stale is logged once with the frame it began on and its advice."""

from __future__ import annotations

import pytest

from graytrack.service.daemon.stale_log import StaleLog

pytestmark = pytest.mark.unit


def _logged(flags: list[str | None]) -> list[tuple[str, str]]:
    events: list[tuple[str, str]] = []
    log = StaleLog(lambda kind, message: events.append((kind, message)))
    for frame_id, family in enumerate(flags, start=100):
        log.observe(frame_id, family)
    return events


def test_one_frame_flagged_between_clear_ones_is_named_as_a_single_frame_not_a_stale_model() -> None:
    events = _logged([None] * 5 + ["scale"] + [None] * 5)
    assert [kind for kind, _ in events] == ["frame_flagged"]
    assert "frame 105" in events[0][1] and "scale" in events[0][1] and "recalibrate" not in events[0][1]


def test_a_lasting_flag_is_one_stale_event_naming_its_first_frame_then_fresh_when_it_clears() -> None:
    events = _logged([None] * 3 + ["focus"] * 20 + [None] * 3)
    assert [kind for kind, _ in events] == ["model_stale", "model_fresh"]
    assert "since frame 103" in events[0][1] and "lens" in events[0][1]  # the family's advice


def test_a_change_of_cause_while_stale_is_logged_and_a_flag_on_the_last_frame_waits_for_the_next() -> None:
    events = _logged(["light", "light", "geometry", "geometry", None, "pixels"])
    assert [kind for kind, _ in events] == ["model_stale", "model_stale", "model_fresh"]
    assert "light" in events[0][1] and "geometry" in events[1][1] and "since" not in events[1][1]
