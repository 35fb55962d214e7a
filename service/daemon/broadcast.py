"""Fan-out of position messages from the acquisition thread to WebSocket clients on the event loop.

The acquisition thread must never wait for a slow client. Each message is encoded once, for all
clients, on the acquisition thread (adding ``t_unix`` and ``age_ms``, the send-time figures), and
handed to the event loop with one ``call_soon_threadsafe``. Every client has a bounded queue: a
client that falls behind loses its oldest messages (counted), not the others' nor the tracker's.
A client may ask for at most ``max_rate`` messages per second (pages do): the others are skipped
for it at delivery, before they cost it a send.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import deque
from typing import Any

from graytrack.service.daemon.timebase import WallClock

CLIENT_QUEUE = 2000


class Client:
    """One connection's queue and decimation."""

    __slots__ = ("queue", "min_interval_s", "last_t", "dropped")

    def __init__(self, max_rate_hz: float | None) -> None:
        self.queue: asyncio.Queue[str] = asyncio.Queue(CLIENT_QUEUE)
        self.min_interval_s = 1.0 / max_rate_hz if max_rate_hz else 0.0
        self.last_t = -1e18
        self.dropped = 0

    def offer(self, text: str, t: float) -> bool:
        """Queue ``text`` (frame time ``t``) unless decimated; False when the oldest had to go."""
        if self.min_interval_s:
            if t - self.last_t < self.min_interval_s:
                return True
            self.last_t = t
        q = self.queue
        if q.full():
            q.get_nowait()
            self.dropped += 1
            q.put_nowait(text)
            return False
        q.put_nowait(text)
        return True


class Broadcaster:
    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._clients: tuple[Client, ...] = ()
        self._lock = threading.Lock()
        self._wall = WallClock()
        self._handover: deque[tuple[str, float]] = deque()
        self._scheduled = False
        self.published = 0
        self.sent = 0
        self.dropped = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver on ``loop`` (the server's, known only once the app runs)."""
        self._loop = loop

    @property
    def clients(self) -> int:
        return len(self._clients)

    def subscribe(self, max_rate_hz: float | None = None) -> Client:
        client = Client(max_rate_hz)
        with self._lock:
            self._clients = self._clients + (client,)
        return client

    def unsubscribe(self, client: Client) -> None:
        with self._lock:
            self._clients = tuple(c for c in self._clients if c is not client)

    def encode(self, message: dict[str, Any]) -> str:
        """The message as sent: with ``t_unix`` (wall clock) and ``age_ms`` (now minus mid-exposure)."""
        now = time.monotonic()
        t = message["t"]
        message["t_unix"] = self._wall.unix(t, now)
        message["age_ms"] = round((now - t) * 1e3, 4)
        return json.dumps(message, allow_nan=False, separators=(",", ":"))

    def publish(self, message: dict[str, Any]) -> None:
        """Called from any thread; returns at once."""
        self.published += 1
        loop = self._loop
        if loop is None or not self._clients or loop.is_closed():
            return
        self._handover.append((self.encode(message), message["t"]))  # the acquisition thread is done with it
        if self._scheduled:
            return  # a delivery is pending on the loop: it will take this message too
        self._scheduled = True
        try:
            loop.call_soon_threadsafe(self._deliver)
        except RuntimeError:  # the loop closed between the check and the call (shutdown)
            self._scheduled = False

    def _deliver(self) -> None:
        """On the loop: everything handed over so far, in order. The flag drops first, so a message
        appended while this runs is either taken here or schedules the next delivery (never stranded)."""
        self._scheduled = False
        handover = self._handover
        while handover:
            text, t = handover.popleft()
            for client in self._clients:  # an immutable tuple: no lock on the hot path
                if not client.offer(text, t):
                    self.dropped += 1
