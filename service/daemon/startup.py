"""The daemon's warm-up before it opens the rig, run off the event loop so that every route answers
meanwhile and the log says what the wait is.

Tracking's compiled kernels load on first use (:func:`graytrack.service.heap.warm_tracking`): from
numba's disk cache in under a second, but compiled on the first start after an install or a fresh
clone, ~30 s on two cores (`make run` on a fresh clone: 29–32 s). Run inside the lifespan, that wait
would come before uvicorn accepts its first request: the server prints "Application startup complete"
and then says nothing while every request, the status page's too, hangs. Here it runs on a thread of
its own, at the event loop's priority (threads start at normal priority: on a loaded two-core machine,
at nice 10 beside a load of 13, a normal one had not finished after 110 s), and the rig opens on the
event loop once it is done; ``GET /api/status`` answers ``starting`` with the step and its seconds
(:meth:`WarmUp.status`).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from typing import Any, Callable

from graytrack.drivers.realtime import raise_thread_priority

log = logging.getLogger("graytrack.daemon")
WARM_STEP = "loading the tracker's compiled kernels"
WARM_EXPECTED = "under a second from numba's cache; about 30 s on the first start after an install, which compiles them"


class WarmUp:
    """``await run(then)``: ``warm()`` on a daemon thread, then ``then()`` on the calling event loop."""

    def __init__(self, warm: Callable[[], None], priority: int = 0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.warm = warm
        self.priority = priority  # SCHED_FIFO level of the warm-up thread ([daemon] realtime_priority), 0 = normal
        self.clock = clock
        self._began: float | None = None  # of the warm-up, while it runs
        self.seconds: float | None = None  # what it took, once done

    def status(self) -> dict[str, Any] | None:
        """The step in progress (the status document's ``startup``), None when none is."""
        began = self._began
        if began is None:
            return None
        return {"step": WARM_STEP, "elapsed_s": round(self.clock() - began, 1), "expected_s": WARM_EXPECTED}

    async def run(self, then: Callable[[], None]) -> None:
        loop = asyncio.get_running_loop()
        done: asyncio.Future[None] = loop.create_future()
        # a daemon thread, not the loop's executor: a shutdown during a first compile does not wait for it
        threading.Thread(target=self._warm, args=(loop, done), name="warm-up", daemon=True).start()
        await done
        then()

    def _warm(self, loop: asyncio.AbstractEventLoop, done: "asyncio.Future[None]") -> None:
        self._began = began = self.clock()
        raise_thread_priority(self.priority, "warm-up")
        log.info("%s (%s); the API answers meanwhile", WARM_STEP, WARM_EXPECTED)
        try:
            self.warm()
        except Exception:  # noqa: BLE001 - slower first install, longer collections: not a daemon that cannot start
            log.exception("tracking could not be warmed up before the heap freeze")
        self.seconds = self.clock() - began
        self._began = None
        log.info("tracker kernels ready in %.1f s: opening the rig", self.seconds)
        if not loop.is_closed():  # else the daemon stopped during the warm-up: nobody waits for it
            try:
                loop.call_soon_threadsafe(lambda: done.done() or done.set_result(None))
            except RuntimeError:  # closed between the check and the call
                pass
