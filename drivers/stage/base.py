"""What the service needs from a closed-loop linear stage, independent of the controller.

The position read is the grating readout, and it is only useful together with *when* it was
taken: :class:`PositionReading` carries the host time on ``time.monotonic`` (the middle of the
request and the reply, the clock the cameras stamp mid-exposure with, whatever clock a simulated
controller runs on) so the acquisition loop can pair it with an exposure.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

from graytrack.drivers.device import Device


@dataclass(frozen=True)
class PositionReading:
    """Grating readout in mm at host ``time.monotonic`` ``t`` (midpoint of request and reply, seconds);
    ``latency_s`` is the round trip, so the reading was taken within ``t ± latency_s / 2``."""

    position_mm: float
    t: float
    latency_s: float


class Stage(Device):
    """A single closed-loop linear axis. Moves are absolute in mm unless named otherwise."""

    @abc.abstractmethod
    def open(self) -> None:
        """Connect and prepare the axis (servo on, referenced); safe to call twice."""

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def move_to(self, target_mm: float) -> None: ...

    @abc.abstractmethod
    def move_by(self, delta_mm: float) -> None: ...

    @abc.abstractmethod
    def position(self) -> PositionReading: ...

    @abc.abstractmethod
    def on_target(self) -> bool: ...

    @abc.abstractmethod
    def wait_on_target(self, timeout_s: float) -> PositionReading:
        """Block until the axis reports on target; return the settled position reading."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop now (abrupt); the axis stays where it stopped."""

    @abc.abstractmethod
    def set_velocity(self, velocity_mm_s: float) -> None:
        """The velocity of the following moves (a calibration pass sets its own, then restores this)."""

    @abc.abstractmethod
    def velocity(self) -> float: ...

    def velocity_limit(self) -> float | None:
        """The highest velocity the controller takes, mm/s (None: it does not say)."""
        return None

    @abc.abstractmethod
    def reference(self, timeout_s: float = 30.0) -> None:
        """Find the axis's reference mark and wait until it is found. This moves the stage (over
        its whole travel on some axes): the daemon does it only when asked (``POST /api/stage/reference``)."""

    @abc.abstractmethod
    def limits(self) -> tuple[float, float]:
        """The range moves are allowed in: soft limits intersected with the controller's travel."""

