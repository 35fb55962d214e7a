"""What one client may cost the daemon: connections, time to send a request, work queued on a connection,
WebSocket frames.

The daemon is reached without a token for everything that only reads (the page, the stream), so a
careless or hostile program, local or on the lab network, must not be able to exhaust it. Measured before
these limits (issue #38): 30 sockets on ``/ws/position`` each declaring a 15 MiB frame and sending 14 MiB
grew the daemon's RSS from 236 to 656 MB (uvicorn's default frame limit is 16 MiB); 500 connections
trickling a request head byte by byte were never closed. And (issue #48) uvicorn's protocol parses every
request a read brings in at once and queues the pipelined ones, resuming reads after each answer whatever
is queued: ten connections writing ``GET /api/status`` 100 at a time grew RSS by hundreds of MB in
seconds, kept after they closed, and the frame loop lost frames. uvicorn has no timeout on *receiving* a
request: ``timeout_keep_alive`` covers only the idle time between requests and is reset by every byte, and
an ASGI middleware runs only once the head is parsed. So the guard lives in the protocol that parses the
bytes, :class:`GuardedHttpProtocol` (uvicorn's httptools protocol, which uvicorn's ``auto`` picks here),
and in :class:`ws_protocol.StreamProtocol` for upgraded connections:

* a connection's requests are parsed one at a time: the parser is handed the bytes up to the end of a
  request and no further, and the next request's bytes wait unparsed, the socket not read, until the
  answer to the current one is written (pipelining is served in order, nothing piles up: a connection
  holds at most one read of bytes, 256 KiB, and one request in work);
* a client (its address; an IPv6 one by its /64) begins at most ``requests_per_s_per_client`` requests a
  second, and all together ``requests_per_s`` (each a second's worth at once): beyond, the next request
  waits its turn unparsed (:class:`RequestBudget`); and serving altogether (the event loop and the request
  threads, the stream's deliveries apart) takes at most ``serving_share`` of a core, measured
  (:class:`ServingShare`): a request's cost is what it takes, not what one was assumed to take (an
  ``/api/status`` answer measured 3.7 ms of CPU beside a 200 Hz frame loop on a 2-core machine, where the
  rates alone had assumed 1 ms). So a flood spends a bounded share of the interpreter the frame loop and the
  stage link run in, and is slowed, not refused;
* an answer the client does not take (the transport's buffer above its high-water mark) for
  ``request_timeout_s`` closes the connection;
* a request (head and body) must arrive whole within ``request_timeout_s`` of its first byte, or of
  the connection's opening when it sends nothing: else ``408`` with a reason (nothing at all sent:
  closed), the connection closed;
* a request head (target and headers) over :data:`MAX_HEAD_BYTES` is ``431`` and closed;
* beyond ``max_connections_per_client`` open connections from one client (its address; an IPv6 one by
  its /64), or ``max_connections`` in all, a request gets ``503`` with a reason and a WebSocket is
  accepted and closed ``1013`` (try again later) with a reason; beyond twice either a connection is
  closed as soon as it opens (the process keeps its file descriptors for its own files);
* a malformed request gets ``400`` as JSON with the security headers, like every answer the protocol
  writes itself;
* a WebSocket frame over :data:`WS_MAX_FRAME_BYTES` closes the connection ``1009`` before its
  payload is read (websockets checks the declared length), and the stream closes on any message
  over :data:`WS_CONTROL_BYTES` (``api/stream.py``): the stream reads nothing from its clients.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import threading
import time
from collections import deque
from functools import partial
from typing import Any, Callable

import httptools
from uvicorn.protocols.http.flow_control import FlowControl
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from graytrack.service.daemon.api.security import TARGET_AUTHORITY, security_headers
from graytrack.service.daemon.settings import DaemonConfig

log = logging.getLogger("graytrack.daemon")
MAX_HEAD_BYTES = 16 * 1024  # request target plus headers; browsers send under 8 KiB
WS_MAX_FRAME_BYTES = 4 * 1024  # what websockets accepts in one frame/message before it closes 1009
WS_CONTROL_BYTES = 1024  # the largest client message the stream ignores (it reads none)
WS_TRY_AGAIN_LATER = 1013
WS_MESSAGE_TOO_BIG = 1009
HARD_CAP_FACTOR = 2  # beyond this many times a connection limit a connection is closed unanswered
REFUSAL_LOG_INTERVAL_S = 60.0
HEAD_TOO_LARGE = f"the request's target and headers exceed {MAX_HEAD_BYTES} bytes"
COST_REQUESTS = 16  # requests a measurement of the mean cost of one spans (fewer: serving's other work dominates)
COST_WINDOW_S = 1.0  # ... within this: a slower trickle says more about the rest of serving than about requests
INITIAL_COST_S = 0.002  # a request's CPU before any was measured
MAX_COST_S = 0.05  # the most one request is charged up front (a measurement stretched by a stall is not a cost)
# The rig before serving: a frame the rig loses while serving has its share cuts that share by this factor at
# once (down to RIG_FIRST_FLOOR of it) and drops what the bucket holds; it then grows back linearly, whole after
# RIG_FIRST_RECOVER_S without a loss. The declared share is what serving may take on a host with room; on a slower
# or busier one the frame loop's own need decides (the interpreter is one: what serving takes, the loop waits for).
RIG_FIRST_CUT = 0.5
RIG_FIRST_FLOOR = 0.125  # of the declared share: a status page polled every second still answers at once
RIG_FIRST_RECOVER_S = 10.0  # host seconds without a frame lost for the whole share to come back
BURST_S = 1.0  # the request budget's buckets hold a second's worth: a page loading its files at once never waits
MAX_TRACKED_CLIENTS = 1024  # request budgets kept before the full ones are forgotten
IPV6_CLIENT_PREFIX = 64  # one IPv6 client is its /64: a host picks addresses within it at will (SLAAC, privacy)


def client_key(client: tuple[str, int] | None) -> str:
    """Whose connection this is, for the per-client cap: the remote address (an IPv6 one by its /64)."""
    if client is None:  # a Unix socket: one local client
        return "local"
    try:
        address = ipaddress.ip_address(client[0])
    except ValueError:
        return client[0]
    if isinstance(address, ipaddress.IPv6Address):
        if address.ipv4_mapped is not None:
            return str(address.ipv4_mapped)
        if not address.is_loopback:
            return str(ipaddress.ip_network(f"{address}/{IPV6_CLIENT_PREFIX}", strict=False))
    return str(address)


class Ticket:
    """One open connection counted against its client; released once, by whichever protocol ends it (the
    HTTP one, or the WebSocket one it hands the connection to)."""

    def __init__(self, counts: dict[str, int], key: str) -> None:
        self._counts, self.key, self.held = counts, key, True
        counts[key] = counts.get(key, 0) + 1

    @property
    def client_connections(self) -> int:
        """The client's open connections, this one included."""
        return self._counts.get(self.key, 0)

    def release(self) -> None:
        if self.held:
            self.held = False
            left = self._counts[self.key] - 1
            if left:
                self._counts[self.key] = left
            else:
                del self._counts[self.key]


