"""Fan-out of position messages from the acquisition thread to WebSocket clients on the event loop.

The acquisition thread must never wait for a slow client, so each message is encoded once and
handed to the event loop with ``call_soon_threadsafe``; every client has a bounded queue and a
client that falls behind loses its oldest messages (counted), not the others' nor the tracker's.
"""

from __future__ import annotations

import asyncio
import json
import threading
from typing import Any

CLIENT_QUEUE = 2000


class Broadcaster:
    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._clients: set[asyncio.Queue[str]] = set()
        self._lock = threading.Lock()
        self.published = 0
        self.sent = 0
        self.dropped = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver on ``loop`` (the server's, known only once the app runs)."""
        self._loop = loop

    @property
    def clients(self) -> int:
        return len(self._clients)

    def subscribe(self) -> "asyncio.Queue[str]":
        q: asyncio.Queue[str] = asyncio.Queue(CLIENT_QUEUE)
        with self._lock:
            self._clients.add(q)
        return q

    def unsubscribe(self, q: "asyncio.Queue[str]") -> None:
        with self._lock:
            self._clients.discard(q)

    def publish(self, message: dict[str, Any]) -> None:
        """Called from any thread; returns at once."""
        self.published += 1
        loop = self._loop
        if loop is None or not self._clients or loop.is_closed():
            return
        text = json.dumps(message, allow_nan=False)
        try:
            loop.call_soon_threadsafe(self._deliver, text)
        except RuntimeError:  # the loop closed between the check and the call (shutdown)
            pass

    def _deliver(self, text: str) -> None:
        with self._lock:
            clients = list(self._clients)
        for q in clients:
            if q.full():
                q.get_nowait()
                self.dropped += 1
            q.put_nowait(text)
