"""What every device of the rig shares: open/close and use as a context manager.

Cameras and stages differ in everything else; keeping this one contract in one place means a
daemon can hold either the same way and release it on any exit path.
"""

from __future__ import annotations

import abc
from types import TracebackType
from typing import TypeVar

DeviceT = TypeVar("DeviceT", bound="Device")


class Device(abc.ABC):
    @abc.abstractmethod
    def open(self) -> None:
        """Connect and configure; raises the device's own error type on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the hardware; safe to call twice."""

    def __enter__(self: DeviceT) -> DeviceT:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
