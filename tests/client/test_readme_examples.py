"""README's REST and WebSocket block, run as written (bash, curl, the venv's websockets client) against
the daemon `make run` starts: the one change is the port (the daemon here listens on a free one). The
WebSocket client runs until stopped, as it would in a terminal: the block runs under a timeout and what
it printed is read."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess

import httpx
import pytest

from tests.client.conftest import ROOT, MakeRun
from tests.service.helpers import wait_for

README = ROOT / "README.md"
MAKE_RUN_HOST = "localhost:8000"
SECONDS = 20.0  # the calls, then the stream for the rest of it
RUN_S = 300.0  # the daemon's first start calibrates (~20 s here, minutes on a slow host)


def block(first_line: str) -> str:
    """The ```sh block of the README whose first line starts with ``first_line``."""
    for found in re.finditer(r"^```sh\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M):
        if found.group(1).startswith(first_line):
            return found.group(1)
    raise AssertionError(f"README.md: no sh block starting {first_line!r}")


@pytest.mark.skipif(shutil.which("curl") is None, reason="the README's block calls curl")
def test_the_readmes_rest_and_websocket_block_works_as_written(make_run: MakeRun) -> None:
    code = block("TOKEN=")
    assert MAKE_RUN_HOST in code and ".venv/bin/python" in code
    port = make_run.url.rsplit(":", 1)[1]
    wait_for(lambda: httpx.get(f"{make_run.url}/api/status", timeout=5).json()["state"] == "tracking",
             RUN_S, "the daemon to track, as the page shows it before a user turns to the README's calls")
    # stdin stays open, as a terminal's would (the websockets client ends the connection at its end),
    # until the stream has run; then ^C, as a user stops it
    keyboard, typing = os.pipe()
    try:
        with subprocess.Popen(["bash", "-c", code.replace(MAKE_RUN_HOST, f"localhost:{port}")], cwd=ROOT,
                              env=make_run.env(), stdin=keyboard, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, start_new_session=True) as shell:
            try:
                out, err = shell.communicate(timeout=SECONDS)
            except subprocess.TimeoutExpired:
                os.killpg(shell.pid, signal.SIGINT)
                out, err = shell.communicate(timeout=30)
    finally:
        os.close(keyboard), os.close(typing)
    decoder, text, answers = json.JSONDecoder(), out, []
    position = 0
    while (start := text.find("{", position)) >= 0:  # the answers and the messages, as printed
        value, position = decoder.raw_decode(text, start)
        answers.append(value)
    status, moved, started, latest, *messages = answers
    assert status["state"] == "tracking" and status["faults"] == {}, status
    assert moved["target_mm"] == 5.0, moved
    assert started["state"] in {"queued", "sweeping"} and started["id"] == latest["id"], (started, latest)
    assert latest["state"] in {"queued", "sweeping"} and 0.0 <= latest["progress"] < 1.0, latest
    assert len(messages) >= 10, out[-2000:]
    assert all({"seq", "t", "x_mm", "locked", "crlb_um"} <= set(m) for m in messages), messages[0]
    seqs = [m["seq"] for m in messages]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