WORKER_THREAD = "AnyIO worker thread"  # the name of anyio's threads, which run the sync endpoints (FastAPI's pool)


class ServingCpu:
    """CPU seconds the threads that serve clients have used: the event loop's (the thread of the first call: the
    protocol asks on the loop) and anyio's worker threads' (found by name; a worker that ended keeps what it was
    counted). The rig's threads, and any other (a test's own clients in the same process), are not counted."""

    def __init__(self) -> None:
        self._loop_clock: int | None = None
        self._workers: dict[int, float] = {}  # a worker thread's ident -> its CPU seconds last read
        self._ended = 0.0  # what workers counted so far used, ended or not (their increments summed)

    def __call__(self) -> float:
        if self._loop_clock is None:
            self._loop_clock = time.pthread_getcpuclockid(threading.get_ident())
        workers: dict[int, float] = {}
        counted = self._ended
        for thread in threading.enumerate():
            ident = thread.ident
            if thread.name != WORKER_THREAD or ident is None:
                continue
            try:
                used = time.clock_gettime(time.pthread_getcpuclockid(ident))
            except OSError:  # ended between the listing and the reading
                continue
            counted += max(used - self._workers.get(ident, 0.0), 0.0)
            workers[ident] = used
        self._workers, self._ended = workers, counted
        return counted + time.clock_gettime(self._loop_clock)


