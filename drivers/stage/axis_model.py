"""The motion a simulated GCS controller drives: what it must provide, and a minimal model.

The simulated controller only needs a handful of calls from the axis it moves; naming them as a
protocol lets it drive either the small trapezoid model here (no dependency on the virtual rig)
or the virtual rig's stage, whose true position the simulated camera renders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol


class AxisModel(Protocol):
    """Motion of one linear axis in continuous time ``t`` (seconds, the controller's clock)."""

    travel_mm: tuple[float, float]

    def move_to(self, target_mm: float, t: float) -> None: ...

    def stop(self, t: float) -> None: ...

    def set_velocity(self, velocity_mm_s: float) -> None: ...

    def velocity_setting(self) -> float: ...

    def target(self) -> float: ...

    def readout(self, t: float) -> float:
        """What the grating scale reads at ``t`` (what ``POS?`` reports)."""
        ...

    def on_target(self, t: float) -> bool: ...


@dataclass
class TrapezoidAxis:
    """Point-to-point moves with a trapezoidal velocity profile; the readout is exact.

    A move started while another is under way starts from the current position at rest: good
    enough for a protocol test double, and the virtual rig's stage models the real dynamics.
    """

    travel_mm: tuple[float, float] = (0.0, 25.0)
    start_mm: float = 12.5
    velocity_mm_s: float = 10.0
    accel_mm_s2: float = 500.0
    _from: float = field(init=False)
    _to: float = field(init=False)
    _t0: float = field(init=False, default=0.0)
    _duration: float = field(init=False, default=0.0)
    _v: float = field(init=False)

    def __post_init__(self) -> None:
        self._from = self._to = self.start_mm
        self._v = self.velocity_mm_s

    def move_to(self, target_mm: float, t: float) -> None:
        here = self.readout(t)
        self._from, self._to, self._t0, self._v = here, target_mm, t, self.velocity_mm_s
        self._duration = _trapezoid_duration(abs(target_mm - here), self._v, self.accel_mm_s2)

    def stop(self, t: float) -> None:
        here = self.readout(t)
        self._from = self._to = here
        self._duration = 0.0

    def set_velocity(self, velocity_mm_s: float) -> None:
        self.velocity_mm_s = velocity_mm_s

    def velocity_setting(self) -> float:
        return self.velocity_mm_s

    def target(self) -> float:
        return self._to

    def readout(self, t: float) -> float:
        distance = self._to - self._from
        covered = _trapezoid_distance(t - self._t0, abs(distance), self._v, self.accel_mm_s2)
        return self._from + math.copysign(covered, distance)

    def on_target(self, t: float) -> bool:
        return t - self._t0 >= self._duration


def _trapezoid_duration(distance: float, v: float, a: float) -> float:
    if distance <= v * v / a:  # triangular: never reaches v
        return 2.0 * math.sqrt(distance / a)
    return distance / v + v / a


def _trapezoid_distance(dt: float, distance: float, v: float, a: float) -> float:
    """Distance covered ``dt`` after the start of a rest-to-rest move of length ``distance``."""
    total = _trapezoid_duration(distance, v, a)
    if dt <= 0:
        return 0.0
    if dt >= total:
        return distance
    v_peak = min(v, math.sqrt(distance * a))
    t_ramp = v_peak / a
    if dt < t_ramp:
        return 0.5 * a * dt * dt
    if dt > total - t_ramp:
        rest = total - dt
        return distance - 0.5 * a * rest * rest
    return 0.5 * a * t_ramp * t_ramp + v_peak * (dt - t_ramp)
