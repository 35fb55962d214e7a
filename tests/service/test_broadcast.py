"""The broadcaster's hand-over from a frame thread to the event loop: in order, nothing stranded,
and frames arriving while the loop is busy go out in one batch (one wake-up, not one each)."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from typing import Any

from graytrack.service.daemon.broadcast import Broadcaster


def test_handover_batches_while_the_loop_is_busy_and_keeps_order() -> None:
    async def scenario() -> tuple[list[int], int]:
        broadcaster = Broadcaster()
        broadcaster.bind(asyncio.get_running_loop())
        client = broadcaster.subscribe()
        wakeups = 0
        deliver = broadcaster._deliver

        def counted() -> None:
            nonlocal wakeups
            wakeups += 1
            deliver()

        broadcaster._deliver = counted  # type: ignore[method-assign]
        sent = threading.Event()

        def frames(first: int, n: int) -> None:
            for seq in range(first, first + n):
                broadcaster.publish({"seq": seq, "t": time.monotonic()})
            sent.set()

        threading.Thread(target=frames, args=(1, 50)).start()
        sent.wait(5)  # the loop is blocked here: all 50 arrive before it can deliver
        await asyncio.sleep(0.05)
        busy_wakeups = wakeups
        sent.clear()
        for seq in range(51, 61):  # the loop free: each message is delivered, none stranded
            threading.Thread(target=frames, args=(seq, 1)).start()
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.05)
        seqs = []
        while not client.queue.empty():
            seqs.append(json.loads(client.queue.get_nowait()[0])["seq"])
        return seqs, busy_wakeups

    seqs, busy_wakeups = asyncio.run(scenario())
    assert seqs == list(range(1, 61))
    assert busy_wakeups == 1


class _Writer:
    """A connection that takes pre-framed bytes (the part of StreamProtocol the broadcaster uses)."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.writable = asyncio.Event()
        self.writable.set()
        self.closed = False

    def write_frame(self, frame: bytes) -> bool | None:
        if self.closed:
            return None
        if not self.writable.is_set():
            return False
        self.frames.append(frame)
        return True


def _payload(frame: bytes) -> str:
    """The text of one server-to-client WebSocket frame, parsed by websockets itself."""
    from websockets.frames import Frame, Opcode
    from websockets.streams import StreamReader

    reader = StreamReader()
    reader.feed_data(frame)
    parser = Frame.parse(reader.read_exact, mask=False)
    try:
        next(parser)
    except StopIteration as done:
        parsed = done.value
    assert parsed.opcode is Opcode.TEXT and parsed.fin
    assert not reader.buffer, "one frame, nothing after it"
    return parsed.data.decode()


def test_every_client_is_written_the_same_preframed_bytes_once_encoded() -> None:
    async def scenario() -> tuple[list[_Writer], Broadcaster, Any]:
        broadcaster = Broadcaster()
        broadcaster.bind(asyncio.get_running_loop())
        writers = [_Writer() for _ in range(4)]
        clients = [broadcaster.subscribe(writer=w) for w in writers]
        fallback = broadcaster.subscribe()  # no pre-framed writer (deflate, a test client): queued text
        for seq in range(1, 31):
            broadcaster.publish({"seq": seq, "t": time.monotonic(), "x_mm": 1.25, "label": "é" * (seq * 5)})
            await asyncio.sleep(0)
        await asyncio.sleep(0.02)
        assert all(c.direct == 30 for c in clients)
        return writers, broadcaster, fallback

    writers, broadcaster, fallback = asyncio.run(scenario())
    for i in range(30):
        first = writers[0].frames[i]
        assert all(w.frames[i] is first for w in writers), "one bytes object for every client"
    queued = [fallback.queue.get_nowait() for _ in range(30)]
    assert [_payload(w) for w in writers[0].frames] == [text for text, _ in queued], "the frame carries the text"
    assert [json.loads(text)["seq"] for text, _ in queued] == list(range(1, 31))
    assert len(writers[0].frames[-1]) > 126 + 4, "the 16-bit length form is exercised"
    assert broadcaster.sent == 4 * 30 and broadcaster.dropped == 0


def test_a_client_above_its_high_water_mark_is_queued_in_order_and_the_others_are_not_held() -> None:
    async def scenario() -> tuple[list[int], list[int]]:
        broadcaster = Broadcaster()
        broadcaster.bind(asyncio.get_running_loop())
        slow, fast = _Writer(), _Writer()
        slow_client = broadcaster.subscribe(writer=slow)
        broadcaster.subscribe(writer=fast)
        slow.writable.clear()  # its transport's buffer is full
        for seq in range(1, 11):
            broadcaster.publish({"seq": seq, "t": time.monotonic()})
            await asyncio.sleep(0)
            if seq == 5:
                slow.writable.set()  # drained: but 1..5 wait in the queue, so 6.. must not overtake them
        await asyncio.sleep(0.01)
        queued = []
        while not slow_client.queue.empty():
            queued.append(json.loads(slow_client.queue.get_nowait()[0])["seq"])
        return queued, [json.loads(_payload(f))["seq"] for f in fast.frames]

    queued, fast = asyncio.run(scenario())
    assert fast == list(range(1, 11))
    assert queued == list(range(1, 11)), "once queued, the rest queue behind (the sending task writes them in order)"