class ServingShare:
    """The share of one core serving may take (``share``, CPU seconds per second), measured on ``cpu`` (CPU
    seconds serving has used: :class:`ServingCpu`'s, the stream's deliveries apart).

    A bucket of CPU seconds, filled at ``share`` and holding ``burst_s`` worth, from which what serving used is
    taken as it is measured, at each request begun. While the bucket holds anything a request goes at once;
    in debt, it waits until the rate has paid the debt back, and is charged the mean cost of recent requests at
    once, so that requests waiting together go one after another instead of all at the same refill (once it
    goes, what it costs is measured instead, and the charge comes back). The debt is held to one burst: a cost
    that is not the requests' (a collection, a thread's end) never holds one back longer than ``burst_s``.

    ``lost`` (frames the rig has lost so far; a count that falls is a new frame loop's) puts the rig first: a
    loss seen at a request cuts the share in force (``scale`` of the declared one, :data:`RIG_FIRST_CUT`) and
    empties the bucket; the share grows back over :data:`RIG_FIRST_RECOVER_S` without one."""

    def __init__(self, share: float, burst_s: float, cpu: Callable[[], float],
                 monotonic: Callable[[], float] = time.monotonic, lost: Callable[[], int] | None = None) -> None:
        self.declared, self.capacity = share, share * burst_s
        self.scale = 1.0  # of the declared share, in force (below 1 while the rig has been losing frames)
        self.cuts = 0  # times a frame lost cut the share
        self._cpu, self._monotonic, self._lost = cpu, monotonic, lost
        self._lost_seen = lost() if lost is not None else 0
        # (measured from the first request on: the loop's thread is the one that asks, not the one that builds this)
        self._level, self._at, self._used = self.capacity, monotonic(), math.nan
        self._charged: deque[tuple[float, float]] = deque()  # (when it goes, estimate) of requests waiting
        self.cost_s = INITIAL_COST_S  # the mean CPU of one request, from the last busy window
        self._window = (self._at, math.nan, 0)  # start, CPU then, requests since

    @property
    def used_s(self) -> float:
        """CPU seconds serving had used at the last request begun (0 before the first)."""
        return 0.0 if math.isnan(self._used) else self._used

    @property
    def share(self) -> float:
        """The share of a core in force (CPU seconds per second)."""
        return self.declared * self.scale

    def _rig_first(self, now: float) -> bool:
        """Grow the share back for the time since the last request; cut it if the rig lost a frame meanwhile."""
        self.scale = min(1.0, self.scale + (now - self._at) / RIG_FIRST_RECOVER_S)
        if self._lost is None:
            return False
        lost, seen = self._lost(), self._lost_seen
        self._lost_seen = lost
        if lost <= seen:  # none (or a new frame loop, counting from 0 again)
            return False
        self.scale = max(RIG_FIRST_FLOOR, self.scale * RIG_FIRST_CUT)
        self.cuts += 1
        return True

    def take(self) -> float:
        """The seconds a request begun now waits for the share (0: go now)."""
        now, used = self._monotonic(), self._cpu()
        if math.isnan(self._used):
            self._used, self._window = used, (now, used, 0)
        refill = self.share * (now - self._at)  # at the share in force since the last request
        cut = self._rig_first(now)
        level = min(self.capacity * self.scale, self._level + refill) - (used - self._used)
        charged = self._charged
        while charged and charged[0][0] <= now:  # gone: from now on what it costs is measured instead
            level += charged.popleft()[1]
        if cut:  # what the bucket held is the rig's again: this request waits its turn too
            level = min(level, 0.0)
        began, used0, count = self._window
        count += 1
        if count >= COST_REQUESTS:
            if now - began <= COST_WINDOW_S:
                self.cost_s = min(max((used - used0) / count, 0.0), MAX_COST_S)
            self._window = (now, used, 0)
        else:
            self._window = (began, used0, count)
        wait = 0.0
        if level < 0 or cut:
            level = max(level, -self.capacity) - self.cost_s
            wait = -level / self.share
            charged.append((now + wait, self.cost_s))
        self._level, self._at, self._used = level, now, used
        return wait


