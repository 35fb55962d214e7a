"""Hostile local clients on raw sockets (what a careless or malicious program on the rig's PC can do),
shared by tests/service/test_limits.py, test_pipeline_flood.py, bench/hostile_clients.py and
bench/pipeline_flood.py.

Raw sockets, not a WebSocket or HTTP library: a library refuses to declare a 15 MiB frame and then not
send it, to trickle a request head a byte at a time, or to write requests without waiting for answers,
which is exactly what these clients do.
"""

from __future__ import annotations

import base64
import json
import os
import resource
import selectors
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import psutil
from websockets.sync.client import connect

DECLARED_BYTES = 15 * 1024 * 1024  # the frame length each hostile WebSocket declares (issue #38)
SENT_BYTES = 14 * 1024 * 1024  # what it then sends of that payload


def raise_fd_limit(wanted: int) -> int:
    """Raise this process's soft limit on open files towards ``wanted`` (never above the hard limit)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = min(max(soft, wanted), hard)
    if target > soft:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    return target


def rss_mb(pid: int) -> float:
    return psutil.Process(pid).memory_info().rss / 2**20


def ws_handshake(port: int, timeout_s: float = 5.0) -> tuple[socket.socket, bytes]:
    """An upgraded connection to ``/ws/position`` and what the server answered to the handshake."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET /ws/position HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    answer = b""
    while b"\r\n\r\n" not in answer:
        chunk = sock.recv(4096)
        if not chunk:
            break
        answer += chunk
    return sock, answer


def masked_frame_head(opcode: int, length: int) -> bytes:
    """A client frame's head (FIN, opcode, mask bit, 64-bit length) and its masking key."""
    return struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, length) + os.urandom(4)


def close_code(data: bytes) -> tuple[int, str] | None:
    """The (code, reason) of the first server close frame in ``data`` (unmasked frames), or None."""
    i = data.find(b"\r\n\r\n")
    i = i + 4 if i >= 0 else 0
    while i + 2 <= len(data):
        opcode, n = data[i] & 0x0F, data[i + 1] & 0x7F
        i += 2
        if n == 126:
            n, i = struct.unpack("!H", data[i:i + 2])[0], i + 2
        elif n == 127:
            n, i = struct.unpack("!Q", data[i:i + 8])[0], i + 8
        if opcode == 0x8 and n >= 2:
            return struct.unpack("!H", data[i:i + 2])[0], data[i + 2:i + n].decode(errors="replace")
        i += n
    return None


@dataclass
class BigFrameClient:
    """A WebSocket that declares a ``DECLARED_BYTES`` frame and sends ``SENT_BYTES`` of it, then stays open."""

    port: int
    sent: int = 0
    error: str | None = None
    received: bytes = b""
    sock: socket.socket | None = None

    def run(self) -> None:
        try:
            self.sock, self.received = ws_handshake(self.port)
            self.sock.sendall(masked_frame_head(0x2, DECLARED_BYTES))
            block = os.urandom(64 * 1024)
            while self.sent < SENT_BYTES:
                self.sock.sendall(block)
                self.sent += len(block)
        except OSError as exc:  # the server closed it (what the limit does): reset or broken pipe
            self.error = type(exc).__name__
        if self.sock is not None:  # what the server answered, for a second (the stream may keep sending)
            deadline = time.monotonic() + 1.0
            self.sock.settimeout(0.2)
            try:
                while time.monotonic() < deadline and (chunk := self.sock.recv(65536)):
                    self.received += chunk
            except OSError:
                pass

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()


def big_frame_clients(port: int, n: int) -> list[BigFrameClient]:
    """``n`` :class:`BigFrameClient` run at once; returns when each has sent all or been cut off (sockets open)."""
    clients = [BigFrameClient(port) for _ in range(n)]
    threads = [threading.Thread(target=c.run) for c in clients]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    return clients


def idle_sockets(port: int, n: int, source: str = "127.0.0.1") -> list[socket.socket]:
    """``n`` connections that send nothing (refused or reset ones are left out), from the loopback address
    ``source`` (any 127.x.y.z: another client as the daemon counts them)."""
    socks = []
    for _ in range(n):
        try:
            socks.append(socket.create_connection(("127.0.0.1", port), timeout=5, source_address=(source, 0)))
        except OSError:
            pass
    return socks


def close_counting_open(socks: list[socket.socket]) -> int:
    """Close ``socks``; how many of them the server had not closed (no EOF, no reset yet)."""
    still_open = 0
    for s in socks:
        s.setblocking(False)
        try:
            still_open += s.recv(1) != b""
        except BlockingIOError:
            still_open += 1
        except OSError:
            pass
        s.close()
    return still_open


