"""graytrack.bluesky: the encoder and stage as ophyd-async devices, mocked and in a real RunEngine.

Mocked, the signals take ``set_mock_value`` and read back with their dtypes and units. Against a
real daemon (uvicorn on loopback, the virtual rig, calibrated at start) ``count`` records fresh
frames that agree with ``/api/status``, and ``scan`` moves the stage through the client and
records encoder positions at the setpoints.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Coroutine

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import pytest
from bluesky import RunEngine
from ophyd_async.core import NotConnectedError, set_mock_value
from ophyd_async.plan_stubs import ensure_connected

from graytrack.bluesky import GraytrackEncoder, GraytrackStage
from tests.service.helpers import LiveServer, free_port

TRACKS_MM = 0.01  # a frame against the daemon's figure or the setpoint (the first frames after a move may lag by µm)


def test_mocked_encoder_reads_what_was_set_with_dtypes_and_units() -> None:
    async def scenario() -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
        encoder = GraytrackEncoder(f"http://127.0.0.1:{free_port()}", name="enc")  # nothing listens there
        await encoder.connect(mock=True)
        set_mock_value(encoder.position, 3.25)
        set_mock_value(encoder.crlb, 0.42)
        set_mock_value(encoder.locked, True)
        set_mock_value(encoder.stale, True)
        set_mock_value(encoder.seq, 17)
        await encoder.trigger()  # done at once without a daemon
        return await encoder.read(), await encoder.describe(), encoder.hints

    reading, described, hints = asyncio.run(scenario())
    assert {key: r["value"] for key, r in reading.items()} == {
        "enc-position": 3.25, "enc-crlb": 0.42, "enc-locked": True, "enc-stale": True, "enc-seq": 17}
    assert {key: (d["dtype"], d["dtype_numpy"], d.get("units")) for key, d in described.items()} == {
        "enc-position": ("number", "<f8", "mm"), "enc-crlb": ("number", "<f8", "µm"),
        "enc-locked": ("boolean", "|b1", None), "enc-stale": ("boolean", "|b1", None),
        "enc-seq": ("integer", "<i8", None)}
    assert hints == {"fields": ["enc-position"]}


def test_mocked_stage_arrives_at_once_and_encoder_starts_unplaced() -> None:
    async def scenario() -> tuple[dict[str, Any], dict[str, Any]]:
        stage = GraytrackStage(f"http://127.0.0.1:{free_port()}", name="st")
        encoder = GraytrackEncoder(f"http://127.0.0.1:{free_port()}", name="enc")
        await asyncio.gather(stage.connect(mock=True), encoder.connect(mock=True))
        await stage.set(2.5)
        return await stage.read(), await encoder.read()

    stage_reading, encoder_reading = asyncio.run(scenario())
    assert stage_reading["st-readback"]["value"] == stage_reading["st-setpoint"]["value"] == 2.5
    assert math.isnan(encoder_reading["enc-position"]["value"]) and encoder_reading["enc-locked"]["value"] is False


def test_a_real_connection_to_no_daemon_is_one_not_connected_error() -> None:
    url = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(NotConnectedError, match=f"graytrack daemon at {url}: .*ConnectError"):
        asyncio.run(GraytrackEncoder(url, name="enc").connect(timeout=2.0))


# -- against a live daemon ----------------------------------------------------------------



@pytest.fixture(scope="module")
def engine() -> RunEngine:
    return RunEngine({}, context_managers=[])


def _on_loop(engine: RunEngine, coro: Coroutine[Any, Any, Any]) -> Any:
    return asyncio.run_coroutine_threadsafe(coro, engine.loop).result(timeout=20.0)


@pytest.fixture(scope="module")
def devices(daemon: LiveServer, data_dir: Path,
            engine: RunEngine) -> Iterator[tuple[GraytrackEncoder, GraytrackStage]]:
    encoder = GraytrackEncoder(daemon.base, name="encoder", data_dir=data_dir)
    stage = GraytrackStage(daemon.base, name="stage", data_dir=data_dir)
    engine(ensure_connected(encoder, stage, timeout=10.0))
    yield encoder, stage
    _on_loop(engine, encoder.close())
    _on_loop(engine, stage.close())


def _events(engine: RunEngine, plan: Any) -> list[dict[str, Any]]:
    events: list[dict[str, Any]] = []
    engine(plan, {"event": lambda name, doc: events.append(doc["data"])})
    return events


def test_count_records_fresh_frames_that_agree_with_the_status(
        daemon: LiveServer, engine: RunEngine, devices: tuple[GraytrackEncoder, GraytrackStage]) -> None:
    encoder, stage = devices
    engine(bps.mv(stage, 5.0))  # at rest where the test says, whatever the calibration left
    events = _events(engine, bp.count([encoder], num=5))
    status = daemon.status()
    assert len(events) == 5
    seqs = [e["encoder-seq"] for e in events]
    assert seqs == sorted(set(seqs)), f"each trigger waits for a new frame: {seqs}"
    assert status["position_mm"] is not None and not status["moving"]
    assert abs(status["position_mm"] - 5.0) < TRACKS_MM
    for e in events:
        # stale is the daemon's own verdict, carried as given (a test machine at load 8 can make its
        # camera-against-grating watch see a scale drift that timing alone made)
        assert e["encoder-locked"] is True and e["encoder-stale"] in (True, False)
        assert abs(e["encoder-position"] - status["position_mm"]) < TRACKS_MM, (e, status["position_mm"])
        assert 0 < e["encoder-crlb"] < 5.0  # µm: the sim rig tracks to about a micrometre
    assert abs(status["crlb_um"] - events[-1]["encoder-crlb"]) < 0.5 * status["crlb_um"]


def test_scan_moves_the_stage_and_the_encoder_tracks_the_setpoints(
        daemon: LiveServer, engine: RunEngine, devices: tuple[GraytrackEncoder, GraytrackStage]) -> None:
    encoder, stage = devices
    events = _events(engine, bp.scan([encoder], stage, 2.0, 4.0, 3))
    assert [e["stage-setpoint"] for e in events] == [2.0, 3.0, 4.0]
    for e, target in zip(events, [2.0, 3.0, 4.0]):
        assert abs(e["stage-readback"] - target) < TRACKS_MM
        assert e["encoder-locked"] is True
        assert abs(e["encoder-position"] - target) < TRACKS_MM, e
    assert abs(daemon.status()["target_mm"] - 4.0) < 1e-9
