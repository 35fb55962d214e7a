"""What keeps the daemon closed to the web, in one place.

* every HTTP answer says it may not be framed (``X-Frame-Options: DENY``, CSP ``frame-ancestors
  'none'``) and may run no inline script (CSP ``script-src 'self'``): a page on another origin
  cannot put the status page under an operator's click;
* a request that changes state is refused before its body is read when the bearer token is
  missing or wrong, and its body may not exceed 64 KiB (checked while it arrives, before any
  parsing): a large anonymous body costs the daemon nothing;
* every HTTP request and the WebSocket name this machine in exactly one Host (a DNS-rebound name is
  refused: a page on another site could otherwise read the status, the events and the recordings
  through a name it controls; a second Host could name another to a proxy in front), and a request
  target in absolute form names it too; the WebSocket accepts a browser only from its own origin (or a
  configured one);
* a read (the stream included) asks for the token as ``[daemon] read_token`` says, the same for
  every read route (``read_policy.py``);
* an error the routes did not foresee is still a JSON answer with these headers (logged with its
  traceback), never a bare text 500; the answers the HTTP protocol writes itself (limits.py) carry them too;
* every GET route answers HEAD: the GET's status and headers, without the body.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import logging
import re
import socket
from typing import Any, Awaitable, Callable

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from graytrack.service.daemon.api.read_policy import presented_token, read_refusal
from graytrack.service.daemon.settings import DaemonConfig

log = logging.getLogger("graytrack.daemon")
MAX_BODY = 64 * 1024
MUTATING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1", "ip6-localhost"})
SAFE_HOST = re.compile(r"^[A-Za-z0-9.\-:\[\]]{1,255}$")
# the scope extension the HTTP protocol (limits.py) puts a request target's host in, when the target is in
# absolute form (RFC 9112 §3.2.2: then the target, not Host, names the server)
TARGET_AUTHORITY = "graytrack.target_authority"


def token_matches(given: str, token: str) -> bool:
    return bool(given) and hmac.compare_digest(given.strip().encode(), token.encode())


def bearer(headers: dict[str, str]) -> str:
    scheme, _, given = headers.get("authorization", "").partition(" ")
    return given.strip() if scheme.lower() == "bearer" else ""


def split_host(host: str) -> str:
    """The name part of a Host header (``[::1]:8000`` → ``::1``, ``a.b:80`` → ``a.b``)."""
    if host.startswith("["):
        return host[1:].partition("]")[0]
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def is_loopback(host: str) -> bool:
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class WebPolicy:
    """The daemon's own view of which hosts and origins are its own."""

    def __init__(self, daemon: DaemonConfig, token: str) -> None:
        self.token = token
        self.bind_host = daemon.host
        self.beyond_loopback = not is_loopback(daemon.host)
        self.read_token = daemon.read_token
        self.allowed_origins = frozenset(o.rstrip("/") for o in daemon.allowed_origins)
        names = set(LOOPBACK_NAMES) | {daemon.host} | set(daemon.allowed_hosts)
        if self.beyond_loopback:
            hostname = socket.gethostname()
            names |= {hostname, f"{hostname}.local"}
        self.host_names = frozenset(n.lower() for n in names)

    def host_allowed(self, host_header: str) -> bool:
        """This machine by a name it has, or any IP literal (a rebinding attack needs a foreign *name*)."""
        name = split_host(host_header).lower()
        if name in self.host_names:
            return True
        try:
            ipaddress.ip_address(name)
            return True
        except ValueError:
            return False

    def origin_allowed(self, origin: str | None, host_header: str) -> bool:
        if origin is None:  # not a browser: Origin is what browsers send, and cannot be forged by a page
            return True
        origin = origin.rstrip("/")
        return origin in self.allowed_origins or origin in (f"http://{host_header}", f"https://{host_header}")

    def host_refusal(self, scope: Scope) -> str | None:
        """Why this request does not name this daemon, or None: exactly one Host header (RFC 9112 §3.2: a
        second one, foreign first, is how a proxy and the daemon could be told different names) naming it,
        and a request target in absolute form (``GET http://name/path``) naming it too."""
        hosts = [value.decode("latin-1") for name, value in scope.get("headers", []) if name.lower() == b"host"]
        if len(hosts) != 1:
            return f"a request names its Host exactly once (this one: {len(hosts)} Host headers)"
        if not self.host_allowed(hosts[0]):
            return (f"Host {hosts[0][:100]!r} is not this daemon: reach it by its address, or add the name to "
                    "[daemon] allowed_hosts")
        authority = scope.get("extensions", {}).get(TARGET_AUTHORITY)
        if authority is not None and not self.host_allowed(authority):
            return (f"the request's target names {authority[:100]!r}, not this daemon: reach it by its address, "
                    "or add the name to [daemon] allowed_hosts")
        return None

    def websocket_refusal(self, scope: Scope) -> str | None:
        """Why this WebSocket handshake is refused, or None."""
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        refusal = self.host_refusal(scope)
        if refusal is not None:
            return refusal
        if not self.origin_allowed(headers.get("origin"), host):
            return f"Origin {headers.get('origin')!r} is not allowed"
        return self.read_refusal(scope, headers, websocket=True)

    def read_refusal(self, scope: Scope, headers: dict[str, str], websocket: bool = False) -> str | None:
        """Why this read is refused by ``[daemon] read_token`` (read_policy.py), or None."""
        return read_refusal(self.read_token, self.beyond_loopback, scope.get("path", ""),
                            presented_token(headers, scope.get("query_string", b"")),
                            lambda given: token_matches(given, self.token), websocket)

    def csp(self, host_header: str) -> str:
        return csp(host_header)


