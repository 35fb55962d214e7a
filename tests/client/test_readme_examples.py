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
import sys
import threading
import time
from pathlib import Path
from typing import IO

import httpx
import pytest

from tests.client.conftest import ROOT, MakeRun
from tests.doc_blocks import block as doc_block
from tests.service.helpers import free_port, wait_for

README = ROOT / "README.md"
MAKE_RUN_HOST = "localhost:8000"
SECONDS = 20.0  # at most: the calls, then the stream until it has printed what the test reads
CALLS = 4  # the block's curl calls, one JSON answer each, printed before the stream's messages
STREAM_MESSAGES = 10  # the stream's messages the test reads: the block is stopped (^C) once it printed them
RUN_S = 300.0  # the daemon's first start calibrates (~20 s here, minutes on a slow host)
INTERRUPTED_S = 15.0  # after each key (^C, ^C, ^D): the client's close handshake, its 10 s close timeout at most


class Printed:
    """What a process writes to ``stream`` (a binary pipe), read as it comes (the websockets client flushes each
    message; its line feed comes before the message, so lines would show each one a message late)."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.chunks: list[bytes] = []
        self.thread = threading.Thread(target=self._read, args=(stream.fileno(),), daemon=True)
        self.thread.start()

    def _read(self, fd: int) -> None:
        while chunk := os.read(fd, 65536):
            self.chunks.append(chunk)

    def text(self, ended: bool = False) -> str:
        """All read so far; with ``ended``, all there is (the process has exited: the pipe closes)."""
        if ended:
            self.thread.join(timeout=30)
        return b"".join(self.chunks).decode(errors="replace")


def json_values(text: str) -> list:
    """The JSON objects printed in ``text`` (the calls' answers, then the stream's messages), in order."""
    decoder, values, position = json.JSONDecoder(), [], 0
    while (start := text.find("{", position)) >= 0:
        try:
            value, position = decoder.raw_decode(text, start)
        except json.JSONDecodeError:  # one being printed as this was read
            break
        values.append(value)
    return values


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
    # until the stream has printed what is read below (SECONDS at most); then ^C, as a user stops it
    keyboard, typing = os.pipe()
    try:
        with subprocess.Popen(["bash", "-c", code.replace(MAKE_RUN_HOST, f"localhost:{port}")], cwd=ROOT,
                              env=make_run.env(), stdin=keyboard, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              start_new_session=True) as shell:
            out, err = Printed(shell.stdout), Printed(shell.stderr)
            deadline = time.monotonic() + SECONDS
            while shell.poll() is None and time.monotonic() < deadline \
                    and len(json_values(out.text())) < CALLS + STREAM_MESSAGES:
                time.sleep(0.1)
            # ^C as a user stops it; on a loaded machine the client may still be closing its connection: ^C
            # again, then ^D (the terminal's input ends: a client waiting on it exits)
            for key in ("^C", "^C", "^D"):
                if shell.poll() is not None:
                    break
                if key == "^C":
                    os.killpg(shell.pid, signal.SIGINT)
                else:
                    os.close(typing)
                    typing = -1
                try:
                    shell.wait(timeout=INTERRUPTED_S)
                except subprocess.TimeoutExpired:
                    pass
            if shell.poll() is None:
                os.killpg(shell.pid, signal.SIGKILL)
                raise AssertionError(f"the block still ran after ^C, ^C and ^D; it printed "
                                     f"{out.text()[-1500:]!r}, on stderr {err.text()[-1500:]!r}")
    finally:
        os.close(keyboard)
        if typing >= 0:
            os.close(typing)
    printed = out.text(ended=True)
    answers = json_values(printed)
    status, moved, started, latest, *messages = answers
    assert status["state"] == "tracking" and status["faults"] == {}, status
    assert moved["target_mm"] == 5.0, moved
    assert started["state"] in {"queued", "sweeping"} and started["id"] == latest["id"], (started, latest)
    assert latest["state"] in {"queued", "sweeping"} and 0.0 <= latest["progress"] < 1.0, latest
    assert len(messages) >= STREAM_MESSAGES, (printed[-2000:], err.text(ended=True)[-2000:])
    assert all({"seq", "t", "x_mm", "locked", "crlb_um"} <= set(m) for m in messages), messages[0]
    seqs = [m["seq"] for m in messages]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


def fifo_threads(pid: int) -> list[str]:
    """The names of the threads of process ``pid`` that run under SCHED_FIFO."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            # the daemon raises its threads with SCHED_RESET_ON_FORK, which the policy read back carries
            if os.sched_getscheduler(int(task.name)) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO:
                found.append((task / "comm").read_text().strip())
        except OSError:  # the thread ended meanwhile
            pass
    return found


@pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="no SCHED_FIFO on this platform")
def test_the_readmes_realtime_block_turns_sched_fifo_off(make_run: MakeRun, tmp_path: Path) -> None:
    """README's "Real-time priority": `make run`'s daemon, run as root, has threads under SCHED_FIFO; the
    block, saved as the configuration file, starts a daemon whose threads all run ordinary scheduling."""
    wait_for(lambda: httpx.get(f"{make_run.url}/api/status", timeout=5).json()["state"] == "tracking",
             RUN_S, "the daemon to track")
    if os.geteuid() == 0:  # the default takes it where the system grants it (root here)
        assert len(fifo_threads(make_run.pid)) >= 3, fifo_threads(make_run.pid)  # frame loop, event loop, poller
    config = tmp_path / "graytrack.toml"
    config.write_text(doc_block("README.md", "[daemon]", "toml").code)
    port, log = free_port(), tmp_path / "serve.log"
    with log.open("w") as sink:
        process = subprocess.Popen([sys.executable, "-m", "graytrack", "serve", "--config", str(config), "--host",
                                    "127.0.0.1", "--port", str(port), "--data-dir", str(tmp_path / "data")],
                                   cwd=ROOT, env=make_run.env(), stdout=sink, stderr=sink)
    try:
        def rig_open() -> bool:  # the frame loop and the grating poller run from here on
            assert process.poll() is None, log.read_text()[-2000:]
            try:
                return httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=5).json()["state"] in (
                    "calibrating", "tracking")
            except httpx.TransportError:
                return False

        wait_for(rig_open, RUN_S, "the daemon with the README's configuration to open the rig")
        assert fifo_threads(process.pid) == []
        assert "SCHED_FIFO" not in log.read_text()
    finally:
        process.terminate()
        process.wait(timeout=30)
