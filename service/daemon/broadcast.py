"""Fan-out of position messages from the acquisition thread to WebSocket clients on the event loop.

The acquisition thread must never wait for a slow client. Each message is encoded once, for all
clients, on the acquisition thread (adding ``t_unix`` and ``age_ms``, the send-time figures), and
framed once as a WebSocket text frame (:func:`ws_protocol.text_frame`); both are handed to the event
loop with one ``call_soon_threadsafe``. On the loop, a client whose connection takes pre-framed bytes
(:class:`ws_protocol.StreamProtocol`) and has nothing queued gets them written to its transport right
there: the same bytes object for every client, no task switch, no per-client encoding. Any other
client (a connection with permessage-deflate, a server without that protocol, a transport above its
high-water mark) has the message queued for its own sending task (``api/stream.py``).

Every client has a bounded queue: a client that falls behind loses its oldest messages (counted),
not the others' nor the tracker's. A client may ask for at most ``max_rate`` messages per second
(pages do): the others are skipped for it at delivery, before they cost it a send.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import deque
from typing import Any

from graytrack.service.daemon.timebase import WallClock
from graytrack.service.daemon.ws_protocol import text_frame

CLIENT_QUEUE = 2000


class Subscriber:
    """One connection's queue and decimation, and its pre-framed writer when it has one.

    ``writer`` (set by the stream route) is the connection's :class:`StreamProtocol` when it takes
    pre-framed bytes; ``busy`` is True while the client's sending task holds a message it took from
    the queue, so a direct write never overtakes it (messages stay in order)."""

    __slots__ = ("queue", "min_interval_s", "last_t", "dropped", "writer", "busy", "direct")

    def __init__(self, max_rate_hz: float | None) -> None:
        self.queue: asyncio.Queue[tuple[str, bytes]] = asyncio.Queue(CLIENT_QUEUE)
        self.min_interval_s = 1.0 / max_rate_hz if max_rate_hz else 0.0
        self.last_t = -1e18
        self.dropped = 0
        self.writer: Any = None
        self.busy = False
        self.direct = 0  # messages written straight to the transport at delivery

    def offer(self, text: str, frame: bytes, t: float) -> int:
        """Deliver ``text`` (``frame``: the same as a WebSocket frame; frame time ``t``) unless decimated:
        1 when written to the transport now, 0 when queued (or skipped), -1 when queued and the oldest
        queued message had to go."""
        if self.min_interval_s:
            if t - self.last_t < self.min_interval_s:
                return 0
            self.last_t = t
        q = self.queue
        writer = self.writer
        if writer is not None and not self.busy and q.empty() and writer.write_frame(frame):
            self.direct += 1
            return 1
        if q.full():
            q.get_nowait()
            self.dropped += 1
            q.put_nowait((text, frame))
            return -1
        q.put_nowait((text, frame))
        return 0


class Broadcaster:
    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._clients: tuple[Subscriber, ...] = ()
        self._lock = threading.Lock()
        self._wall = WallClock()
        self._handover: deque[tuple[str, bytes, float]] = deque()
        self._scheduled = False
        self.published = 0
        self.sent = 0
        self.dropped = 0
        self.cpu_s = 0.0  # the loop's CPU in deliveries: the stream's, not a request's (limits.ServingShare)

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver on ``loop`` (the server's, known only once the app runs)."""
        self._loop = loop

    @property
    def clients(self) -> int:
        return len(self._clients)

    def subscribe(self, max_rate_hz: float | None = None, writer: Any = None) -> Subscriber:
        """A new client; ``writer`` is its connection's :class:`StreamProtocol` when it takes pre-framed bytes."""
        client = Subscriber(max_rate_hz)
        client.writer = writer
        with self._lock:
            self._clients = self._clients + (client,)
        return client

    def unsubscribe(self, client: Subscriber) -> None:
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
        text = self.encode(message)
        self._handover.append((text, text_frame(text.encode()), message["t"]))  # the frame thread is done with it
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
        began = time.thread_time()
        handover = self._handover
        clients = self._clients  # an immutable tuple: no lock on the hot path
        while handover:
            text, frame, t = handover.popleft()
            for client in clients:
                outcome = client.offer(text, frame, t)
                if outcome > 0:
                    self.sent += 1
                elif outcome < 0:
                    self.dropped += 1
        self.cpu_s += time.thread_time() - began
