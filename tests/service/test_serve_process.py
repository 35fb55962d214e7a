"""``graytrack serve`` as a real process on a free loopback port: HTTP, WebSocket, SIGTERM."""

from __future__ import annotations

import json
import stat
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from graytrack.service.cli import main
from tests.service.helpers import ServeProcess


def test_serve_process_tracks_streams_and_shuts_down_cleanly(tmp_path: Path) -> None:
    with ServeProcess(tmp_path) as daemon:
        daemon.wait_state("tracking")
        assert stat.S_IMODE((tmp_path / "data" / "token").stat().st_mode) == 0o600
        moved = httpx.post(f"{daemon.base}/api/stage/move", json={"target_mm": 6.5}, headers=daemon.auth())
        assert moved.status_code == 202

        with connect(f"ws://127.0.0.1:{daemon.port}/ws/position", open_timeout=5) as ws:
            messages = [json.loads(ws.recv(timeout=5)) for _ in range(100)]
        assert [m["seq"] for m in messages] == list(range(messages[0]["seq"], messages[0]["seq"] + 100))
        assert all({"seq", "t", "x_mm", "locked"} <= m.keys() for m in messages)
        page = httpx.get(f"{daemon.base}/")
        assert page.status_code == 200 and 'id="position"' in page.text
        assert httpx.get(f"{daemon.base}/static/app.js").status_code == 200
        assert "graytrack_frames_tracked_total" in httpx.get(f"{daemon.base}/metrics").text
        assert daemon.terminate() == 0, daemon.stderr
    assert "hardware closed" in daemon.stderr and "Traceback" not in daemon.stderr
    assert "Warning" not in daemon.stderr, "no deprecation warning at start (uvicorn's websockets-sansio)"


@pytest.mark.parametrize("content, message", [
    ("[sweeep]\npositions = 3\n", "sweeep: unknown table"),
    ("[daemon]\nport = 99999\n", "daemon.port: Input should be less than or equal to 65535"),
    ("[sweep]\nframes_per_position = 2\n", "sweep.frames_per_position"),
    ("[stage]\nbaudrate = 1234\n", "stage.baudrate"),
])
def test_serve_refuses_a_bad_config_in_one_line(tmp_path: Path, content: str, message: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(content)
    assert main(["serve", "--config", str(config)]) == 2  # the CLI's path, in-process (no daemon starts)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("graytrack serve: error: ") and message in lines[0], lines
