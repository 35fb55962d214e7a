"""What one local client may cost the daemon: connections, time to send a request, WebSocket frames.

The daemon is reached without a token for everything that only reads (the page, the stream), so a
careless or hostile local program must not be able to exhaust it. Measured before these limits
(issue #38): 30 sockets on ``/ws/position`` each declaring a 15 MiB frame and sending 14 MiB grew
the daemon's RSS from 236 to 656 MB (uvicorn's default frame limit is 16 MiB); 500 connections
trickling a request head byte by byte were never closed. uvicorn has no timeout on *receiving* a
request: ``timeout_keep_alive`` covers only the idle time between requests and is reset by every
byte, and an ASGI middleware runs only once the head is parsed. So the guard lives in the protocol
that parses the bytes, :class:`GuardedHttpProtocol` (uvicorn's httptools protocol, which uvicorn's
``auto`` picks here), and in :class:`ws_protocol.StreamProtocol` for upgraded connections:

* a request (head and body) must arrive whole within ``request_timeout_s`` of its first byte, or of
  the connection's opening when it sends nothing: else ``408`` with a reason (nothing at all sent:
  closed), the connection closed;
* a request head (target and headers) over :data:`MAX_HEAD_BYTES` is ``431`` and closed;
* beyond ``max_connections`` open connections a request gets ``503`` with a reason and a WebSocket
  is accepted and closed ``1013`` (try again later) with a reason; beyond twice that a connection is
  closed as soon as it opens (the process keeps its file descriptors for its own files);
* a WebSocket frame over :data:`WS_MAX_FRAME_BYTES` closes the connection ``1009`` before its
  payload is read (websockets checks the declared length), and the stream closes on any message
  over :data:`WS_CONTROL_BYTES` (``api/stream.py``): the stream reads nothing from its clients.
"""

from __future__ import annotations

import json
import logging
import time
from functools import partial
from typing import Any, Callable

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from graytrack.service.daemon.settings import DaemonConfig

log = logging.getLogger("graytrack.daemon")
MAX_HEAD_BYTES = 16 * 1024  # request target plus headers; browsers send under 8 KiB
WS_MAX_FRAME_BYTES = 4 * 1024  # what websockets accepts in one frame/message before it closes 1009
WS_CONTROL_BYTES = 1024  # the largest client message the stream ignores (it reads none)
WS_TRY_AGAIN_LATER = 1013
WS_MESSAGE_TOO_BIG = 1009
HARD_CAP_FACTOR = 2  # beyond this many times max_connections a connection is closed unanswered
REFUSAL_LOG_INTERVAL_S = 60.0
HEAD_TOO_LARGE = f"the request's target and headers exceed {MAX_HEAD_BYTES} bytes"


class ConnectionLimits:
    """The limits (from ``[daemon]``) and what they refused, shared by every connection's protocol."""

    def __init__(self, daemon: DaemonConfig, monotonic: Callable[[], float] = time.monotonic) -> None:
        self.max_connections = daemon.max_connections
        self.request_timeout_s = daemon.request_timeout_s
        self.keep_alive_s = daemon.keep_alive_s
        self.refused = 0  # requests and WebSockets answered 503/1013 for the connection limit
        self.dropped = 0  # connections closed unanswered beyond the hard cap
        self.timed_out = 0  # requests closed for not arriving within request_timeout_s
        self.oversized = 0  # request heads over MAX_HEAD_BYTES and WebSocket messages over the control size
        self._monotonic = monotonic
        self._logged_at = -REFUSAL_LOG_INTERVAL_S
        self._unlogged = 0

    def over(self, open_connections: int) -> str | None:
        """Why a connection that makes ``open_connections`` open ones (itself included) is refused, or None."""
        if open_connections <= self.max_connections:
            return None
        return (f"the daemon serves at most {self.max_connections} connections at once ([daemon] "
                f"max_connections); try again when one closes")

    def beyond_hard_cap(self, open_connections: int) -> bool:
        return open_connections > HARD_CAP_FACTOR * self.max_connections

    def note_refusal(self, what: str) -> None:
        """Count a refusal; log at most one line a minute (a flood must not flood the log too)."""
        self._unlogged += 1
        now = self._monotonic()
        if now - self._logged_at >= REFUSAL_LOG_INTERVAL_S:
            log.warning("connection limit (%d): refused %d connections since the last report (latest: %s)",
                        self.max_connections, self._unlogged, what)
            self._logged_at, self._unlogged = now, 0

    def counters(self) -> dict[str, int]:
        return {"refused": self.refused, "dropped": self.dropped, "timed_out": self.timed_out,
                "oversized": self.oversized}