class RequestBudget:
    """Token buckets of requests begun: one per client, one for all, each holding ``burst_s`` worth of its rate.
    A request takes a token of both at once, lent when there is none: it then waits until the debt is paid
    back by the rate (its bytes unparsed, the socket unread), and goes on without asking again. Paced, never
    refused; each waiting connection is woken once, at its turn. A connection has one request in work and gives
    its lent token back when it closes while waiting, so the debt is at most the waiting connections' count."""

    def __init__(self, per_client_hz: float, total_hz: float, burst_s: float,
                 monotonic: Callable[[], float] = time.monotonic, share: ServingShare | None = None) -> None:
        self.per_client_hz, self.total_hz, self.burst_s = per_client_hz, total_hz, burst_s
        self._monotonic = monotonic
        self.share = share  # serving's measured share of a core, when one is set
        self._total = (total_hz * burst_s, monotonic())
        self._clients: dict[str, tuple[float, float]] = {}

    def _level(self, bucket: tuple[float, float], rate: float, now: float) -> float:
        tokens, at = bucket
        return min(rate * self.burst_s, tokens + rate * (now - at))

    def take(self, key: str) -> float:
        """Take a token for a request of client ``key``: the seconds it has to wait for it (0: go now)."""
        now = self._monotonic()
        total = self._level(self._total, self.total_hz, now) - 1.0
        own = self._level(self._clients.get(key, (self.per_client_hz * self.burst_s, now)), self.per_client_hz,
                          now) - 1.0
        self._total, self._clients[key] = (total, now), (own, now)
        if len(self._clients) > MAX_TRACKED_CLIENTS:
            self._forget_full(now)
        waits = max(-total / self.total_hz, -own / self.per_client_hz, 0.0)
        return max(waits, self.share.take()) if self.share is not None else waits

    def give_back(self, key: str) -> None:
        """Return the token a request of ``key`` was lent and never used (its connection closed while it waited):
        the debt stays that of the requests waiting now, whatever comes and goes."""
        now = self._monotonic()
        total = self._level(self._total, self.total_hz, now)
        own = self._level(self._clients.get(key, (0.0, now)), self.per_client_hz, now)
        self._total = (min(total + 1.0, self.total_hz * self.burst_s), now)
        self._clients[key] = (min(own + 1.0, self.per_client_hz * self.burst_s), now)

    def _forget_full(self, now: float) -> None:
        """Drop the clients whose bucket has filled again: a new one starts full anyway."""
        full = self.per_client_hz * self.burst_s
        for key in [k for k, b in self._clients.items() if self._level(b, self.per_client_hz, now) >= full]:
            del self._clients[key]


