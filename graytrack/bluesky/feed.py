"""The daemon's position stream read in the background on bluesky's event loop.

Every message goes to ``publish`` (the encoder's signal setters) and then wakes whoever waits for
a fresh frame: ``frames`` counts the messages, so a trigger can wait for one that arrived after it
was asked, and a read can tell whether a message landed while it was gathering its signals.
"""

from __future__ import annotations

import asyncio
from typing import Callable

from graytrack.client import AsyncClient, AsyncPositionStream, GraytrackClientError, Position


class Feed:
    """One stream of one client; :meth:`close` stops the task and closes the socket (not the client)."""

    def __init__(self, client: AsyncClient, publish: Callable[[Position], None], max_rate: float | None) -> None:
        self.publish = publish
        self.frames = 0
        self.last: Position | None = None
        self._stream: AsyncPositionStream = client.stream(max_rate=max_rate)
        self._arrived = asyncio.Event()
        self._error: BaseException | None = None
        self._task = asyncio.get_running_loop().create_task(self._run(), name=f"graytrack feed {client.url}")

    async def _run(self) -> None:
        try:
            async for position in self._stream:
                self.last = position
                self.publish(position)  # all signals of one frame before anyone is woken
                self.frames += 1
                self._arrived.set()
                self._arrived = asyncio.Event()
        except GraytrackClientError as exc:  # refused (token, policy): retrying cannot help
            self._error = exc
            self._arrived.set()

    async def fresh(self, after: int, timeout_s: float) -> Position:
        """The first message counted after ``after`` frames, waiting at most ``timeout_s``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while self.frames <= after:
            if self._error is not None:
                raise self._error
            remaining = deadline - loop.time()
            if remaining <= 0:
                seen = "no message yet" if self.last is None else f"last seq {self.last.seq}"
                raise TimeoutError(f"no new position from the daemon within {timeout_s:g} s ({seen}); "
                                   "is it tracking?")
            try:
                await asyncio.wait_for(self._arrived.wait(), remaining)
            except TimeoutError:
                continue
        assert self.last is not None
        return self.last

    async def close(self) -> None:
        self._task.cancel()
        try:
            await self._task
        except asyncio.CancelledError:
            pass
        await self._stream.aclose()
