"""``WS /ws/position``: one message per tracked frame (or at most ``?max_rate=`` per second).

Two tasks per connection, not per message: one sends what the broadcaster queued, one waits for
the client to go away. A connection served by :class:`StreamProtocol` without extensions is written
to by the broadcaster itself, pre-framed bytes shared by every client (``broadcast.py``); its sending
task only handles what had to be queued (a transport above its high-water mark). The handshake is
checked by :class:`WebPolicy` (Host, Origin, and the token as ``[daemon] read_token`` says,
read_policy.py); a refused one is answered 403 with the reason as JSON and the security headers. A
connection beyond the connection limit is accepted only to be closed 1013 with the reason; a client
message over a small control size closes the connection 1009 (the stream reads nothing from its
clients; limits.py).
"""

from __future__ import annotations

import asyncio
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from fastapi.responses import JSONResponse

from graytrack.service.daemon.api.read_policy import SUBPROTOCOL, offered_subprotocols
from graytrack.service.daemon.api.security import security_headers
from graytrack.service.daemon.broadcast import Broadcaster, Subscriber
from graytrack.service.daemon.limits import WS_CONTROL_BYTES, WS_MESSAGE_TOO_BIG, WS_TRY_AGAIN_LATER, ConnectionLimits
from graytrack.service.daemon.ws_protocol import EXTENSION, REFUSAL

router = APIRouter()
POLICY_VIOLATION = 1008


@router.websocket("/ws/position")
async def positions(websocket: WebSocket) -> None:
    refusal = websocket.app.state.policy.websocket_refusal(websocket.scope)
    if refusal is not None:
        await _deny(websocket, refusal)
        return
    max_rate = _max_rate(websocket.query_params.get("max_rate"))
    if max_rate is False:
        await _deny(websocket, "max_rate must be a positive number (messages/s)")
        return
    # a client presenting the token as a subprotocol offers "graytrack" beside it: that one is answered
    # (a browser fails a handshake that selects none of those it offered), never the token
    offered = offered_subprotocols({k.decode("latin-1"): v.decode("latin-1") for k, v in websocket.scope["headers"]})
    await websocket.accept(subprotocol=SUBPROTOCOL if SUBPROTOCOL in offered else None)
    extensions = websocket.scope.get("extensions", {})
    if REFUSAL in extensions:
        await websocket.close(code=WS_TRY_AGAIN_LATER, reason=extensions[REFUSAL][:120])
        return
    broadcaster: Broadcaster = websocket.app.state.broadcaster
    writer = extensions.get(EXTENSION)
    client = broadcaster.subscribe(max_rate or None, writer if writer is not None and writer.preframed else None)
    sender = asyncio.create_task(_pump(websocket, client, broadcaster))
    closed = asyncio.create_task(_until_closed(websocket, websocket.app.state.limits))
    try:
        await asyncio.wait({sender, closed}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        broadcaster.unsubscribe(client)
        sender.cancel()
        closed.cancel()


async def _deny(websocket: WebSocket, reason: str) -> None:
    """A handshake refused: 403 with the reason as JSON and the security headers, like every HTTP answer
    (a server without the denial-response extension closes it 1008 with the reason instead)."""
    if "websocket.http.response" in websocket.scope.get("extensions", {}):
        headers = {name.decode(): value.decode() for name, value in security_headers()}
        await websocket.send_denial_response(JSONResponse({"error": reason}, status_code=403, headers=headers))
    else:
        await websocket.close(code=POLICY_VIOLATION, reason=reason[:120])


def _max_rate(text: str | None) -> float | None | bool:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        return False
    return value if math.isfinite(value) and value > 0 else False


async def _pump(websocket: WebSocket, client: Subscriber, broadcaster: Broadcaster) -> None:
    queue, writer = client.queue, client.writer
    try:
        while True:
            text, frame = await queue.get()
            if writer is None:
                await websocket.send_text(text)
            else:
                client.busy = True  # the broadcaster writes nothing directly until this one is out
                written = writer.write_frame(frame)
                while written is False:  # above the high-water mark: wait for the transport to drain
                    await writer.writable.wait()
                    written = writer.write_frame(frame)
                client.busy = False
                if written is None:
                    return  # closing or closed
            broadcaster.sent += 1
    except (WebSocketDisconnect, RuntimeError):
        return


async def _until_closed(websocket: WebSocket, limits: ConnectionLimits) -> None:
    """Returns when the client goes away, or after closing it 1009 for a message over the control size
    (clients have nothing to say on this socket; a small one, a page's keepalive, is ignored)."""
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            size = len(message.get("bytes") or b"") + len((message.get("text") or "").encode())
            if size > WS_CONTROL_BYTES:
                limits.oversized += 1
                await websocket.close(code=WS_MESSAGE_TOO_BIG, reason=f"a message of {size} bytes: this stream "
                                                                       f"reads none over {WS_CONTROL_BYTES}")
                return
    except (WebSocketDisconnect, RuntimeError):
        return
