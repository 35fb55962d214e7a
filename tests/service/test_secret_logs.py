"""The token in no line of the daemon's log: a real ``graytrack serve`` (reads need the token everywhere,
``read_token = "always"``, so every way of passing it is exercised on loopback) at ``debug`` and ``info``,
the token passed every documented way, right and wrong; then its whole stderr is searched."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tests.service.helpers import ServeProcess

WRONG = "a-wrong-token-someone-typed-0123456789"


@pytest.mark.parametrize("level", ["debug", "info"])
def test_the_token_passed_every_documented_way_is_in_no_line_of_the_log(tmp_path: Path, level: str) -> None:
    stdout = tmp_path / "stdout.log"  # uvicorn's access log goes there
    with ServeProcess(tmp_path, stdout_path=stdout, daemon={"auto_calibrate": "never", "read_token": "always",
                                        "log_level": level}) as daemon:
        daemon.wait_state("idle")
        token = (tmp_path / "data" / "token").read_text().strip()
        ws = f"ws://127.0.0.1:{daemon.port}/ws/position"
        # the stream: the query (the line uvicorn writes with the target), the subprotocol, the header
        with connect(f"{ws}?max_rate=5&token={token}", open_timeout=10) as stream:
            assert stream.subprotocol is None
        with connect(f"{ws}?max_rate=5", subprotocols=["graytrack", f"graytrack.bearer.{token}"],  # type: ignore[list-item]
                     open_timeout=10) as stream:
            assert stream.subprotocol == "graytrack", "the plain protocol answered, never the token"
        with connect(ws, additional_headers={"Authorization": f"Bearer {token}"}, open_timeout=10):
            pass
        for wrong in (f"{ws}?token={WRONG}", ws):
            with pytest.raises(InvalidStatus) as refused:
                connect(wrong, open_timeout=10)
            assert refused.value.response.status_code == 403
        # reads: the header, the query (a download link); a state change with the header
        assert daemon.get("/api/status", headers={"Authorization": f"Bearer {token}"}).status_code == 200
        assert daemon.get(f"/api/events?token={token}").status_code == 200
        assert daemon.get(f"/api/status?token={WRONG}").status_code == 401
        assert daemon.get("/api/status").status_code == 401
        assert httpx.post(f"{daemon.base}/api/stage/move", json={"target_mm": 1.0}, timeout=5,
                          headers={"Authorization": f"Bearer {token}"}).status_code == 202
        assert daemon.terminate() == 0
    log = daemon.stderr + stdout.read_text()
    assert token not in log and WRONG not in log, [line for line in log.splitlines() if token in line or WRONG in line]
    assert "/ws/position?max_rate=5&token=[redacted]" in log, "the handshake's line was written, redacted"
    if level == "debug":  # the handshake's headers, as the WebSocket protocol logs them at debug
        assert "graytrack.bearer.[redacted]" in log and "authorization: Bearer [redacted]" in log, log[-3000:]
