"""The position stream through a real uvicorn server: defined instants, visible drops, decimation,
and grating references that are right or absent while the stage moves."""

from __future__ import annotations

import json
import os
import shutil
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from websockets.sync.client import connect

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings, wait_for


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Iterator[LiveServer]:
    with LiveServer(create_app(fast_settings(calibrated(tmp_path_factory.mktemp("stream"))))) as server:
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
    # each message names the calibration whose model placed it: the one in use
    active = daemon.status()["active_calibration"]["id"]
    assert {m["calibration"] for _, m in received[-20:]} == {active}


def test_a_page_asks_for_a_decimated_stream(daemon: LiveServer) -> None:
    received = _collect(daemon, 12, "?max_rate=20")
    t = np.array([m["t"] for _, m in received])
    assert np.min(np.diff(t)) >= 0.05 - 1e-6, "at most 20 messages per second"
    seqs = np.array([m["seq"] for _, m in received])
    # the skipped messages are visible as seq gaps; two messages in a row only when the frames between
    # them never came (a loaded machine's frame loop fell behind): then 50 ms apart all the same
    assert np.mean(np.diff(seqs) > 1) >= 0.5, seqs


def test_references_during_moves_are_right_or_absent(daemon: LiveServer, tmp_path) -> None:
    # real time and a slow stage (2 mm/s), the saved model of the module's daemon: moves that last
    # long enough to be paired, starts and stops that must not be
    shutil.copy(daemon.rig.storage.model_path, tmp_path / "model.json")
    slow = {"stage": {"velocity_mm_s": 2.0}, "camera": {"frame_rate_hz": 200.0}}
    settings = fast_settings(tmp_path, slow, sim_clock_scale=1.0, auto_calibrate="never")
    with LiveServer(create_app(settings)) as rig:
        rig.wait_state("tracking")
        stop = threading.Event()

        def move_around() -> None:
            for target in (4.6, 5.4, 4.8, 5.5, 5.0):
                rig.post("/api/stage/move", json={"target_mm": target}, headers=rig.auth())
                if stop.wait(0.45):
                    return

        rig.post("/api/stage/move", json={"target_mm": 5.0}, headers=rig.auth())
        wait_for(lambda: abs((rig.status()["position_mm"] or 0) - 5.0) < 0.01, what="the start")
        mover = threading.Thread(target=move_around)
        mover.start()
        try:
            received = [m for _, m in _collect(rig, 450)]
        finally:
            stop.set()
            mover.join()
    x = np.array([np.nan if m["x_mm"] is None else m["x_mm"] for m in received])
    t = np.array([m["t"] for m in received])
    speed = np.abs(np.gradient(x, t))
    moving = [m for m, v in zip(received, speed) if v > 0.5 and "error_um" in m and m["locked"]]
    assert len(moving) >= 5, f"only {len(moving)} frames paired while moving"
    error = np.abs([m["error_um"] for m in moving])
    bound = np.median([m["crlb_um"] for m in moving])
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


def test_no_permessage_deflate_unless_configured(daemon: LiveServer) -> None:
    # the client offers deflate (websockets does by default); the daemon declines: compressing every
    # message again per client on the event loop was the 1 kHz stream's largest loop cost
    with connect(f"ws://127.0.0.1:{daemon.port}/ws/position", open_timeout=5) as ws:
        assert "permessage-deflate" in (ws.request.headers.get("Sec-WebSocket-Extensions") or "")
        assert ws.response.headers.get("Sec-WebSocket-Extensions") is None
        assert json.loads(ws.recv(timeout=5))["seq"] > 0


def _policy(tid: int) -> int:
    """The scheduling policy of one of this process's threads (/proc: field 41 of stat)."""
    stat = open(f"/proc/self/task/{tid}/stat").read()
    return int(stat.rsplit(")", 1)[1].split()[38])


def _fifo_allowed(level: int) -> bool:
    """Whether this process may use SCHED_FIFO at ``level`` (tried in a throwaway thread)."""
    allowed = []

    def attempt() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(level))
            allowed.append(True)
        except OSError:
            allowed.append(False)

    thread = threading.Thread(target=attempt)
    thread.start()
    thread.join()
    return allowed[0]


def test_realtime_priority_raises_the_frame_loop_the_event_loop_and_the_poller_only(daemon: LiveServer,
                                                                                    tmp_path) -> None:
    shutil.copy(daemon.rig.storage.model_path, tmp_path / "model.json")
    settings = fast_settings(tmp_path, realtime_priority=3, auto_calibrate="never")
    with LiveServer(create_app(settings)) as rig:
        rig.wait_state("tracking")
        acquisition, grating = rig.rig.acquisition, rig.rig.grating
        frame_loop = _policy(acquisition._thread.native_id)
        event_loop = _policy(rig.thread.native_id)
        poller = _policy(grating._thread.native_id)  # it holds the interpreter lock the raised ones need
        supervisor = _policy(rig.rig.supervisor.thread.native_id)
        received = _collect(rig, 20)
    assert supervisor == os.SCHED_OTHER, "threads the raised ones start are ordinary (SCHED_RESET_ON_FORK)"
    expected = os.SCHED_FIFO if _fifo_allowed(3) else os.SCHED_OTHER  # refused (no CAP_SYS_NICE): normal, said once
    assert frame_loop == event_loop == poller == expected
    assert len(received) == 20, "the stream runs either way"


def test_clients_get_the_same_preframed_message_text(daemon: LiveServer) -> None:
    # the broadcaster frames each message once and writes those bytes to every connection
    # (service/daemon/ws_protocol.py): what a client reads is the text send_text would have sent
    broadcaster = daemon.app.state.broadcaster
    with connect(f"ws://127.0.0.1:{daemon.port}/ws/position", open_timeout=5, compression=None) as a, \
            connect(f"ws://127.0.0.1:{daemon.port}/ws/position", open_timeout=5, compression=None) as b:
        # b subscribed after a's handshake (a loaded machine can take a quarter second, 50 messages, over it): b's
        # first 100, then a's until they reach b's last (a's connection holds every message since its own start)
        texts_b = [b.recv(timeout=5) for _ in range(100)]
        last_b = json.loads(texts_b[-1])["seq"]
        texts_a = [a.recv(timeout=5)]
        while json.loads(texts_a[-1])["seq"] < last_b and len(texts_a) < 5000:
            texts_a.append(a.recv(timeout=5))
        clients = broadcaster._clients
        assert len(clients) == 2 and all(c.writer is not None and c.direct > 0 for c in clients)
    assert all(isinstance(t, str) for t in texts_a + texts_b), "text frames, as before"
    by_seq = {json.loads(t)["seq"]: t for t in texts_a}
    common = [t for t in texts_b if json.loads(t)["seq"] in by_seq]
    assert len(common) > 90, "b's messages are a's from where b came in"
    assert all(by_seq[json.loads(t)["seq"]] == t for t in common), "byte for byte the same message"
