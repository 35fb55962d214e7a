"""A closed-loop linear axis on a PI controller speaking GCS 2 over a serial port.

Covers the commands such an axis needs: ``*IDN?``, ``SVO``, ``FRF``/``FRF?``, ``MOV``/``MOV?``,
``MVR``, ``POS?``, ``ONT?``, ``VEL``/``VEL?``, ``STP``/``HLT``, ``ERR?``, ``TMN?``/``TMX?``.
Every set command is followed by ``ERR?``; every transaction holds the link lock; a lost port is
reopened by the next call (see :mod:`graytrack.drivers.stage.connection`).

Soft limits are enforced here, before anything is sent, because they protect the target and the
camera, which the controller knows nothing about.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Callable

from graytrack.drivers.registry import stages
from graytrack.drivers.stage import gcs_protocol as gcs
from graytrack.drivers.stage.base import PositionReading, Stage
from graytrack.drivers.stage.connection import GCSConnection, Reply
from graytrack.drivers.stage.errors import GCSControllerError, StageError, StageLimitError, StageTimeoutError

if TYPE_CHECKING:
    from graytrack.drivers.config import StageConfig

VELOCITY_OUT_OF_LIMITS = 8  # the GCS error number VEL leaves for a velocity the controller will not take
STOPPED_BY_COMMAND = 10  # the error STP/HLT leave in the register; expected after our own stop


@stages.register("gcs")
class GCSStage(Stage):
    @classmethod
    def from_config(cls, config: StageConfig, port: str | None = None) -> GCSStage:
        """The ``[stage]`` table's controller; ``port`` overrides its serial device (the virtual rig's pty)."""
        return cls(
            port or config.port or "",
            baudrate=config.baudrate,
            axis=config.axis,
            timeout_s=config.timeout_s,
            soft_limits_mm=config.soft_limits_mm,
            velocity_mm_s=config.velocity_mm_s,
            reference_on_open=config.reference_on_open,
        )

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        axis: str = "1",
        timeout_s: float = 1.0,
        soft_limits_mm: tuple[float, float] | None = None,
        velocity_mm_s: float | None = None,
        reference_on_open: bool = True,
    ) -> None:
        if soft_limits_mm is not None and not soft_limits_mm[0] < soft_limits_mm[1]:
            raise ValueError(f"soft limits must be (low, high) with low < high, got {soft_limits_mm}")
        self.axis = axis
        self.soft_limits_mm = soft_limits_mm
        self.velocity_mm_s = velocity_mm_s
        self.reference_on_open = reference_on_open
        # Readings are stamped on the host's time.monotonic whatever clock the controller runs on
        # (a simulated one may run faster): the time contract the cameras also keep.
        self.link = GCSConnection(port, baudrate=baudrate, timeout_s=timeout_s)
        self._travel: tuple[float, float] | None = None

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> None:
        """Identify, switch the servo on, reference if needed, set the velocity, read travel."""
        self.link.open()
        with self.link.locked():
            if not self.servo_on():
                self.set_servo(True)
            if self.reference_on_open and not self.is_referenced():
                self.reference()
            if self.velocity_mm_s is not None:
                self.set_velocity(self.velocity_mm_s)
            self._travel = self.travel_range()

    def close(self) -> None:
        self.link.close()

    def identify(self) -> str:
        return self._query_line("*IDN?").strip()

    # -- axis state ------------------------------------------------------------------------
    def set_servo(self, on: bool) -> None:
        self.link.command("SVO", self.axis, int(on))

    def servo_on(self) -> bool:
        return self._query_axis("SVO?", gcs.parse_axis_bool)

    def reference(self, timeout_s: float = 30.0) -> None:
        """Reference move (``FRF``), waiting until the controller reports the axis referenced."""
        self.link.command("FRF", self.axis)
        deadline = time.monotonic() + timeout_s
        while not self.is_referenced():
            if time.monotonic() > deadline:
                raise StageTimeoutError(f"axis {self.axis} not referenced within {timeout_s:g} s")
            time.sleep(0.01)
        self.wait_on_target(timeout_s)

    def is_referenced(self) -> bool:
        return self._query_axis("FRF?", gcs.parse_axis_bool)

    def travel_min(self) -> float:
        return self._query_axis("TMN?", gcs.parse_axis_float)

    def travel_max(self) -> float:
        return self._query_axis("TMX?", gcs.parse_axis_float)

    def travel_range(self) -> tuple[float, float]:
        return self.travel_min(), self.travel_max()

    def limits(self) -> tuple[float, float]:
        low, high = self._travel if self._travel is not None else (-math.inf, math.inf)
        if self.soft_limits_mm is not None:
            low, high = max(low, self.soft_limits_mm[0]), min(high, self.soft_limits_mm[1])
        return low, high

    # -- motion ----------------------------------------------------------------------------
    def move_to(self, target_mm: float) -> None:
        self._check_target(target_mm)
        self.link.command("MOV", self.axis, float(target_mm))

    def move_by(self, delta_mm: float) -> None:
        """Relative move; checked against the limits from the current target, atomically."""
        with self.link.locked():
            self._check_target(self.target() + delta_mm)
            self.link.command("MVR", self.axis, float(delta_mm))

    def target(self) -> float:
        return self._query_axis("MOV?", gcs.parse_axis_float)

    def position(self) -> PositionReading:
        value, reply = self.link.query(
            "POS?", self.axis, parse=lambda lines: gcs.parse_axis_float(gcs.single_line(lines), self.axis)
        )
        return _reading(value, reply)

    def on_target(self) -> bool:
        return self._query_axis("ONT?", gcs.parse_axis_bool)

    def wait_on_target(self, timeout_s: float, poll_s: float = 0.005) -> PositionReading:
        deadline = time.monotonic() + timeout_s
        while not self.on_target():
            if time.monotonic() > deadline:
                raise StageTimeoutError(f"axis {self.axis} not on target within {timeout_s:g} s")
            time.sleep(poll_s)
        return self.position()

    def set_velocity(self, velocity_mm_s: float) -> None:
        if not velocity_mm_s > 0:
            raise StageLimitError(f"velocity must be positive, got {velocity_mm_s}")
        if float(gcs.format_number(float(velocity_mm_s))) <= 0.0:
            raise StageLimitError(
                f"velocity {velocity_mm_s:g} mm/s is below the 1e-9 mm/s the GCS protocol can express")
        try:
            self.link.command("VEL", self.axis, float(velocity_mm_s))
        except GCSControllerError as exc:
            if exc.code != VELOCITY_OUT_OF_LIMITS:
                raise
            limit = self.velocity_limit()
            raise StageLimitError(f"velocity {velocity_mm_s:g} mm/s is beyond the controller's limit"
                                  + (f" of {limit:g} mm/s" if limit is not None else "")) from None

    def velocity(self) -> float:
        return self._query_axis("VEL?", gcs.parse_axis_float)

    def velocity_limit(self) -> float | None:
        """The controller's maximum closed-loop velocity (parameter 0xA), None when it will not say."""
        try:
            value, _ = self.link.query("SPA?", self.axis, "0xA",
                                       parse=lambda lines: gcs.parse_parameter(gcs.single_line(lines),
                                                                               self.axis, "0xA"))
        except StageError:
            self.link.error_code()  # an older controller refuses SPA?: its error register is cleared
            return None
        return value

    def stop(self) -> None:
        """``STP``: abrupt stop of all axes. The controller then holds error 10, which is ours."""
        self.link.command("STP", tolerate=(STOPPED_BY_COMMAND,))

    def halt(self) -> None:
        """``HLT``: decelerated stop of this axis."""
        self.link.command("HLT", self.axis, tolerate=(STOPPED_BY_COMMAND,))

    def error_code(self) -> int:
        return self.link.error_code()

    # -- helpers ---------------------------------------------------------------------------
    def _check_target(self, target_mm: float) -> None:
        low, high = self.limits()
        if not (math.isfinite(target_mm) and low <= target_mm <= high):
            raise StageLimitError(f"target {target_mm!r} mm outside the allowed range [{low:g}, {high:g}] mm")

    def _query_axis(self, name: str, parse: Callable[[str, str], object]):  # type: ignore[no-untyped-def]
        value, _ = self.link.query(name, self.axis, parse=lambda lines: parse(gcs.single_line(lines), self.axis))
        return value

    def _query_line(self, name: str) -> str:
        value, _ = self.link.query(name, parse=gcs.single_line)
        return value


def _reading(value: float, reply: Reply) -> PositionReading:
    return PositionReading(position_mm=value, t=reply.t_mid, latency_s=reply.t_received - reply.t_sent)
