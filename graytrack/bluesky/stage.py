"""The daemon's stage as an ophyd-async movable, so a plan can scan it with the encoder as detector.

``set(x)`` is the client's ``move(x, wait=True)``: done when the grating rests within
``tolerance_mm`` of the target. ``readback`` is the grating (the stage's own scale) as the daemon
last reported it, ``setpoint`` the target the daemon accepted. Mocked, ``set`` only copies the
value to both, as a simulated motor would.
"""

from __future__ import annotations

import math
import os

from bluesky.protocols import Movable, Stoppable
from ophyd_async.core import AsyncStatus, StandardReadable, soft_signal_r_and_setter
from ophyd_async.core import StandardReadableFormat as Format

from graytrack.bluesky.connector import DaemonConnector
from graytrack.client import AsyncClient
from graytrack.client.plans import SETTLE_TIMEOUT_S, SETTLE_TOLERANCE_MM


class GraytrackStage(StandardReadable, Movable[float], Stoppable):
    """``GraytrackStage("http://host:8000", name="stage", data_dir=...)``; moves need the token."""

    def __init__(self, url: str, name: str = "", token: str | None = None,
                 data_dir: str | os.PathLike[str] | None = None, tolerance_mm: float = SETTLE_TOLERANCE_MM,
                 settle_timeout_s: float = SETTLE_TIMEOUT_S) -> None:
        self.tolerance_mm = tolerance_mm
        self.settle_timeout_s = settle_timeout_s
        self._client: AsyncClient | None = None
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.readback, self._set_readback = soft_signal_r_and_setter(float, math.nan, units="mm", precision=6)
        with self.add_children_as_readables():
            self.setpoint, self._set_setpoint = soft_signal_r_and_setter(float, math.nan, units="mm", precision=6)
        super().__init__(name=name, connector=DaemonConnector(url, token, data_dir))

    async def attach(self, client: AsyncClient, timeout: float) -> None:
        """Check the daemon answers and take its grating reading and last target."""
        self._client = client
        status = await client.status()
        self._set_setpoint(math.nan if status.target_mm is None else status.target_mm)
        await self._refresh()

    async def detach(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            await client.aclose()

    async def close(self) -> None:
        """Let go of the daemon; ``connect()`` again to resume."""
        await self.detach()

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Move to ``value`` mm and wait until the stage rests there."""
        if self._client is None:  # mocked: a motor that arrives at once
            self._set_setpoint(value)
            self._set_readback(value)
            return
        moved = await self._client.move(value, wait=True, tolerance_mm=self.tolerance_mm,
                                        timeout_s=self.settle_timeout_s)
        self._set_setpoint(moved.target_mm)
        await self._refresh()

    async def stop(self, success: bool = True) -> None:
        """Stop the stage where it is (a plan's abort calls this)."""
        if self._client is not None:
            await self._client.stop()
            await self._refresh()

    async def _refresh(self) -> None:
        assert self._client is not None
        status = await self._client.status()
        self._set_readback(math.nan if status.grating_mm is None else status.grating_mm)
