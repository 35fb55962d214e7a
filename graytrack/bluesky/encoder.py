"""The daemon's tracked position as an ophyd-async detector.

Signals (soft, so ``connect(mock=True)`` and ``set_mock_value`` work as for any ophyd-async
device): ``position`` (mm, hinted), ``crlb`` (its Cramér–Rao bound, µm), ``locked``, ``stale``
(the validity monitor says the model no longer holds) and ``seq`` (the stream message the values
came from). A real connection keeps them current from the position stream; ``trigger()`` waits
for a message that arrives after it is called, so the read that follows is a new frame.
"""

from __future__ import annotations

import math
import os

from bluesky.protocols import Reading, Triggerable
from ophyd_async.core import AsyncStatus, StandardReadable, soft_signal_r_and_setter
from ophyd_async.core import StandardReadableFormat as Format

from graytrack.bluesky.connector import DaemonConnector
from graytrack.bluesky.feed import Feed
from graytrack.client import AsyncClient, Position

TRIGGER_TIMEOUT_S = 5.0
NOT_PLACED = math.nan  # a frame the tracker could not place, or no frame yet


class GraytrackEncoder(StandardReadable, Triggerable):
    """``GraytrackEncoder("http://host:8000", name="encoder", data_dir="/var/lib/graytrack")``.

    ``token`` or ``data_dir`` (whose ``token`` file the daemon wrote) authorise the stream;
    ``max_rate`` asks the daemon for at most that many messages/s; ``trigger_timeout_s`` bounds
    the wait for a fresh frame. Connecting for real needs the daemon tracking: it waits (up to the
    connect timeout) for the first message so the signals hold a frame from the start.
    """

    def __init__(self, url: str, name: str = "", token: str | None = None,
                 data_dir: str | os.PathLike[str] | None = None, max_rate: float | None = None,
                 trigger_timeout_s: float = TRIGGER_TIMEOUT_S) -> None:
        if not trigger_timeout_s > 0:
            raise ValueError(f"trigger_timeout_s must be a positive number of seconds, got {trigger_timeout_s}")
        self.max_rate = max_rate
        self.trigger_timeout_s = trigger_timeout_s
        self._feed: Feed | None = None
        self._client: AsyncClient | None = None
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.position, self._set_position = soft_signal_r_and_setter(float, NOT_PLACED, units="mm", precision=6)
        with self.add_children_as_readables():
            self.crlb, self._set_crlb = soft_signal_r_and_setter(float, NOT_PLACED, units="µm", precision=4)
            self.locked, self._set_locked = soft_signal_r_and_setter(bool, False)
            self.stale, self._set_stale = soft_signal_r_and_setter(bool, False)
            self.seq, self._set_seq = soft_signal_r_and_setter(int, -1)
        super().__init__(name=name, connector=DaemonConnector(url, token, data_dir))

    # -- connection (called by DaemonConnector) ------------------------------------------
    async def attach(self, client: AsyncClient, timeout: float) -> None:
        """Check the daemon answers, start the stream and wait for its first message."""
        self._client = client
        await client.status()
        self._feed = Feed(client, self._publish, self.max_rate)
        await self._feed.fresh(0, timeout)

    async def detach(self) -> None:
        """Stop the stream and close the client (also before a mock connection)."""
        feed, client, self._feed, self._client = self._feed, self._client, None, None
        if feed is not None:
            await feed.close()
        if client is not None:
            await client.aclose()

    async def close(self) -> None:
        """Let go of the daemon; ``connect()`` again to resume."""
        await self.detach()

    def _publish(self, p: Position) -> None:
        self._set_position(NOT_PLACED if p.x_mm is None else p.x_mm)
        self._set_crlb(NOT_PLACED if p.crlb_um is None else p.crlb_um)
        self._set_locked(p.locked)
        self._set_stale(p.stale)
        self._set_seq(p.seq)

    # -- bluesky verbs -------------------------------------------------------------------
    @AsyncStatus.wrap
    async def trigger(self) -> None:
        """Done when a stream message newer than the call has been published (at once when mocked)."""
        if self._feed is not None:
            await self._feed.fresh(self._feed.frames, self.trigger_timeout_s)

    async def read(self) -> dict[str, Reading]:
        """The signals, all from one frame: gathered again if a message lands while they are read."""
        while True:
            frames = self._feed.frames if self._feed is not None else 0
            reading = await super().read()
            if self._feed is None or self._feed.frames == frames:
                return reading
