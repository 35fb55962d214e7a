"""The position stream's bookkeeping, shared by the blocking and the asyncio stream.

:class:`Link` holds everything but the socket: the URL and headers, the ``seq`` of the last
message (so the first message after a lost connection says how many were missed), the back-off
between reconnection attempts, the silence deadline, and which failures are worth retrying (a
refusal by the daemon's policy is not). The two transports only connect, receive and sleep.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

from websockets.exceptions import ConnectionClosed, InvalidStatus, InvalidURI

from graytrack.client.errors import GraytrackClientError, StreamRefused, StreamSilent

POLICY_VIOLATION = 1008  # the daemon's refusal after the handshake (e.g. a bad max_rate)
FIRST_RETRY_S = 0.05
LONGEST_RETRY_S = 1.0
OPEN_TIMEOUT_S = 10.0
MAX_MESSAGE = 1 << 20


@dataclass(frozen=True)
class Position:
    """One stream message (one tracked frame), with what the client saw of the stream before it.

    ``gap`` counts the messages missed just before this one (``seq`` numbers skipped): messages
    lost while the connection was down, or dropped by the daemon for a client too slow to read
    its queue. With ``max_rate`` the daemon skips messages on purpose and ``gap`` counts those too.
    ``reconnected`` marks the first message over a new connection, ``restarted`` one whose ``seq``
    went back (a restarted daemon; ``gap`` then counts the new daemon's messages missed).
    ``x_mm``, ``locked``, ``crlb_um``, ``stale`` and ``stale_reason`` are the frame record's quantities
    (core/frame_record.py, ``graytrack.wire.FitFigures``); the rest of the record is in ``raw``.
    """

    seq: int
    t: float  # mid-exposure, the daemon host's time.monotonic() (s)
    x_mm: float | None
    locked: bool
    crlb_um: float | None
    stale: bool
    stale_reason: str | None
    age_ms: float | None  # send time minus mid-exposure, in the daemon
    t_unix: float | None
    frame_id: int | None
    dropped: int  # camera frames missing so far (frame_id gaps)
    reference_mm: float | None  # the grating at t, when known
    error_um: float | None
    calibration: str | None = None  # the id of the calibration whose model placed the frame
    gap: int = 0
    reconnected: bool = False
    restarted: bool = False
    raw: dict[str, Any] = field(default_factory=dict, repr=False)  # the message as sent (fit figures, trim, event)


def ws_url(base: str, max_rate: float | None) -> str:
    """``ws(s)://host/ws/position[?max_rate=N]`` from the daemon's HTTP base URL."""
    parts = urlsplit(base)
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None:
        raise ValueError(f"daemon URL must start with http:// or https://, got {base!r}")
    if max_rate is not None and not max_rate > 0:
        raise ValueError(f"max_rate must be a positive number of messages/s, got {max_rate}")
    query = urlencode({"max_rate": f"{max_rate:g}"}) if max_rate is not None else ""
    return urlunsplit((scheme, parts.netloc, parts.path.rstrip("/") + "/ws/position", query, ""))


def _message(document: dict[str, Any], gap: int, reconnected: bool, restarted: bool) -> Position:
    get = document.get
    return Position(seq=document["seq"], t=document["t"], x_mm=get("x_mm"), locked=bool(get("locked")),
                    crlb_um=get("crlb_um"), stale=bool(get("stale", False)), stale_reason=get("stale_reason"),
                    age_ms=get("age_ms"),
                    t_unix=get("t_unix"), frame_id=get("frame_id"), dropped=get("dropped", 0),
                    reference_mm=get("reference_mm"), error_um=get("error_um"), calibration=get("calibration"),
                    gap=gap, reconnected=reconnected,
                    restarted=restarted, raw=document)


class Link:
    """One stream's state across its connections (not thread-safe: one reader)."""

    def __init__(self, url: str, token: str | None, silence_s: float | None) -> None:
        self.url = url
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.silence_s = silence_s
        self.last_seq: int | None = None
        self.connections = 0
        self.missed = 0  # messages missed over the stream's life (the sum of the gaps)
        self._new_connection = False
        self._heard = time.monotonic()  # the last message, or the stream's start
        self._retry_s = FIRST_RETRY_S
        self._last_failure: str | None = None

    # -- time ----------------------------------------------------------------------------
    def receive_timeout(self) -> float | None:
        """How long a receive may wait before the stream is silent (None: for ever)."""
        if self.silence_s is None:
            return None
        return max(0.0, self._heard + self.silence_s - time.monotonic())

    def open_timeout(self) -> float:
        remaining = self.receive_timeout()
        return OPEN_TIMEOUT_S if remaining is None else max(0.01, min(OPEN_TIMEOUT_S, remaining))

    def silent(self) -> StreamSilent:
        seen = "no message yet" if self.last_seq is None else f"last seq {self.last_seq}"
        why = f"; {self._last_failure}" if self._last_failure else ""
        return StreamSilent(f"no position message for {self.silence_s:g} s ({seen}{why})", request=self.url)

    # -- events --------------------------------------------------------------------------
    def connected(self) -> None:
        self.connections += 1
        self._new_connection = self.connections > 1
        self._retry_s = FIRST_RETRY_S

    def failed(self, exc: BaseException) -> float:
        """After a lost or refused connection: the pause before the next attempt, or raise when hopeless."""
        if isinstance(exc, ConnectionClosed) and exc.rcvd is not None and exc.rcvd.code == POLICY_VIOLATION:
            raise StreamRefused(exc.rcvd.reason or "refused by the daemon's policy", request=self.url) from None
        if isinstance(exc, InvalidStatus) and 400 <= exc.response.status_code < 500:
            body = exc.response.body.decode("utf-8", "replace").strip() if exc.response.body else ""
            raise StreamRefused(body or f"handshake refused with HTTP {exc.response.status_code}: the daemon refuses "
                                        "this Host, Origin, token or max_rate",
                                exc.response.status_code, self.url) from None
        if isinstance(exc, (InvalidURI, ValueError)):
            raise GraytrackClientError(str(exc), request=self.url) from None
        self._last_failure = f"{type(exc).__name__}: {exc}".strip()
        remaining = self.receive_timeout()
        if remaining is not None and remaining <= 0:
            raise self.silent() from exc
        pause = self._retry_s if remaining is None else min(self._retry_s, remaining)
        self._retry_s = min(self._retry_s * 2, LONGEST_RETRY_S)
        return pause

    def received(self, text: str | bytes) -> Position:
        self._heard = time.monotonic()
        document = json.loads(text)
        seq = document["seq"]
        last, reconnected = self.last_seq, self._new_connection
        restarted = last is not None and seq <= last
        gap = 0 if last is None else (seq - 1 if restarted else seq - last - 1)
        self.last_seq, self._new_connection = seq, False
        self.missed += gap
        return _message(document, gap, reconnected, restarted)