def json_response(status: int, phrase: str, error: str, headers: tuple[tuple[str, str], ...] = ()) -> bytes:
    """A complete HTTP/1.1 answer ``{"error": ...}`` that closes the connection (written by the protocol itself:
    the request never reached the app)."""
    body = json.dumps({"error": error}).encode()
    head = [f"HTTP/1.1 {status} {phrase}", "content-type: application/json", f"content-length: {len(body)}",
            "connection: close", *(f"{name}: {value}" for name, value in headers)]
    return ("\r\n".join(head) + "\r\n\r\n").encode("latin-1") + body


async def _answer(status: int, error: str, headers: tuple[tuple[bytes, bytes], ...], scope: dict[str, Any],
                  receive: Any, send: Any) -> None:
    """The ASGI app a refused request is answered by, in place of the daemon's: ``status`` with the reason, closed."""
    body = json.dumps({"error": error}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


async def _refuse(limits: ConnectionLimits, reason: str, scope: dict[str, Any], receive: Any, send: Any) -> None:
    """A request on a connection beyond the limit: 503 with the reason."""
    limits.refused += 1
    limits.note_refusal(f"{scope.get('method')} {scope.get('path')} answered 503")
    await _answer(503, reason, ((b"retry-after", b"1"),), scope, receive, send)


class GuardedHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a deadline on receiving each request, a bound on its head, and the
    connection limit. Built by uvicorn through :func:`server_protocols` (``limits`` bound there)."""

    def __init__(self, *args: Any, limits: ConnectionLimits, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.limits = limits
        self.deadline: Any = None  # asyncio.TimerHandle while a request is being received
        self.received_any = False
        self.head_bytes = 0
        self.in_head = False

    def connection_made(self, transport: Any) -> None:  # type: ignore[override]
        super().connection_made(transport)
        open_connections = len(self.connections)
        if self.limits.beyond_hard_cap(open_connections):
            self.limits.dropped += 1
            self.limits.note_refusal("closed at once beyond the hard cap")
            transport.close()
            return
        refusal = self.limits.over(open_connections)
        if refusal is not None:  # answered once its head is in (a WebSocket: by StreamProtocol, 1013)
            self.app = partial(_refuse, self.limits, refusal)
        self._arm()

    def _arm(self) -> None:
        if self.deadline is None:
            self.deadline = self.loop.call_later(self.limits.request_timeout_s, self._expired)

    def _disarm(self) -> None:
        if self.deadline is not None:
            self.deadline.cancel()
            self.deadline = None

    def _expired(self) -> None:
        self.deadline = None
        if self.transport.is_closing():
            return
        self.limits.timed_out += 1
        if self.received_any and (self.cycle is None or not self.cycle.response_started):
            self.transport.write(json_response(
                408, "Request Timeout", f"the request did not arrive whole within {self.limits.request_timeout_s:g} s "
                                        "([daemon] request_timeout_s)"))
        self.transport.close()

    def data_received(self, data: bytes) -> None:
        self.received_any = True
        super().data_received(data)
        if self.in_head and self.head_bytes > MAX_HEAD_BYTES and not self.transport.is_closing():
            self.limits.oversized += 1
            self._disarm()
            self.transport.write(json_response(431, "Request Header Fields Too Large", HEAD_TOO_LARGE))
            self.transport.close()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self.head_bytes, self.in_head = 0, True
        self._arm()

    def on_url(self, url: bytes) -> None:
        super().on_url(url)
        self.head_bytes += len(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        super().on_header(name, value)
        self.head_bytes += len(name) + len(value) + 4

    def on_headers_complete(self) -> None:
        self.in_head = False
        if self.head_bytes > MAX_HEAD_BYTES:  # arrived whole in one read: answered in place of the app
            self.limits.oversized += 1
            self.app = partial(_answer, 431, HEAD_TOO_LARGE, ())
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._disarm()  # received whole: how long the app takes to answer is not the client's doing
        super().on_message_complete()

    def handle_websocket_upgrade(self) -> None:
        self._disarm()  # from here the WebSocket protocol's own limits and keepalive pings apply
        super().handle_websocket_upgrade()


def server_protocols(limits: ConnectionLimits, ws_protocol: type) -> dict[str, Any]:
    """uvicorn's options for the limits: the guarded HTTP protocol, the WebSocket protocol with ``limits``
    (both built by uvicorn with its own arguments plus ours), the frame limit and the keep-alive."""
    return {"http": partial(GuardedHttpProtocol, limits=limits), "ws": partial(ws_protocol, limits=limits),
            "ws_max_size": WS_MAX_FRAME_BYTES, "timeout_keep_alive": limits.keep_alive_s}
