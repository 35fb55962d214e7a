"""Who may read: one rule (``[daemon] read_token``) for every route that only reads, the stream included.

Before it, a daemon bound beyond loopback asked the stream for the token while ``/api/status``, the
events and the recordings answered anyone on the network. Now every read is decided here, the same way:

* ``"beyond_loopback"`` (the default): reads need the token when the daemon listens beyond loopback
  (``[daemon] host`` is not a loopback address); on loopback every local program may read, as before;
* ``"always"``: reads need the token wherever the daemon listens;
* ``"never"``: reads are open wherever it listens (a trusted network only).

Open under every policy: what a newcomer needs before having the token, and what holds no data of
the rig: the page and its static files, :data:`OPEN_PATHS` (the liveness probe, where the token is,
the API's shape). Everything else read is under the policy, unknown paths too (a 404 would say
which routes exist).

The token may be presented, in this order of preference (the first two never end up in a URL, so
never in an access log, a proxy's log or a browser's history):

* the header ``Authorization: Bearer <token>``;
* on the WebSocket, where a browser cannot set headers, the subprotocols ``graytrack`` and
  ``graytrack.bearer.<token>`` (``new WebSocket(url, ["graytrack", "graytrack.bearer." + token])``):
  the daemon answers with ``graytrack`` and never echoes the token;
* ``?token=<token>`` in the query (a download link): the daemon redacts it from its log
  (``service/daemon/logs.py``), but proxies and browsers may keep it.

A state change still needs the header (``security.py``): the query and the subprotocol are read
tokens only.
"""

from __future__ import annotations

from typing import Callable, Literal
from urllib.parse import parse_qs

SUBPROTOCOL = "graytrack"
BEARER_SUBPROTOCOL = "graytrack.bearer."
ReadToken = Literal["beyond_loopback", "always", "never"]
OPEN_PATHS = frozenset({"/", "/favicon.ico", "/healthz", "/api/access", "/api/openapi.json", "/api/docs"})
OPEN_PREFIXES = ("/static/",)
HOW_HTTP = "send 'Authorization: Bearer <token>'"
HOW_WEBSOCKET = "offer the subprotocols graytrack, graytrack.bearer.<token>"  # within a close reason's 123 bytes


def offered_subprotocols(headers: dict[str, str]) -> list[str]:
    return [p.strip() for p in headers.get("sec-websocket-protocol", "").split(",") if p.strip()]


def presented_token(headers: dict[str, str], query_string: bytes) -> str:
    """The token a request presents for reading: header, then subprotocol, then query ('' if none)."""
    scheme, _, given = headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and given.strip():
        return given.strip()
    for protocol in offered_subprotocols(headers):
        if protocol.startswith(BEARER_SUBPROTOCOL):
            return protocol[len(BEARER_SUBPROTOCOL):]
    query = parse_qs(query_string.decode("latin-1"))
    return (query.get("token") or [""])[0]


def is_open(path: str) -> bool:
    """Served to anyone under every policy."""
    return path in OPEN_PATHS or path.startswith(OPEN_PREFIXES)


def reads_need_token(read_token: ReadToken, beyond_loopback: bool) -> bool:
    return read_token == "always" or (read_token == "beyond_loopback" and beyond_loopback)


def read_refusal(policy: ReadToken, beyond_loopback: bool, path: str, given: str,
                 matches: Callable[[str], bool], websocket: bool = False) -> str | None:
    """Why reading ``path`` with ``given`` is refused under ``policy`` (None: allowed)."""
    if is_open(path) or not reads_need_token(policy, beyond_loopback):
        return None
    if not given:
        where = "beyond loopback" if policy == "beyond_loopback" else "(read_token = always)"
        return f"this daemon needs the token for reads {where}: {HOW_WEBSOCKET if websocket else HOW_HTTP}"
    if not matches(given):
        return "invalid bearer token"
    return None
