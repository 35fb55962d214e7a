"""How a graytrack device connects: a real connection opens an :class:`~graytrack.client.AsyncClient` to
the daemon (and whatever the device runs over it); a mock connection opens nothing, so tests and
simulations drive the soft signals with ``set_mock_value``. Both devices share it, so the client is
made, checked and closed in one place and always on the event loop that connects (bluesky's).
"""

from __future__ import annotations

import os
from typing import Protocol

from ophyd_async.core import Device, DeviceConnector, DeviceMock, NotConnectedError

from graytrack.client import AsyncClient, GraytrackClientError


class DaemonDevice(Protocol):
    """What the connector asks of its device: start over a fresh client, and let go of it."""

    async def attach(self, client: AsyncClient, timeout: float) -> None: ...

    async def detach(self) -> None: ...


class DaemonConnector(DeviceConnector):
    """Connects a device's soft signals and, when real, a client of the daemon at ``url``."""

    def __init__(self, url: str, token: str | None = None, data_dir: str | os.PathLike[str] | None = None) -> None:
        self.url = url
        self.token = token
        self.data_dir = data_dir

    async def connect_mock(self, device: Device, mock: DeviceMock) -> None:
        await _daemon_device(device).detach()
        await super().connect_mock(device, mock)

    async def connect_real(self, device: Device, timeout: float, force_reconnect: bool) -> None:
        owner = _daemon_device(device)
        await owner.detach()
        await super().connect_real(device, timeout, force_reconnect)
        client = AsyncClient(self.url, token=self.token, data_dir=self.data_dir, timeout=timeout)
        try:
            await owner.attach(client, timeout)
        except (GraytrackClientError, TimeoutError) as exc:
            await client.aclose()
            raise NotConnectedError(f"graytrack daemon at {self.url}: {exc}") from exc
        except BaseException:
            await client.aclose()
            raise


def _daemon_device(device: Device) -> DaemonDevice:
    if not (hasattr(device, "attach") and hasattr(device, "detach")):
        raise TypeError(f"{device!r} is not a graytrack device (no attach/detach)")
    return device  # type: ignore[return-value]
