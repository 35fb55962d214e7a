"""One serial link to a PI GCS controller: transactions, resynchronisation, reconnection.

A transaction is "write one command line, read one complete reply" under a lock, so concurrent
callers (the acquisition loop reading ``POS?``, an operator's ``MOV``) never interleave bytes.

Why resynchronisation: GCS has no sequence numbers, so a reply that arrives late (after the
caller gave up) or a line broken by noise would otherwise be read as the answer to the *next*
command. After any anomaly the link is marked dirty, and before it is used again the driver
discards its input, asks ``*IDN?`` and throws away everything up to the identification line it
learnt at connect time. Only then is the link clean again.

Why reconnection: USB serial adapters vanish and return (a replug, a hub reset). A broken port is
closed at once and reopened by the next transaction, so the caller keeps calling and gets
:class:`StageConnectionError` only while the port is really gone.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, NoReturn, TypeVar

import serial

from graytrack.drivers.stage import gcs_protocol as gcs
from graytrack.drivers.stage.errors import (
    GCSControllerError,
    StageConnectionError,
    StageProtocolError,
    StageTimeoutError,
)

T = TypeVar("T")

READ_SLICE_S = 0.01  # pyserial read timeout; bounds how late a deadline is noticed
QUIET_S = 0.03  # silence that ends the drain before the first identification


@dataclass(frozen=True)
class Reply:
    """A complete reply and the host times (``clock()``) bracketing its transaction."""

    lines: list[str]
    t_sent: float
    t_received: float

    @property
    def t_mid(self) -> float:
        """Best host estimate of when the controller sampled its answer."""
        return 0.5 * (self.t_sent + self.t_received)


@dataclass
class LinkStats:
    transactions: int = 0
    timeouts: int = 0
    malformed: int = 0
    resyncs: int = 0
    reconnects: int = 0
    disconnects: int = 0


@dataclass
class _State:
    port: serial.Serial | None = None
    dirty: bool = True
    framer: gcs.ReplyFramer = field(default_factory=gcs.ReplyFramer)
    replies: deque[list[str]] = field(default_factory=deque)


class GCSConnection:
    """Thread-safe GCS transactions over a serial port that may come and go."""

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        timeout_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.port_name = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.clock = clock
        self.identity: str | None = None
        self.stats = LinkStats()
        self._lock = threading.RLock()
        self._state = _State()
        self._ever_opened = False

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> str:
        """Open the port and identify the controller; returns its ``*IDN?`` line."""
        with self._lock:
            self._ensure_open()
            assert self.identity is not None
            return self.identity

    def close(self) -> None:
        with self._lock:
            self._drop_port()

    def locked(self) -> threading.RLock:
        """The transaction lock, for callers that need several commands to be atomic."""
        return self._lock

    # -- transactions ----------------------------------------------------------------------
    def query(
        self,
        name: str,
        *args: object,
        parse: Callable[[list[str]], T] = lambda lines: lines,  # type: ignore[assignment,return-value]
        idempotent: bool = True,
    ) -> tuple[T, Reply]:
        """Send a query, parse its reply. Malformed replies of idempotent queries are retried once.

        On a timeout the controller's error register is read: an invalid query makes a GCS
        controller stay silent and set an error number, which is more useful than "no reply".
        """
        line = gcs.format_command(name, *args)
        command = line.decode().strip()
        with self._lock:
            attempts = 2 if idempotent else 1
            for attempt in range(attempts):
                try:
                    reply = self._transact(line, command)
                    return parse(reply.lines), reply
                except (StageProtocolError, ValueError, IndexError) as exc:
                    self.stats.malformed += 1
                    self._state.dirty = True
                    if attempt + 1 == attempts:
                        raise StageProtocolError(f"malformed reply to {command!r}: {exc}") from None
            raise AssertionError("unreachable")

    def command(self, name: str, *args: object, tolerate: tuple[int, ...] = ()) -> None:
        """Send a set command and check ``ERR?``; raise :class:`GCSControllerError` on nonzero."""
        line = gcs.format_command(name, *args)
        command = line.decode().strip()
        with self._lock:
            self._ensure_ready()
            self._write(line)
            code = self.error_code()
            if code != 0 and code not in tolerate:
                raise GCSControllerError(code, command)

    def error_code(self) -> int:
        """Read and clear the controller's error register (``ERR?``)."""
        code, _ = self.query("ERR?", parse=lambda lines: gcs.parse_error_code(gcs.single_line(lines)), idempotent=False)
        return code

    # -- internals -------------------------------------------------------------------------
    def _transact(self, line: bytes, command: str) -> Reply:
        self._ensure_ready()
        t_sent = self.clock()
        self._write(line)
        self.stats.transactions += 1
        try:
            lines = self._read_reply(t_sent + self.timeout_s)
        except StageTimeoutError:
            self.stats.timeouts += 1
            self._state.dirty = True
            self._explain_silence(command)
            raise StageTimeoutError(
                f"no reply to {command!r} from {self.port_name} within {self.timeout_s:g} s"
            ) from None
        t_received = self.clock()
        if self._state.replies:
            # Two replies for one command: one of them is stale, and which one cannot be known.
            self._state.dirty = True
            raise StageProtocolError(f"more than one reply to {command!r}")
        return Reply(lines, t_sent, t_received)

    def _explain_silence(self, command: str) -> None:
        """After a timeout, raise the controller's error if it refused the query."""
        if command == "ERR?":
            return
        try:
            self._resync()
            self._write(b"ERR?\n")
            code = gcs.parse_error_code(gcs.single_line(self._read_reply(self.clock() + self.timeout_s)))
        except (StageTimeoutError, StageProtocolError, ValueError):
            self._state.dirty = True
            return
        if code != 0:
            raise GCSControllerError(code, command)

    def _ensure_ready(self) -> None:
        self._ensure_open()
        port = self._state.port
        assert port is not None
        try:
            unsolicited = port.in_waiting > 0
        except (OSError, serial.SerialException) as exc:
            self._lost(exc)
        if self._state.dirty or unsolicited or self._state.replies or self._state.framer.pending():
            self._resync()

    def _ensure_open(self) -> None:
        if self._state.port is not None:
            return
        try:
            port = serial.Serial(self.port_name, self.baudrate, timeout=READ_SLICE_S, write_timeout=self.timeout_s)
        except (OSError, serial.SerialException) as exc:
            raise StageConnectionError(f"cannot open {self.port_name}: {exc}") from None
        self._state = _State(port=port)
        if self._ever_opened:
            self.stats.reconnects += 1
        self._ever_opened = True
        try:
            self._identify()
        except Exception:
            self._drop_port()
            raise

    def _identify(self) -> None:
        """First contact on a fresh port: drain leftovers, learn the identification line."""
        self._drain_until_quiet()
        self._write(b"*IDN?\n")
        lines = self._read_reply(self.clock() + self.timeout_s)
        identity = gcs.single_line(lines).strip()
        if not identity or not identity.isprintable():
            raise StageProtocolError(f"{self.port_name}: unreadable identification {identity!r}")
        self.identity = identity
        self._state.dirty = False

    def _resync(self) -> None:
        """Discard everything up to a fresh identification reply (see module docstring)."""
        if self.identity is None:
            self._identify()
            return
        self.stats.resyncs += 1
        port = self._state.port
        assert port is not None
        self._state.framer.clear()
        self._state.replies.clear()
        try:
            port.reset_input_buffer()
        except (OSError, serial.SerialException) as exc:
            self._lost(exc)
        self._write(b"*IDN?\n")
        deadline = self.clock() + self.timeout_s
        while True:
            try:
                lines = self._read_reply(deadline)
            except StageTimeoutError:
                raise StageTimeoutError(f"{self.port_name}: no identification while resynchronising") from None
            if lines and lines[-1].strip().endswith(self.identity):
                self._state.dirty = False
                return

    def _drain_until_quiet(self) -> None:
        port = self._state.port
        assert port is not None
        deadline = self.clock() + self.timeout_s
        quiet_since = self.clock()
        while self.clock() < deadline and self.clock() - quiet_since < QUIET_S:
            if self._read_chunk(port):
                quiet_since = self.clock()
        self._state.framer.clear()
        self._state.replies.clear()

    def _read_reply(self, deadline: float) -> list[str]:
        port = self._state.port
        assert port is not None
        state = self._state
        while not state.replies:
            if self.clock() > deadline:
                raise StageTimeoutError("deadline passed")
            data = self._read_chunk(port)
            if data:
                state.replies.extend(state.framer.feed(data))
        return state.replies.popleft()

    def _read_chunk(self, port: serial.Serial) -> bytes:
        try:
            return port.read(max(1, port.in_waiting))
        except (OSError, serial.SerialException, TypeError) as exc:
            self._lost(exc)

    def _write(self, data: bytes) -> None:
        port = self._state.port
        if port is None:
            raise StageConnectionError(f"{self.port_name} is not open")
        try:
            port.write(data)
        except (OSError, serial.SerialException) as exc:
            self._lost(exc)

    def _lost(self, exc: BaseException) -> NoReturn:
        self.stats.disconnects += 1
        self._drop_port()
        raise StageConnectionError(f"lost {self.port_name}: {exc}") from None

    def _drop_port(self) -> None:
        port = self._state.port
        self._state = _State()
        if port is not None:
            try:
                port.close()
            except (OSError, serial.SerialException):
                pass

