"""The broadcaster's hand-over from a frame thread to the event loop: in order, nothing stranded,
and frames arriving while the loop is busy go out in one batch (one wake-up, not one each)."""

from __future__ import annotations

import asyncio
import json
import threading
import time

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
            seqs.append(json.loads(client.queue.get_nowait())["seq"])
        return seqs, busy_wakeups

    seqs, busy_wakeups = asyncio.run(scenario())
    assert seqs == list(range(1, 61))
    assert busy_wakeups == 1