@dataclass
class Slowloris:
    """Connections that trickle a request head a byte every ``interval_s`` and never finish it; records when
    the server closed each (seconds after it opened) and what it answered."""

    port: int
    n: int
    interval_s: float = 0.2
    closed_after_s: list[float | None] = field(default_factory=list)
    answers: list[bytes] = field(default_factory=list)

    def run(self, give_up_s: float) -> None:
        head = f"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\nX-Slow: ".encode()
        selector = selectors.DefaultSelector()
        opened: list[float] = []
        self.closed_after_s = [None] * self.n
        self.answers = [b""] * self.n
        socks = []
        for i in range(self.n):
            s = socket.create_connection(("127.0.0.1", self.port), timeout=5)
            s.sendall(head)
            s.setblocking(False)
            socks.append(s)
            opened.append(time.monotonic())
            selector.register(s, selectors.EVENT_READ, i)
        deadline = time.monotonic() + give_up_s
        next_byte = time.monotonic() + self.interval_s
        while time.monotonic() < deadline and selector.get_map():
            for key, _ in selector.select(timeout=max(0.0, next_byte - time.monotonic())):
                i = key.data
                try:
                    chunk = socks[i].recv(4096)
                except OSError:
                    chunk = b""
                self.answers[i] += chunk
                if not chunk:  # closed by the server: when, to the select's resolution
                    self.closed_after_s[i] = time.monotonic() - opened[i]
                    selector.unregister(socks[i])
            if time.monotonic() >= next_byte:
                next_byte += self.interval_s
                for key in list(selector.get_map().values()):
                    try:
                        socks[key.data].send(b"a")
                    except OSError:
                        pass  # closed: the select sees it
        selector.close()
        for s in socks:
            s.close()


class StreamReader:
    """A real client on ``/ws/position`` in a thread: records every message's ``seq`` and arrival time."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.seqs: list[int] = []
        self.times: list[float] = []
        self.messages: list[dict[str, Any]] = []  # every message as received
        self.error: str | None = None
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            with connect(f"ws://127.0.0.1:{self.port}/ws/position", open_timeout=10) as ws:
                self._ready.set()
                while not self._stop.is_set():
                    message = json.loads(ws.recv(timeout=5))
                    self.messages.append(message)
                    self.seqs.append(message["seq"])
                    self.times.append(time.monotonic())
        except Exception as exc:  # noqa: BLE001 - reported by the caller
            self.error = f"{type(exc).__name__}: {exc}"
            self._ready.set()

    def __enter__(self) -> "StreamReader":
        self._thread.start()
        self._ready.wait(15)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def window(self, start: float, end: float) -> tuple[list[int], float]:
        """The seqs received in [start, end) on this process's monotonic clock, and their rate per second."""
        seqs = [s for s, t in zip(self.seqs, self.times) if start <= t < end]
        return seqs, len(seqs) / (end - start)


def gaps(seqs: list[int]) -> int:
    """Messages missing between consecutive seqs."""
    return sum(b - a - 1 for a, b in zip(seqs, seqs[1:]) if b > a + 1)


PIPELINE_BATCH = 100  # requests in one write (issue #48's probe)
FLOOD_READ_BYTES = 256 * 1024  # what one connection reads of its answers per wake-up


@dataclass
class PipelineFlood:
    """``n`` connections that each write ``method path`` requests (with ``body``, as JSON, where given; never a
    token) ``PIPELINE_BATCH`` at a time, pipelined (no
    waiting for answers), for ``seconds``, while reading whatever answers come back (``read_answers``; else
    they are left unread, the socket's buffers full). Non-blocking sockets and one select loop: the loop ends at
    its deadline whatever the daemon does. Counts bytes sent and the answers' status lines."""

    port: int
    n: int = 10
    seconds: float = 20.0
    path: str = "/api/status"
    read_answers: bool = True
    method: str = "GET"
    body: bytes = b""
    sent_requests: int = 0
    answers: int = 0
    statuses: dict[str, int] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    def run(self) -> None:
        head = f"{self.method} {self.path} HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\n"
        if self.body:
            head += f"Content-Type: application/json\r\nContent-Length: {len(self.body)}\r\n"
        request = (head + "\r\n").encode() + self.body
        batch = request * PIPELINE_BATCH
        selector = selectors.DefaultSelector()
        socks: list[socket.socket] = []
        pending: dict[int, memoryview] = {}
        tails: dict[int, bytes] = {}
        for i in range(self.n):
            s = socket.create_connection(("127.0.0.1", self.port), timeout=5)
            s.setblocking(False)
            socks.append(s)
            pending[i], tails[i] = memoryview(batch), b""
            selector.register(s, selectors.EVENT_WRITE | (selectors.EVENT_READ if self.read_answers else 0), i)
        deadline = time.monotonic() + self.seconds
        while time.monotonic() < deadline and selector.get_map():
            for key, mask in selector.select(timeout=max(0.0, min(0.2, deadline - time.monotonic()))):
                i, s = key.data, socks[key.data]
                try:
                    if mask & selectors.EVENT_READ:
                        chunk = s.recv(FLOOD_READ_BYTES)
                        if not chunk:
                            self.errors.append(f"connection {i} closed by the daemon")
                            selector.unregister(s)
                            continue
                        self._count(tails[i] + chunk, i, tails)
                    if mask & selectors.EVENT_WRITE:
                        sent = s.send(pending[i])
                        pending[i] = pending[i][sent:]
                        if not len(pending[i]):
                            self.sent_requests += PIPELINE_BATCH
                            pending[i] = memoryview(batch)
                except BlockingIOError:
                    pass
                except OSError as exc:
                    self.errors.append(f"connection {i}: {type(exc).__name__}")
                    selector.unregister(s)
        selector.close()
        for s in socks:
            s.close()

    def _count(self, data: bytes, i: int, tails: dict[int, bytes]) -> None:
        """Count the status lines in ``data``; keep its last bytes (a status line cut between two reads)."""
        start = 0
        while (found := data.find(b"HTTP/1.1 ", start)) >= 0 and found + 12 <= len(data):
            status = data[found + 9:found + 12].decode(errors="replace")
            self.statuses[status] = self.statuses.get(status, 0) + 1
            self.answers += 1
            start = found + 12
        tails[i] = data[max(start, len(data) - 11):]


