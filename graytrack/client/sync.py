"""The blocking client: one ``httpx.Client`` for the routes, ``websockets.sync`` for the stream.

What each method sends and how its answer is read is in :mod:`routes`; the operations of several
requests are the plans of :mod:`plans`; this module only moves bytes.
"""

from __future__ import annotations

import os
import socket
import time
from datetime import datetime
from types import TracebackType
from typing import Any, Iterator, TypeVar

import httpx
from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect

from graytrack.client import plans, routes
from graytrack.client.plans import CALIBRATION_TIMEOUT_S, POLL_S, SETTLE_TIMEOUT_S, SETTLE_TOLERANCE_MM, Progress
from graytrack.client.routes import DEFAULT_TIMEOUT_S, Call
from graytrack.client.stream import MAX_MESSAGE, Link, Position, ws_url
from graytrack.client.token import resolve_token
from graytrack.wire import (Activated, Calibration, CalibrationPage, CalibrationRow, Event, Health, Homed, Moved,
                            Status, Stopped, Velocity)

T = TypeVar("T")


class Client:
    """The daemon at ``url`` (``http://host:port``). Mutating routes need its token: ``token=`` or
    ``data_dir=`` (the daemon's data directory; its ``token`` file is read once, here).

    Environment proxies are ignored: the daemon is on the lab's own network (or loopback)."""

    def __init__(self, url: str, token: str | None = None, data_dir: str | os.PathLike[str] | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.url = url.rstrip("/")
        self.token = resolve_token(token, data_dir)
        self._http = httpx.Client(base_url=self.url, timeout=timeout, trust_env=False)

    # -- transport -------------------------------------------------------------------------
    def call(self, call: Call[T]) -> T:
        """Send one :class:`Call` and read its answer (what every method below does)."""
        headers = routes.headers(call, self.token)
        try:
            response = self._http.request(call.method, call.path, params=call.params, json=call.body, headers=headers)
        except httpx.TransportError as exc:
            raise routes.unreachable(call, self.url, exc) from None
        return routes.read(call, response.status_code, response.content, self.token is not None)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading ---------------------------------------------------------------------------
    def status(self) -> Status:
        return self.call(routes.status())

    def health(self) -> Health:
        """``ok`` while frames are tracked now with a model that holds; otherwise ``reason`` (no exception)."""
        return self.call(routes.health())

    def calibration(self, calibration_id: str = "latest") -> Calibration:
        return self.call(routes.calibration(calibration_id))

    def calibrations(self, limit: int = 20, offset: int = 0) -> CalibrationPage:
        return self.call(routes.calibrations(limit, offset))

    def calibration_row(self, calibration_id: str) -> CalibrationRow:
        return self.call(routes.calibration_row(calibration_id))

    def calibration_file(self, calibration_id: str, name: str) -> bytes:
        return self.call(routes.calibration_file(calibration_id, name))

    def events(self, since: int | str | datetime = 0, limit: int = 200) -> list[Event]:
        return self.call(routes.events(since, limit))

    def profile(self, row: int | None = None) -> dict[str, Any]:
        return self.call(routes.profile(row))

    def maps(self, row: int | None = None) -> dict[str, Any]:
        return self.call(routes.maps(row))

    def metrics(self) -> str:
        return self.call(routes.metrics())

    # -- acting (token) --------------------------------------------------------------------
    def calibrate(self, wait: bool = True, progress: Progress | None = None,
                  timeout_s: float = CALIBRATION_TIMEOUT_S, poll_s: float = POLL_S) -> Calibration:
        """Start a calibration; with ``wait``, follow it until ``done`` (raises :class:`CalibrationFailed`)."""
        if not wait:
            return self.call(routes.start_calibration())
        return plans.run(plans.calibrate(progress, timeout_s, poll_s), self.call)

    def ensure_calibrated(self, progress: Progress | None = None, timeout_s: float = CALIBRATION_TIMEOUT_S,
                          poll_s: float = POLL_S) -> Status:
        """Until the daemon has a model: follows the calibration it runs (``make run``'s first start), or
        starts one when it has none; the status once calibrated (``plans.calibrated``)."""
        return plans.run(plans.calibrated(progress, timeout_s, poll_s), self.call)

    def move(self, x_mm: float, wait: bool = False, tolerance_mm: float = SETTLE_TOLERANCE_MM,
             timeout_s: float = SETTLE_TIMEOUT_S, poll_s: float = POLL_S) -> Moved:
        """Move to ``x_mm``; with ``wait``, return once the grating rests within ``tolerance_mm`` of it."""
        return plans.run(plans.move(routes.move(x_mm), wait, tolerance_mm, timeout_s, poll_s), self.call)

    def jog(self, step_mm: float, wait: bool = False, tolerance_mm: float = SETTLE_TOLERANCE_MM,
            timeout_s: float = SETTLE_TIMEOUT_S, poll_s: float = POLL_S) -> Moved:
        return plans.run(plans.move(routes.jog(step_mm), wait, tolerance_mm, timeout_s, poll_s), self.call)

    def stop(self) -> Stopped:
        """Stop the stage now (also aborts a running calibration)."""
        return self.call(routes.stop())

    def home(self) -> Homed:
        return self.call(routes.home())

    def set_velocity(self, velocity_mm_s: float) -> Velocity:
        return self.call(routes.set_velocity(velocity_mm_s))

    def activate(self, calibration_id: str) -> Activated:
        return self.call(routes.activate(calibration_id))

    def reset_trim(self) -> dict[str, Any]:
        return self.call(routes.reset_trim())

    # -- the stream ------------------------------------------------------------------------
    def stream(self, max_rate: float | None = None, silence_s: float | None = None) -> "PositionStream":
        """Position messages as they come, reconnecting after a lost connection (see :class:`Position`'s
        ``gap``). With ``silence_s``, raise :class:`StreamSilent` when no message came for that long."""
        return PositionStream(Link(ws_url(self.url, max_rate), self.token, silence_s))


class PositionStream(Iterator[Position]):
    """An iterator over :class:`Position`; a context manager that closes its connection."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._ws: ClientConnection | None = None

    def __iter__(self) -> "PositionStream":
        return self

    def __next__(self) -> Position:
        while True:
            ws = self._ws or self._open()
            try:
                text = ws.recv(timeout=self.link.receive_timeout())
            except TimeoutError:
                raise self.link.silent() from None
            except ConnectionClosed as exc:
                self._discard()
                time.sleep(self.link.failed(exc))
                continue
            return self.link.received(text)

    def _open(self) -> ClientConnection:
        while True:
            try:
                ws = connect(self.link.url, additional_headers=self.link.headers, open_timeout=self.link.open_timeout(),
                             compression=None, proxy=None, max_size=MAX_MESSAGE)
            except (OSError, InvalidHandshake, TimeoutError) as exc:
                time.sleep(self.link.failed(exc))
                continue
            # held open across calls and closed by close(): entering says so (websockets >= 17.1 warns otherwise)
            self._ws = ws.__enter__()
            self.link.connected()
            return self._ws

    def _discard(self) -> None:
        ws, self._ws = self._ws, None
        if ws is not None:
            ws.close()

    def drop_connection(self) -> None:
        """Cut the connection as a network fault would (no closing handshake): to test how a controller
        lives through one. The next message comes over a new connection, its ``gap`` says what was missed."""
        if self._ws is not None:
            self._ws.socket.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        self._discard()

    def __enter__(self) -> "PositionStream":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
