"""What the daemon writes to its log: never a secret, and never so much that its own faults are lost.

**Secrets.** uvicorn logs each WebSocket handshake with its query (``"WebSocket /ws/position?token=…"
[accepted]`` at the default level) and, at ``debug``, every request's target. :class:`Redact` sits on
every handler the process logs through (the daemon's, uvicorn's, a library's) and replaces, in the
message, its arguments, a traceback's text and a stack: the daemon's token wherever it appears, the
value of any ``token=`` parameter, an ``Authorization: Bearer`` value and a ``graytrack.bearer.``
subprotocol (a wrong token is someone's secret too). Every level, every logger.

**Floods.** A client on the network can make uvicorn write a line per request it sends (garbage
that is not HTTP, handshakes from a foreign origin, at ``debug`` every refused request): 4,000 such
requests wrote 6,000 lines in 2.7 s, and journald's rate limit then drops whatever comes next, the
daemon's own faults included. :class:`FloodGate` sits on uvicorn's per-request loggers: in each
window of :data:`WINDOW_S` the first :data:`VERBATIM_LINES` lines are written as they come, the rest
are counted by source address and reason and summarised when the window closes ("N requests refused
in the last 10 s from ADDRESS: reason"), at most :data:`SUMMARY_LINES` sources by name. Errors
(uvicorn's tracebacks) and every line of the daemon's own loggers pass untouched: a fault is always
written.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading
import time
from collections import Counter
from http import HTTPStatus
from typing import Any, Callable

REDACTED = "[redacted]"
# the value of a token= parameter (query strings), a bearer header's value, the subprotocol that carries one
SECRET_PATTERNS = (re.compile(r"(?i)(\btoken=)[^&\s\"'#;,]+"),
                   re.compile(r"(?i)(\bauthorization:\s*bearer\s+)[^\s\"',;]+"),
                   re.compile(r"(?i)(\bgraytrack\.bearer\.)[^\s\"',;]+"))
WINDOW_S = 10.0  # a flood is summarised per window this long: a line per source and reason every 10 s at most
VERBATIM_LINES = 3  # per-request lines written as they come in each window (a lone request is seen whole)
SUMMARY_LINES = 5  # sources summarised by name per window; the rest in one line (addresses may be spoofed: many)
REQUEST_LOGGERS = ("uvicorn.access", "uvicorn.error")
# uvicorn's per-request lines that carry no client address (a parser error is logged before any scope exists)
UNADDRESSED = frozenset({"Invalid HTTP request received.", "Unsupported upgrade request.",
                         "Exceeded concurrency limit."})
UNKNOWN_ADDRESS = "an unknown address"
# what the WebSocket protocol (websockets, on uvicorn's logger) writes per connection, without its address:
# the template and whether it is a refusal
CONNECTION_LINES = {"connection rejected (%d %s)": True, "HTTP response sent (%d %s)": False, "connection open": False,
                    "connection closed": False}


class Redact(logging.Filter):
    """Secrets out of every record a handler writes (module docstring); the set of secrets is shared by the
    daemons of one process (tests run several): each adds its token while it runs."""

    def __init__(self) -> None:
        super().__init__("graytrack.redact")
        self.secrets: set[str] = set()

    def text(self, text: str) -> str:
        for secret in tuple(self.secrets):  # a copy: a daemon of this process may add or drop its own meanwhile
            if secret in text:
                text = text.replace(secret, REDACTED)
        for pattern in SECRET_PATTERNS:
            text = pattern.sub(rf"\g<1>{REDACTED}", text)
        return text

    def _value(self, value: Any) -> Any:
        return self.text(value) if isinstance(value, str) else value

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = self.text(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(self._value(arg) for arg in record.args)
        elif isinstance(record.args, dict):
            record.args = {key: self._value(value) for key, value in record.args.items()}
        if record.exc_info and not record.exc_text:  # formatters reuse exc_text once it is set
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = self.text(record.exc_text)
        if record.stack_info:
            record.stack_info = self.text(record.stack_info)
        return True


def _address(value: Any) -> str:
    """The host of uvicorn's ``host:port`` client (the port changes with every connection)."""
    text = str(value)
    host = text.rsplit(":", 1)[0] if ":" in text else text
    return host or UNKNOWN_ADDRESS


def classify(record: logging.LogRecord) -> tuple[str, bool, str] | None:
    """``(address, refused, reason)`` of one of uvicorn's per-request lines, None for any other line."""
    args = record.args if isinstance(record.args, tuple) else ()
    template = str(record.msg)
    if record.name == "uvicorn.access" and len(args) == 5:  # client, method, target, HTTP version, status
        status = int(args[4]) if str(args[4]).isdigit() else 0
        try:
            phrase = HTTPStatus(status).phrase
        except ValueError:
            phrase = "status"
        return _address(args[0]), status >= 400, f"{status} {phrase}"
    if record.name == "uvicorn.access":
        return UNKNOWN_ADDRESS, False, "a request"
    if template.startswith("%s - ") and "WebSocket" in template and args:
        if "[accepted]" in template:
            return _address(args[0]), False, "WebSocket accepted"
        status = args[2] if len(args) > 2 else 403
        return _address(args[0]), True, f"WebSocket handshake refused ({status})"
    if template in UNADDRESSED:
        return UNKNOWN_ADDRESS, True, template.rstrip(".")
    if template in CONNECTION_LINES:
        return UNKNOWN_ADDRESS, CONNECTION_LINES[template], f"WebSocket {record.getMessage()}"
    return None