class ConnectionLimits:
    """The limits (from ``[daemon]``) and what they refused, shared by every connection's protocol."""

    def __init__(self, daemon: DaemonConfig, monotonic: Callable[[], float] = time.monotonic,
                 serving_cpu: Callable[[], float] | None = None, rig_lost: Callable[[], int] | None = None) -> None:
        self.max_connections = daemon.max_connections
        self.max_per_client = daemon.max_connections_per_client
        self.request_timeout_s = daemon.request_timeout_s
        self.keep_alive_s = daemon.keep_alive_s
        self.refused = 0  # requests and WebSockets answered 503/1013 for a connection limit
        self.dropped = 0  # connections closed unanswered beyond a hard cap
        self.timed_out = 0  # requests closed for not arriving within request_timeout_s
        self.oversized = 0  # request heads over MAX_HEAD_BYTES and WebSocket messages over the control size
        self.stalled = 0  # connections closed for not taking their answers within request_timeout_s
        self._by_client: dict[str, int] = {}
        share = (ServingShare(daemon.serving_share, BURST_S, serving_cpu, monotonic, rig_lost)
                 if serving_cpu is not None else None)
        self.budget = RequestBudget(daemon.requests_per_s_per_client, daemon.requests_per_s, BURST_S, monotonic, share)
        self.paced = 0  # requests that waited for the request budget
        self._monotonic = monotonic
        self._logged_at = -REFUSAL_LOG_INTERVAL_S
        self._unlogged = 0

    def admit(self, client: tuple[str, int] | None) -> Ticket:
        """Count a new connection from ``client`` (the remote address uvicorn reports)."""
        return Ticket(self._by_client, client_key(client))

    def over(self, open_connections: int, ticket: Ticket) -> str | None:
        """Why a connection that makes ``open_connections`` open ones (itself included) is refused, or None."""
        if ticket.client_connections > self.max_per_client:
            return (f"the daemon serves at most {self.max_per_client} connections from one client at once ([daemon] "
                    f"max_connections_per_client; {ticket.key} has {ticket.client_connections}); close one first")
        if open_connections > self.max_connections:
            return (f"the daemon serves at most {self.max_connections} connections at once ([daemon] "
                    f"max_connections); try again when one closes")
        return None

    def beyond_hard_cap(self, open_connections: int, ticket: Ticket) -> bool:
        return (open_connections > HARD_CAP_FACTOR * self.max_connections
                or ticket.client_connections > HARD_CAP_FACTOR * self.max_per_client)

    def note_refusal(self, what: str) -> None:
        """Count a refusal; log at most one line a minute (a flood must not flood the log too)."""
        self._unlogged += 1
        now = self._monotonic()
        if now - self._logged_at >= REFUSAL_LOG_INTERVAL_S:
            log.warning("connection limits: refused %d connections since the last report (latest: %s)",
                        self._unlogged, what)
            self._logged_at, self._unlogged = now, 0

    def counters(self) -> dict[str, int]:
        return {"refused": self.refused, "dropped": self.dropped, "timed_out": self.timed_out,
                "oversized": self.oversized, "stalled": self.stalled}


def json_response(status: int, phrase: str, error: str, headers: tuple[tuple[str, str], ...] = ()) -> bytes:
    """A complete HTTP/1.1 answer ``{"error": ...}`` with the security headers that closes the connection
    (written by the protocol itself: the request never reached the app)."""
    body = json.dumps({"error": error}).encode()
    head = [f"HTTP/1.1 {status} {phrase}", "content-type: application/json", f"content-length: {len(body)}",
            "connection: close", *(f"{name}: {value}" for name, value in headers),
            *(f"{name.decode()}: {value.decode()}" for name, value in security_headers())]
    return ("\r\n".join(head) + "\r\n\r\n").encode("latin-1") + body


async def _answer(status: int, error: str, headers: tuple[tuple[bytes, bytes], ...], scope: dict[str, Any],
                  receive: Any, send: Any) -> None:
    """The ASGI app a refused request is answered by, in place of the daemon's: ``status`` with the reason, closed."""
    body = json.dumps({"error": error}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers, *security_headers()]})
    await send({"type": "http.response.body", "body": body})


async def _refuse(limits: ConnectionLimits, reason: str, scope: dict[str, Any], receive: Any, send: Any) -> None:
    """A request on a connection beyond a limit: 503 with the reason."""
    limits.refused += 1
    limits.note_refusal(f"{scope.get('method')} {scope.get('path')} answered 503")
    await _answer(503, reason, ((b"retry-after", b"1"),), scope, receive, send)


def _blank_line_end(data: bytes, start: int, before: bytes) -> int:
    """The end of the first blank line (``\\n\\r\\n`` or ``\\n\\n``) in ``data[start:]``, where ``before`` are the
    bytes just before ``start`` (a blank line may straddle the two), or ``len(data)`` without one. A request's
    head ends at a blank line, and so does a chunked body; an earlier match inside a chunk only splits the
    bytes fed to the parser once more."""
    if before.endswith(b"\n") and (data.startswith(b"\n", start) or data.startswith(b"\r\n", start)):
        return start + (1 if data.startswith(b"\n", start) else 2)
    if before.endswith(b"\n\r") and data.startswith(b"\n", start):
        return start + 1
    ends = [found + size for mark, size in ((b"\n\r\n", 3), (b"\n\n", 2)) if (found := data.find(mark, start)) >= 0]
    return min(ends, default=len(data))


class ParsedFlow(FlowControl):
    """uvicorn's flow control, but reading stays paused while the connection holds bytes not yet parsed: the
    answer in work resumes reading when it waits for its body or is written, which would let the next
    requests' bytes pile up behind it."""

    def __init__(self, transport: Any, protocol: "GuardedHttpProtocol") -> None:
        super().__init__(transport)
        self._protocol = protocol

    def resume_reading(self) -> None:
        if not self._protocol.holds_unparsed:
            super().resume_reading()


class GuardedHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a deadline on receiving each request, a bound on its head, one request
    parsed at a time, a deadline on a client taking its answers, and the connection limits. Built by uvicorn
    through :func:`server_protocols` (``limits`` bound there)."""

    def __init__(self, *args: Any, limits: ConnectionLimits, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.limits = limits
        self.ticket: Ticket | None = None
        self.deadline: Any = None  # asyncio.TimerHandle while a request is being received
        self.stall: Any = None  # asyncio.TimerHandle while the transport's buffer is above its high-water mark
        self.received_any = False
        self.head_bytes = 0
        self.in_head = False
        self.inbox = b""  # bytes received; inbox[parsed_to:] not given to the parser yet
        self.parsed_to = 0
        self.fed_tail = b""  # the last bytes given to the parser
        self.in_body = False  # the parser is inside a request's body
        self.body_left: int | None = None  # of a body with a declared length; None: chunked (or none declared yet)
        self.chunked = False
        self.held = False  # reading paused here because the next request waits for an answer
        self.pacing: Any = None  # asyncio.TimerHandle while the next request waits for the request budget
        self.budgeted = False  # the next request has its token (taken, its wait over or under way)

    @property
    def holds_unparsed(self) -> bool:
        return self.parsed_to < len(self.inbox)

    def connection_made(self, transport: Any) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self.flow = ParsedFlow(transport, self)
        self.ticket = self.limits.admit(self.client)
        open_connections = len(self.connections)
        if self.limits.beyond_hard_cap(open_connections, self.ticket):
            self.limits.dropped += 1
            self.limits.note_refusal("closed at once beyond a hard cap")
            transport.close()
            return
        refusal = self.limits.over(open_connections, self.ticket)
        if refusal is not None:  # answered once its head is in (a WebSocket: by StreamProtocol, 1013)
            self.app = partial(_refuse, self.limits, refusal)
        self._arm()

    def take_ticket(self) -> Ticket | None:
        """The connection's place in its client's count, handed to the WebSocket protocol it is upgraded to."""
        ticket, self.ticket = self.ticket, None
        return ticket

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
        # a 408 only where no answer is half-written (a keep-alive connection's next request gets one too)
        if self.received_any and (self.cycle is None or self.cycle.response_complete
                                  or not self.cycle.response_started):
            self.transport.write(json_response(
                408, "Request Timeout", f"the request did not arrive whole within {self.limits.request_timeout_s:g} s "
                                        "([daemon] request_timeout_s)"))
        self.transport.close()

    def pause_writing(self) -> None:
        super().pause_writing()
        if self.stall is None:
            self.stall = self.loop.call_later(self.limits.request_timeout_s, self._stalled)

    def resume_writing(self) -> None:
        super().resume_writing()
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None

    def _stalled(self) -> None:
        """The client took none of its answers for request_timeout_s: closed, what was buffered for it dropped."""
        self.stall = None
        if not self.transport.is_closing():
            self.limits.stalled += 1
            self.limits.note_refusal("closed: its answers not read")
            self.transport.abort()

    def data_received(self, data: bytes) -> None:
        self.received_any = True
        self.inbox = self.inbox[self.parsed_to:] + data if self.holds_unparsed else data
        self.parsed_to = 0
        self._parse()

    def _answer_pending(self) -> bool:
        return self.cycle is not None and not self.cycle.response_complete

    def _parse(self) -> None:
        """Give the parser the received bytes up to the end of the request they hold, then the next request's
        once no answer is in work: the answer to one request is written before the next is parsed."""
        while self.holds_unparsed and not self.transport.is_closing():
            if self._answer_pending() and not self.in_body:  # the next request's bytes: they wait
                self._hold()
                return
            if self.pacing is not None:  # waiting for its turn in the budget
                return
            if not self.in_head and not self.in_body and not self.budgeted and self.ticket is not None:
                wait_s = self.limits.budget.take(self.ticket.key)  # a new request begins: the budget's token
                self.budgeted = True
                if wait_s > 0:
                    self.limits.paced += 1
                    self._hold()
                    self._disarm()  # the wait is the daemon's: the request's time starts once it is parsed
                    self._unset_keepalive_if_required()
                    self.pacing = self.loop.call_later(wait_s, self._paced)
                    return
            start = self.parsed_to
            if self.in_body and self.body_left is not None:
                end = start + max(1, min(self.body_left, len(self.inbox) - start))
            else:
                end = _blank_line_end(self.inbox, start, self.fed_tail)
            piece, self.parsed_to = self.inbox[start:end], end
            self.fed_tail = (self.fed_tail + piece)[-2:]
            super().data_received(piece)
            upgraded = self.transport.get_protocol()
            if upgraded is not self:  # a WebSocket from here: what followed its handshake is its
                rest, self.inbox, self.parsed_to = self.inbox[end:], b"", 0
                self.held = False
                self.transport.resume_reading()
                if rest:
                    upgraded.data_received(rest)
                return
            if self.in_head and self.head_bytes > MAX_HEAD_BYTES and not self.transport.is_closing():
                self.limits.oversized += 1
                self._disarm()
                self.transport.write(json_response(431, "Request Header Fields Too Large", HEAD_TOO_LARGE))
                self.transport.close()
        if not self.holds_unparsed:
            self.inbox, self.parsed_to = b"", 0
            if self.held:
                self.held = False
                self.flow.resume_reading()

    def _hold(self) -> None:
        if not self.held:
            self.held = True
            self.flow.pause_reading()

    def _paced(self) -> None:
        self.pacing = None
        if not self.transport.is_closing():
            self._parse()

    def send_400_response(self, msg: str) -> None:
        """A request the parser refused: JSON with the security headers like every other answer, closed."""
        self._disarm()
        self.transport.write(json_response(400, "Bad Request", "the request is not valid HTTP/1.1 (the parser "
                                                               "refused it)"))
        self.transport.close()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self.holds_unparsed and not self.transport.is_closing():
            self._parse()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None
        if self.pacing is not None:  # gone while its next request waited: the lent token is returned
            self.pacing.cancel()
            self.pacing = None
            if self.ticket is not None:
                self.limits.budget.give_back(self.ticket.key)
        if self.ticket is not None:
            self.ticket.release()
        self.inbox, self.parsed_to = b"", 0
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self.head_bytes, self.in_head, self.budgeted = 0, True, False
        self.body_left, self.chunked = None, False
        self._arm()

    def on_url(self, url: bytes) -> None:
        super().on_url(url)
        self.head_bytes += len(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        super().on_header(name, value)
        self.head_bytes += len(name) + len(value) + 4
        name = name.lower()
        if name == b"content-length" and value.strip().isdigit():  # the parser refuses any other
            self.body_left = int(value)
        elif name == b"transfer-encoding":
            self.chunked = True

    def on_headers_complete(self) -> None:
        self.in_head = False
        self.in_body = True
        if self.chunked or self.body_left is None:
            self.body_left = None if self.chunked else 0
        if self.head_bytes > MAX_HEAD_BYTES:  # arrived whole in one read: answered in place of the app
            self.limits.oversized += 1
            self.app = partial(_answer, 431, HEAD_TOO_LARGE, ())
        authority = self._absolute_form_authority()
        if authority is not None:  # checked with Host by the app's guard (api/security.py)
            self.scope.setdefault("extensions", {})[TARGET_AUTHORITY] = authority  # type: ignore[typeddict-item]
        super().on_headers_complete()

    def _absolute_form_authority(self) -> str | None:
        """The host a request target in absolute form names (``http://name:port/path``), for the Host check."""
        if self.url.startswith(b"/") or self.url == b"*":
            return None
        try:
            parsed = httptools.parse_url(self.url)
        except httptools.HttpParserInvalidURLError:
            return None  # the parser answers 400
        if not parsed.host:
            return None
        host = parsed.host.decode("latin-1")
        return f"[{host}]" if ":" in host else host

    def on_body(self, body: bytes) -> None:
        if self.body_left is not None:
            self.body_left -= len(body)
        super().on_body(body)

    def on_message_complete(self) -> None:
        self.in_body = False
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
