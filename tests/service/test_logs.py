"""The daemon's log on its own (service/daemon/logs.py): secrets redacted from every part of a record, and
uvicorn's per-request lines summarised per window on an injected clock while every other line passes."""

from __future__ import annotations

import logging
import sys

import pytest

from graytrack.service.daemon.logs import REDACTED, VERBATIM_LINES, WINDOW_S, FloodGate, Redact
from tests.service.helpers import Lines

pytestmark = pytest.mark.unit
TOKEN = "s3cr3t-t0ken-0f-32-characters-xyz"




class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _record(name: str, level: int, msg: str, *args: object, exc_info: object = None) -> logging.LogRecord:
    return logging.LogRecord(name, level, __file__, 1, msg, args, exc_info)  # type: ignore[arg-type]


def test_the_token_is_redacted_from_the_message_its_arguments_and_a_traceback() -> None:
    redact, lines = Redact(), Lines()
    redact.secrets.add(TOKEN)
    lines.addFilter(redact)
    try:
        raise ValueError(f"bad header Authorization: Bearer {TOKEN}")
    except ValueError:
        failure = sys.exc_info()
    records = [
        _record("uvicorn.error", logging.INFO, '%s - "WebSocket %s" [accepted]', "127.0.0.1:5000",
                f"/ws/position?max_rate=10&token={TOKEN}"),
        _record("uvicorn.access", logging.INFO, '%s - "%s %s HTTP/%s" %d', "127.0.0.1:5001", "GET",
                f"/api/status?token={TOKEN}", "1.1", 200),
        _record("graytrack.daemon", logging.ERROR, f"the token {TOKEN} in a message", exc_info=failure),
        _record("websockets", logging.DEBUG, "offered %s", f"graytrack, graytrack.bearer.{TOKEN}"),
        # a wrong token is someone's secret too: taken out by its place, not its value
        _record("uvicorn.error", logging.INFO, '%s - "WebSocket %s" 403', "10.0.0.9:5002",
                "/ws/position?token=not-the-token-but-a-secret&max_rate=5"),
        _record("x", logging.INFO, "%(url)s", {"url": f"http://h/?token={TOKEN}"}),  # mapping arguments
    ]
    for record in records:
        lines.handle(record)
    text = "\n".join(lines.lines)
    assert TOKEN not in text and "not-the-token-but-a-secret" not in text, text
    assert text.count(REDACTED) >= 7, text
    assert "/ws/position?max_rate=10&token=[redacted]" in text and "ValueError: bad header" in text
    assert "token=[redacted]&max_rate=5" in text, "the rest of the target is kept"


def test_a_flood_is_summarised_per_window_by_source_and_reason_and_faults_always_pass() -> None:
    clock, lines = Clock(), Lines()
    summary = logging.getLogger("test.logs.summary")
    summary.propagate, summary.level = False, logging.DEBUG
    summary.addHandler(lines)
    gate = FloodGate(clock, summary)

    def request(record: logging.LogRecord) -> None:
        if gate.filter(record):
            lines.handle(record)

    # 10,000 requests over 25 s: three sources and reasons, a stage fault and an error in the middle
    for k in range(10_000):
        clock.now = 1000.0 + 25.0 * k / 10_000
        if k % 3 == 0:
            request(_record("uvicorn.access", logging.INFO, '%s - "%s %s HTTP/%s" %d', f"192.0.2.7:{40000 + k % 999}",
                            "POST", "/api/stage/move", "1.1", 401))
        elif k % 3 == 1:
            request(_record("uvicorn.error", logging.WARNING, "Invalid HTTP request received."))
        else:
            request(_record("uvicorn.error", logging.INFO, '%s - "WebSocket %s" 403', f"198.51.100.3:{k}",
                            "/ws/position"))
        if k == 5000:
            request(_record("graytrack.daemon", logging.WARNING, "stage fault: %s", "no reply to 'POS? 1'"))
            request(_record("uvicorn.error", logging.ERROR, "Exception in ASGI application"))
    clock.now += WINDOW_S
    gate.flush()
    windows = 3  # 0-10, 10-20, 20-25 s
    assert len(lines.lines) <= windows * (VERBATIM_LINES + 3) + 2, lines.lines
    assert "WARNING graytrack.daemon: stage fault: no reply to 'POS? 1'" in lines.lines
    assert "ERROR uvicorn.error: Exception in ASGI application" in lines.lines
    first = [line for line in lines.lines if "in the last 10 s" in line][:3]
    assert set(first) == {  # the first window: 4,000 requests, a third of them each
        "WARNING test.logs.summary: 1333 requests refused in the last 10 s from an unknown address: "
        "Invalid HTTP request received",
        "WARNING test.logs.summary: 1333 requests refused in the last 10 s from 198.51.100.3: "
        "WebSocket handshake refused (403)",
        "WARNING test.logs.summary: 1334 requests refused in the last 10 s from 192.0.2.7: 401 Unauthorized"}, first
    counted = sum(int(line.split(": ", 1)[1].split()[0]) for line in lines.lines if "in the last 10 s" in line)
    assert counted == 10_000, "every request is in a summary"


def test_a_lone_request_is_written_whole_and_summaries_wait_for_the_window_to_end() -> None:
    clock, lines = Clock(), Lines()
    summary = logging.getLogger("test.logs.summary2")
    summary.propagate = False
    summary.addHandler(lines)
    gate = FloodGate(clock, summary)
    records = [_record("uvicorn.error", logging.INFO, '%s - "WebSocket %s" [accepted]', "127.0.0.1:1", "/ws/position")
               for _ in range(VERBATIM_LINES + 2)]
    assert [gate.filter(r) for r in records] == [True] * VERBATIM_LINES + [False, False]
    clock.now += WINDOW_S - 0.001
    assert gate.flush() == []
    clock.now += 0.001
    assert gate.flush() == ["5 requests served in the last 10 s from 127.0.0.1: WebSocket accepted"]
    assert gate.filter(records[0]), "a new window writes its first lines again"
    assert gate.filter(_record("uvicorn.error", logging.INFO, "Application startup complete.")), "not a request"