class FloodGate(logging.Filter):
    """uvicorn's per-request lines, rate-limited and summarised per window (module docstring). ``monotonic``
    is the clock the windows run on; ``summary`` the logger the summaries are written to."""

    def __init__(self, monotonic: Callable[[], float] = time.monotonic,
                 summary: logging.Logger | None = None) -> None:
        super().__init__("graytrack.floodgate")
        self.monotonic = monotonic
        self.summary = summary or logging.getLogger("graytrack.daemon.requests")
        self._lock = threading.Lock()
        self._window_end: float | None = None
        self._written = 0
        self._counts: Counter[tuple[str, bool, str]] = Counter()
        self._held: Counter[tuple[str, bool, str]] = Counter()  # of _counts, those not written

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            return True
        key = classify(record)
        if key is None:
            return True
        self.flush()
        with self._lock:
            if self._window_end is None:
                self._window_end = self.monotonic() + WINDOW_S
            self._counts[key] += 1
            if self._written < VERBATIM_LINES:
                self._written += 1
                return True
            self._held[key] += 1
            return False

    def flush(self, force: bool = False) -> list[str]:
        """Close the window once it has ended (or now, ``force``): write its summaries, and return them."""
        with self._lock:
            if self._window_end is None or (not force and self.monotonic() < self._window_end):
                return []
            counts, held = self._counts, self._held
            self._window_end, self._written = None, 0
            self._counts, self._held = Counter(), Counter()
        lines = summaries(counts, held)
        for refused, line in lines:
            self.summary.log(logging.WARNING if refused else logging.INFO, "%s", line)
        return [line for _, line in lines]


def summaries(counts: Counter[tuple[str, bool, str]], held: Counter[tuple[str, bool, str]]) -> list[tuple[bool, str]]:
    """One line per source and reason with requests not written one by one (the largest first, at most
    :data:`SUMMARY_LINES`), then one for the rest: ``(refused, line)``."""
    if not held:
        return []
    ranked = sorted(held, key=lambda key: (-counts[key], key))
    lines = []
    for address, refused, reason in ranked[:SUMMARY_LINES]:
        verb = "refused" if refused else "served"
        lines.append((refused, f"{counts[address, refused, reason]} requests {verb} in the last {WINDOW_S:g} s "
                               f"from {address}: {reason}"))
    rest = ranked[SUMMARY_LINES:]
    if rest:
        sources = {address for address, _, _ in rest}
        lines.append((any(refused for _, refused, _ in rest),
                      f"{sum(counts[key] for key in rest)} more requests in the last {WINDOW_S:g} s from "
                      f"{len(sources)} other source(s) and reason(s), not written one by one"))
    return lines


FLUSH_EVERY_S = 1.0  # how often a running daemon closes an ended window (the summary of a flood that stopped)
REDACT = Redact()  # one per process: every handler gets this one, whichever daemon attached it


class LogGuard:
    """:class:`Redact` on every handler and :class:`FloodGate` on uvicorn's request loggers while a daemon runs
    (its app's lifespan: uvicorn has configured its loggers by then); :meth:`close` takes them off again."""

    def __init__(self, token: str, monotonic: Callable[[], float] = time.monotonic) -> None:
        self.token = token
        self.gate = FloodGate(monotonic)

    def install(self) -> None:
        REDACT.secrets.add(self.token)
        for handler in _handlers():
            if REDACT not in handler.filters:
                handler.addFilter(REDACT)
        for name in REQUEST_LOGGERS:
            logging.getLogger(name).addFilter(self.gate)

    async def flush_every(self) -> None:
        """Close each ended window while the daemon runs (a flood that stopped still gets its summary)."""
        while True:
            await asyncio.sleep(FLUSH_EVERY_S)
            self.gate.flush()

    def close(self) -> None:
        self.gate.flush(force=True)
        for name in REQUEST_LOGGERS:
            logging.getLogger(name).removeFilter(self.gate)
        REDACT.secrets.discard(self.token)  # the filter stays on the handlers: it still takes token= values out


def _handlers() -> list[logging.Handler]:
    loggers = [logging.getLogger(), *(logger for logger in logging.root.manager.loggerDict.values()
                                      if isinstance(logger, logging.Logger))]
    return [handler for logger in loggers for handler in logger.handlers]
