"""The event log's account of frames lost between the camera and the tracker (service/daemon/loss_log.py):
the count the page shows (the stream's ``dropped``) always has events that add up to it."""

from __future__ import annotations


import pytest

from graytrack.service.daemon.loss_log import LossLog

pytestmark = pytest.mark.unit


def _events(frame_ids: list[int], period_s: float = 0.01) -> tuple[list[tuple[str, str]], LossLog]:
    events: list[tuple[str, str]] = []
    log = LossLog(lambda kind, message: events.append((kind, message)), quiet_s=10.0)
    last = None
    for i, frame_id in enumerate(frame_ids):
        log.observe(frame_id - last - 1 if last is not None else 0, frame_id, i * period_s)
        last = frame_id
    return events, log


def test_a_run_without_gaps_logs_nothing() -> None:
    events, log = _events(list(range(5000)))
    assert events == [] and log.total == 0


def test_the_first_gap_is_logged_at_once_and_later_ones_summed_into_one_event_when_the_quiet_period_ends() -> None:
    # frames 10 ms apart on the clock; gaps of 3 before frame 103, 5 before 405 and 2 before 602, none after
    ids = list(range(100)) + list(range(103, 400)) + list(range(405, 600)) + list(range(602, 1500))
    events, log = _events(ids)
    assert [kind for kind, _ in events] == ["frames_lost", "frames_lost"]
    assert events[0][1].startswith("3 camera frames lost before frame 103") and events[0][1].endswith("3 since start")
    assert "(the frame loop fell behind the camera, or the link lost them)" in events[0][1]
    # the two gaps in the quiet period: one event once it ends (10 s after the first), no further gap needed
    assert events[1][1].startswith("7 camera frames lost in 2 gaps between frames 405 and 602")
    assert events[1][1].endswith("10 since start") and log.total == 10
    # the events add up to the count the page shows
    assert sum(int(message.split()[0]) for _, message in events) == log.total


def test_one_frame_lost_is_said_in_the_singular() -> None:
    events, _ = _events(list(range(10)) + list(range(11, 20)))
    assert events == [("frames_lost", events[0][1])] and events[0][1].startswith("1 camera frame lost before frame 11")


def test_the_quiet_period_is_a_daemon_setting_of_10_s_by_default() -> None:
    from pydantic import ValidationError

    from graytrack.service.daemon.loss_log import QUIET_S
    from graytrack.service.daemon.settings import DaemonConfig

    assert QUIET_S == 10.0 and DaemonConfig().frames_lost_quiet_s == QUIET_S
    assert DaemonConfig(frames_lost_quiet_s=0.5).frames_lost_quiet_s == 0.5
    with pytest.raises(ValidationError, match="frames_lost_quiet_s"):
        DaemonConfig(frames_lost_quiet_s=0)
