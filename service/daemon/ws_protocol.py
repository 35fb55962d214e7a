"""The WebSocket protocol the daemon serves with: uvicorn's websockets-sansio one, plus pre-framed sends.

At 1 kHz × 4 clients the stream's cost on the event loop was, per client and message, Starlette's
``send_text`` → the exception middleware's ``sender`` → uvicorn's ``send`` (an ``await`` on
``writable``, the text encoded to UTF-8 again) → websockets' ``Frame.serialize`` → the transport.
Every client gets the same bytes, so the broadcaster frames each message once
(:func:`text_frame`, on the frame thread) and hands those bytes to each connection's transport
(:meth:`StreamProtocol.write_frame`): one ``transport.write`` per client, nothing else.

A connection offers this through its ASGI scope (``scope["extensions"]["graytrack.preframed"]``,
the protocol itself) only when the bytes on the wire would be the same as ``send_text`` writes: a
server's frames are not masked, and no extension was negotiated (permessage-deflate compresses per
connection: such a connection, and any server without this protocol, such as Starlette's test
client, is sent to through ``send_text``). Back-pressure is kept: a transport above its
high-water mark (``writable`` cleared by ``pause_writing``) is not written to; the broadcaster queues
for that client instead.

The connection limits (``limits.py``) are decided here for upgraded connections, once the handshake is
in (the connection keeps its place in its client's count, handed over by the HTTP protocol): a connection
beyond ``max_connections`` or ``max_connections_per_client`` carries its refusal in ``scope["extensions"][REFUSAL]``,
and the route accepts it only to close it ``1013`` with that reason (a close code needs a handshake).
"""

from __future__ import annotations

import struct
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.protocol import State

from graytrack.service.daemon.limits import ConnectionLimits, Ticket

EXTENSION = "graytrack.preframed"
REFUSAL = "graytrack.refusal"


def text_frame(payload: bytes) -> bytes:
    """One unmasked, final WebSocket text frame (RFC 6455 §5.2) carrying ``payload`` (UTF-8): what a
    server's ``send_text`` puts on the wire when no extension is negotiated."""
    n = len(payload)
    if n < 126:
        return bytes((0x81, n)) + payload
    if n < 65536:
        return struct.pack("!BBH", 0x81, 126, n) + payload
    return struct.pack("!BBQ", 0x81, 127, n) + payload


class StreamProtocol(WebSocketsSansIOProtocol):
    """uvicorn's websockets-sansio protocol whose connections accept pre-framed text frames and carry the
    connection limit's verdict. Built by uvicorn through :func:`limits.server_protocols` (``limits`` bound there)."""

    def __init__(self, *args: Any, limits: ConnectionLimits, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.limits = limits
        self.ticket: Ticket | None = None  # set as the connection is made

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        upgraded_from = transport.get_protocol()  # the HTTP protocol, until uvicorn switches the transport to this one
        take = getattr(upgraded_from, "take_ticket", None)
        self.ticket = (take() if take is not None else None) or self.limits.admit(self.client)

    def connection_lost(self, exc: Exception | None) -> None:
        super().connection_lost(exc)
        if self.ticket is not None:
            self.ticket.release()

    async def send(self, message: Any) -> None:
        await super().send(message)
        if message["type"] == "websocket.http.response.body" and not message.get("more_body", False):
            # A denial response (403 with its JSON reason) ends the handshake as the ASGI spec has it; uvicorn's
            # protocol leaves its flag unset and logs an ERROR for each refused handshake, a line per
            # cross-origin probe that the log's summaries cannot hold back (errors are always written).
            self.handshake_complete = True

    def handle_connect(self, event: Any) -> None:
        super().handle_connect(event)
        scope = getattr(self, "scope", None)  # absent when the handshake was refused
        if scope is not None:  # the ASGI task starts later: it sees these
            scope["extensions"][EXTENSION] = self
            assert self.ticket is not None
            refusal = self.limits.over(len(self.connections), self.ticket)  # this connection included
            if refusal is not None:
                self.limits.refused += 1
                self.limits.note_refusal("a WebSocket closed 1013")
                scope["extensions"][REFUSAL] = refusal

    @property
    def preframed(self) -> bool:
        """Whether :meth:`write_frame` bytes are what ``send_text`` would write (no extension negotiated)."""
        return self.handshake_complete and not self.conn.extensions

    def write_frame(self, frame: bytes) -> bool | None:
        """Write one pre-framed message: True when written, False when the transport is above its
        high-water mark (the caller queues and waits for ``writable``), None when the connection is
        closing or closed (nothing more may be sent on it)."""
        if self.close_sent or self.disconnected or self.conn.state is not State.OPEN or self.transport.is_closing():
            return None
        if not self.writable.is_set():
            return False
        self.transport.write(frame)
        return True
