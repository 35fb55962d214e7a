"""The asyncio client: the same methods as :class:`graytrack.client.Client`, as coroutines, and ``async for``
over the stream. Requests and answers come from :mod:`routes`, operations from :mod:`plans`, the
stream's bookkeeping from :mod:`stream`: only the awaiting is this module's own.
"""

from __future__ import annotations

import asyncio
import os
from datetime import datetime
from types import TracebackType
from typing import Any, AsyncIterator, TypeVar

import httpx
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from graytrack.client import plans, routes
from graytrack.client.plans import CALIBRATION_TIMEOUT_S, POLL_S, SETTLE_TIMEOUT_S, SETTLE_TOLERANCE_MM, Progress
from graytrack.client.routes import DEFAULT_TIMEOUT_S, Call
from graytrack.client.stream import MAX_MESSAGE, Link, Position, ws_url
from graytrack.client.token import resolve_token
from graytrack.wire import (Activated, Calibration, CalibrationPage, CalibrationRow, Event, Health, Homed, Moved,
                            Status, Stopped, Velocity)

T = TypeVar("T")


class AsyncClient:
    """As :class:`graytrack.client.Client`; use ``async with`` or ``await aclose()``."""

    def __init__(self, url: str, token: str | None = None, data_dir: str | os.PathLike[str] | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.url = url.rstrip("/")
        self.token = resolve_token(token, data_dir)
        self._http = httpx.AsyncClient(base_url=self.url, timeout=timeout, trust_env=False)

    async def call(self, call: Call[T]) -> T:
        headers = routes.headers(call, self.token)
        try:
            response = await self._http.request(call.method, call.path, params=call.params, json=call.body,
                                                headers=headers)
        except httpx.TransportError as exc:
            raise routes.unreachable(call, self.url, exc) from None
        return routes.read(call, response.status_code, response.content, self.token is not None)

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def status(self) -> Status:
        return await self.call(routes.status())

    async def health(self) -> Health:
        return await self.call(routes.health())

    async def calibration(self, calibration_id: str = "latest") -> Calibration:
        return await self.call(routes.calibration(calibration_id))

    async def calibrations(self, limit: int = 20, offset: int = 0) -> CalibrationPage:
        return await self.call(routes.calibrations(limit, offset))

    async def calibration_row(self, calibration_id: str) -> CalibrationRow:
        return await self.call(routes.calibration_row(calibration_id))

    async def calibration_file(self, calibration_id: str, name: str) -> bytes:
        return await self.call(routes.calibration_file(calibration_id, name))

    async def events(self, since: int | str | datetime = 0, limit: int = 200) -> list[Event]:
        return await self.call(routes.events(since, limit))

    async def profile(self, row: int | None = None) -> dict[str, Any]:
        return await self.call(routes.profile(row))

    async def maps(self, row: int | None = None) -> dict[str, Any]:
        return await self.call(routes.maps(row))

    async def metrics(self) -> str:
        return await self.call(routes.metrics())

    async def calibrate(self, wait: bool = True, progress: Progress | None = None,
                        timeout_s: float = CALIBRATION_TIMEOUT_S, poll_s: float = POLL_S) -> Calibration:
        if not wait:
            return await self.call(routes.start_calibration())
        return await plans.run_async(plans.calibrate(progress, timeout_s, poll_s), self.call)

    async def ensure_calibrated(self, progress: Progress | None = None, timeout_s: float = CALIBRATION_TIMEOUT_S,
                                poll_s: float = POLL_S) -> Status:
        return await plans.run_async(plans.calibrated(progress, timeout_s, poll_s), self.call)

    async def move(self, x_mm: float, wait: bool = False, tolerance_mm: float = SETTLE_TOLERANCE_MM,
                   timeout_s: float = SETTLE_TIMEOUT_S, poll_s: float = POLL_S) -> Moved:
        return await plans.run_async(plans.move(routes.move(x_mm), wait, tolerance_mm, timeout_s, poll_s), self.call)

    async def jog(self, step_mm: float, wait: bool = False, tolerance_mm: float = SETTLE_TOLERANCE_MM,
                  timeout_s: float = SETTLE_TIMEOUT_S, poll_s: float = POLL_S) -> Moved:
        return await plans.run_async(plans.move(routes.jog(step_mm), wait, tolerance_mm, timeout_s, poll_s), self.call)

    async def stop(self) -> Stopped:
        return await self.call(routes.stop())

    async def home(self) -> Homed:
        return await self.call(routes.home())

    async def set_velocity(self, velocity_mm_s: float) -> Velocity:
        return await self.call(routes.set_velocity(velocity_mm_s))

    async def activate(self, calibration_id: str) -> Activated:
        return await self.call(routes.activate(calibration_id))

    async def reset_trim(self) -> dict[str, Any]:
        return await self.call(routes.reset_trim())

    def stream(self, max_rate: float | None = None, silence_s: float | None = None) -> "AsyncPositionStream":
        """``async for position in client.stream():`` (see :meth:`graytrack.client.Client.stream`)."""
        return AsyncPositionStream(Link(ws_url(self.url, max_rate), self.token, silence_s))


class AsyncPositionStream(AsyncIterator[Position]):
    def __init__(self, link: Link) -> None:
        self.link = link
        self._ws: ClientConnection | None = None

    def __aiter__(self) -> "AsyncPositionStream":
        return self

    async def __anext__(self) -> Position:
        while True:
            ws = self._ws or await self._open()
            try:
                text = await asyncio.wait_for(ws.recv(), self.link.receive_timeout())
            except TimeoutError:
                raise self.link.silent() from None
            except ConnectionClosed as exc:
                await self._discard()
                await asyncio.sleep(self.link.failed(exc))
                continue
            return self.link.received(text)

    async def _open(self) -> ClientConnection:
        while True:
            try:
                self._ws = await connect(self.link.url, additional_headers=self.link.headers,
                                         open_timeout=self.link.open_timeout(), compression=None, proxy=None,
                                         max_size=MAX_MESSAGE)
            except (OSError, InvalidHandshake, TimeoutError) as exc:
                await asyncio.sleep(self.link.failed(exc))
                continue
            self.link.connected()
            return self._ws

    async def _discard(self) -> None:
        ws, self._ws = self._ws, None
        if ws is not None:
            await ws.close()

    def drop_connection(self) -> None:
        """As :meth:`graytrack.client.sync.PositionStream.drop_connection`."""
        if self._ws is not None:
            self._ws.transport.abort()

    async def aclose(self) -> None:
        await self._discard()

    async def __aenter__(self) -> "AsyncPositionStream":
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.aclose()
