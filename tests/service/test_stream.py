"""The position stream through a real uvicorn server: defined instants, visible drops, decimation,
and grating references that are right or absent while the stage moves."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from websockets.sync.client import connect

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    with LiveServer(create_app(fast_settings(tmp_path_factory.mktemp("stream")))) as server:
        server.wait_state("tracking")
        yield server


def _collect(daemon: LiveServer, count: int, query: str = "") -> list[tuple[float, dict]]:
    """``count`` messages with the monotonic time each was received."""
    received = []
    with connect(f"ws://127.0.0.1:{daemon.port}/ws/position{query}", open_timeout=5) as ws:
        for _ in range(count):
            text = ws.recv(timeout=5)
            received.append((time.monotonic(), json.loads(text)))
    return received


def test_messages_carry_host_time_wall_time_and_age(daemon: LiveServer) -> None:
    received = _collect(daemon, 200)
    t = np.array([m["t"] for _, m in received])
    arrival = np.array([r for r, _ in received])
    latency = arrival - t
    # t is mid-exposure on this process's time.monotonic(): received after it, and soon after
    assert np.all(latency > 0) and np.median(latency) < 0.1, np.percentile(latency, [0, 50, 100])
    age = np.array([m["age_ms"] for _, m in received]) * 1e-3
    assert np.all(age >= 0) and np.all(age <= latency + 1e-3), "age is taken at send, before receipt"
    offset = np.array([m["t_unix"] for _, m in received]) - t
    assert abs(np.median(offset) - (time.time() - time.monotonic())) < 0.05 and np.ptp(offset) < 0.01
    ids = np.array([m["frame_id"] for _, m in received])
    dropped = np.array([m["dropped"] for _, m in received])
    # every camera frame not in the stream is counted: frame_id gaps add up to the dropped counter
    assert (ids[-1] - ids[0]) - (len(ids) - 1) == dropped[-1] - dropped[0]


def test_a_page_asks_for_a_decimated_stream(daemon: LiveServer) -> None:
    received = _collect(daemon, 12, "?max_rate=20")
    t = np.array([m["t"] for _, m in received])
    assert np.min(np.diff(t)) >= 0.05 - 1e-6, "at most 20 messages per second"
    seqs = [m["seq"] for _, m in received]
    assert np.all(np.diff(seqs) > 1), "the skipped messages are visible as seq gaps"


def test_references_during_moves_are_right_or_absent(daemon: LiveServer) -> None:
    stop = threading.Event()

    def move_around() -> None:
        for target in (2.0, 8.5, 1.0, 6.0, 9.5, 3.0):
            daemon.post("/api/stage/move", json={"target_mm": target}, headers=daemon.auth())
            time.sleep(0.25)  # about 2.5 mm at the virtual rig's speed: starts, stops and reversals
            if stop.is_set():
                return

    mover = threading.Thread(target=move_around)
    mover.start()
    try:
        received = [m for _, m in _collect(daemon, 2000)]
    finally:
        stop.set()
        mover.join()
    paired = [m for m in received if "error_um" in m and m["locked"]]
    x = np.array([m["x_mm"] for m in received if m["x_mm"] is not None])
    assert np.ptp(x) > 3.0, "the stage moved during the collection"
    assert len(paired) > 0.2 * len(received), f"only {len(paired)} of {len(received)} frames paired"
    error = np.abs([m["error_um"] for m in paired])
    bound = np.median([m["crlb_um"] for m in paired])
    assert np.percentile(error, 99.9) <= 5 * bound, (np.percentile(error, [50, 99, 99.9, 100]), bound)


def test_metrics_count_drops_and_staleness(daemon: LiveServer) -> None:
    (_, message), = _collect(daemon, 1)
    values = {}
    for line in daemon.get("/metrics").text.splitlines():
        if not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    assert values["graytrack_stale"] == 0.0 and values["graytrack_healthy"] == 1.0
    assert values["graytrack_frames_dropped_total"] >= message["dropped"], "the counter only grows"
    assert values["graytrack_frames_total"] > message["seq"]