def csp(host_header: str) -> str:
    """The Content-Security-Policy of an answer to a request naming ``host_header`` (its WebSocket allowed)."""
    connect = "'self'"
    if SAFE_HOST.match(host_header):
        connect += f" ws://{host_header} wss://{host_header}"
    return ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
            f"connect-src {connect}; frame-ancestors 'none'; base-uri 'none'; form-action 'self'; "
            "object-src 'none'")


def security_headers(host_header: str = "") -> list[tuple[bytes, bytes]]:
    """The headers every HTTP answer carries, the app's and those the protocol writes itself (a malformed
    request, a timeout, a refusal: no Host was read there, so no WebSocket address in the policy)."""
    return [(b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
            (b"referrer-policy", b"no-referrer"), (b"content-security-policy", csp(host_header).encode())]


async def _send_json(send: Send, status: int, body: dict[str, Any], headers: list[tuple[bytes, bytes]]) -> None:
    payload = json.dumps(body).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode()),
                            *headers]})
    await send({"type": "http.response.body", "body": payload})


class WebGuard:
    """ASGI middleware: the HTTP half of the module's rules (headers, token before body, body limit)."""

    def __init__(self, app: ASGIApp, policy: WebPolicy, max_body: int = MAX_BODY) -> None:
        self.app, self.policy, self.max_body = app, policy, max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope.get("headers", [])}
        security = security_headers(headers.get("host", ""))

        started = False
        head = scope["method"] == "HEAD"
        if head:  # every GET route answers HEAD: the GET's status and headers, no body
            scope = {**scope, "method": "GET"}

        async def send_secured(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                own = message.get("headers", [])
                extra = [h for h in security if not any(k.lower() == h[0] for k, _ in own)]  # a route may be stricter
                message = {**message, "headers": [*own, *extra]}
            elif head and message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        refusal = self.policy.host_refusal(scope)
        if refusal is not None:
            await _send_json(send_secured, 400, {"error": refusal}, [])
            return
        if scope["method"] in MUTATING:
            given = bearer(headers)
            if not given:
                await _send_json(send_secured, 401,
                                 {"error": "missing bearer token: send 'Authorization: Bearer <token>'"},
                                 [(b"www-authenticate", b"Bearer")])
                return
            if not token_matches(given, self.policy.token):
                await _send_json(send_secured, 401, {"error": "invalid bearer token"},
                                 [(b"www-authenticate", b"Bearer")])
                return
            receive = await self._bounded_body(headers, receive, send_secured)
            if receive is None:
                return
        else:
            refusal = self.policy.read_refusal(scope, headers)
            if refusal is not None:
                await _send_json(send_secured, 401, {"error": refusal}, [(b"www-authenticate", b"Bearer")])
                return
        try:
            await self.app(scope, receive, send_secured)
        except Exception:  # noqa: BLE001 - whatever a route did not foresee: JSON, headers, the daemon goes on
            log.exception("unhandled error answering %s %s", scope["method"], scope.get("path", ""))
            if started:
                raise
            await _send_json(send_secured, 500, {"error": "internal error (the daemon's log has the details)"}, [])

    async def _bounded_body(self, headers: dict[str, str], receive: Receive,
                            send: Send) -> Callable[[], Awaitable[Message]] | None:
        """The whole body (at most ``max_body`` bytes) replayed to the app; None after answering 413 or when
        the client left before sending all of it."""
        too_large = {"error": f"request body over {self.max_body // 1024} KiB"}
        declared = headers.get("content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_body):
            await _send_json(send, 413, too_large, [(b"connection", b"close")])
            return None
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return None  # gone before its body was whole (or timed out, limits.py): nothing runs on a part
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body:
                await _send_json(send, 413, too_large, [(b"connection", b"close")])
                return None
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body, delivered = b"".join(chunks), False

        async def replay() -> Message:
            nonlocal delivered
            if not delivered:
                delivered = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        return replay