# /metrics counters the flood's figures compare (service/daemon/metrics.py)
RIG_COUNTERS = {
    "frames": "graytrack_frames_total",  # camera frames received
    "frames_lost": "graytrack_frames_dropped_total",  # gaps in the camera's frame_id sequence
    "camera_dropped": "graytrack_camera_dropped_frames_total",  # lost or skipped by the camera itself
    "grating_errors": "graytrack_grating_errors_total",  # failed POS? readings: the stage link
    "faults": "graytrack_faults_total",  # faults raised (a stage that did not answer among them)
}


def rig_counters(base: str) -> dict[str, float]:
    """The rig's counters of :data:`RIG_COUNTERS` from one ``/metrics`` scrape."""
    import httpx

    text = httpx.get(f"{base}/metrics", timeout=10).text
    values = {line.split()[0]: float(line.split()[-1]) for line in text.splitlines()
              if line and not line.startswith("#")}
    return {key: values[name] for key, name in RIG_COUNTERS.items()}


def counter_deltas(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    return {key: after[key] - before[key] for key in before}


@dataclass
class FloodFigures:
    """A flood between two quiet windows of the same length on one daemon: its RSS and the rig's counters."""

    rss_before_mb: float
    rss_peak_mb: float  # the largest of the samples taken during the flood
    rss_after_mb: float  # at the end of the quiet window after the flood (its connections closed)
    quiet: dict[str, float]  # counter deltas over the quiet window before the flood
    flood: dict[str, float]  # over the flood
    quiet_after: dict[str, float]  # over the quiet window after it
    client: PipelineFlood


RSS_SAMPLE_S = 0.25
# The rig a flood is measured on in the tests (and bench/pipeline_flood.py --test-rig): the tests' fast rig with
# the virtual rig in a process of its own, as the daemon runs it by default: the daemon's interpreter then
# holds what the flood must not reach, the frame loop and the stage link
FLOOD_RIG: dict[str, dict[str, Any]] = {"camera": {"rig_process": True}}


def quiet_flood_quiet(base: str, pid: int, port: int, seconds: float, connections: int,
                      read_answers: bool = True, **request: Any) -> FloodFigures:
    """The rig's counters over ``seconds`` of quiet, over ``seconds`` of :class:`PipelineFlood` on
    ``connections`` connections (``request``: its method, path and body, where not reads of the status; RSS
    sampled every :data:`RSS_SAMPLE_S` meanwhile), and over ``seconds`` of quiet again once the flood's
    connections closed (what the host's load alone does to the rig, on both sides of the flood); RSS at the end."""
    start = rig_counters(base)
    time.sleep(seconds)
    quiet_end = rig_counters(base)
    before = rss_mb(pid)
    flood = PipelineFlood(port, connections, seconds, read_answers=read_answers, **request)
    thread = threading.Thread(target=flood.run, name="flood")
    flood_start = rig_counters(base)
    thread.start()
    peak = before
    while thread.is_alive():
        peak = max(peak, rss_mb(pid))
        thread.join(RSS_SAMPLE_S)
    flood_end = rig_counters(base)
    time.sleep(seconds)
    return FloodFigures(before, peak, rss_mb(pid), counter_deltas(start, quiet_end),
                        counter_deltas(flood_start, flood_end), counter_deltas(flood_end, rig_counters(base)), flood)
