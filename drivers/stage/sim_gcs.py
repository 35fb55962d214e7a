"""The command interpreter of a simulated single-axis PI GCS controller (no I/O).

It keeps what a real controller keeps (servo state, referenced flag, the error register) and
answers the way one does: queries reply ``AXIS=VALUE``; set commands stay silent; a refused
command sets the error register (read and cleared by ``ERR?``) and, if it was a query, gets no
reply at all. The byte transport and fault injection live in :mod:`.sim_controller`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from graytrack.drivers.stage import gcs_protocol as gcs
from graytrack.drivers.stage.axis_model import AxisModel

DEFAULT_IDN = "(c)2024 Physik Instrumente (PI) GmbH & Co. KG, C-863.12 (simulated), 0000000001, 01.001"
MAX_VELOCITY_MM_S = 50.0
MAX_VELOCITY_PARAMETER = 0xA  # PI's parameter ID of the maximum closed-loop velocity


class _Refused(Exception):
    def __init__(self, code: int) -> None:
        self.code = code


@dataclass
class AxisState:
    servo: bool = False
    referenced: bool = False


class SimGCSInterpreter:
    """Executes one GCS command line against an :class:`AxisModel`; returns reply lines or None."""

    def __init__(
        self,
        model: AxisModel,
        clock: Callable[[], float],
        axis: str = "1",
        idn: str = DEFAULT_IDN,
        reference_mm: float | None = None,
    ) -> None:
        self.model = model
        self.clock = clock
        self.axis = axis
        self.idn = idn
        self.reference_mm = reference_mm
        self.state = AxisState()
        self.error = 0
        self._handlers: dict[str, Callable[[list[str]], list[str] | None]] = {
            "*IDN?": lambda args: [self.idn],
            "ERR?": self._err,
            "SAI?": lambda args: [self.axis],
            "HLP?": self._help,
            "SVO": self._svo,
            "SVO?": lambda args: self._axis_reply(args, lambda: int(self.state.servo)),
            "FRF": self._frf,
            "FRF?": lambda args: self._axis_reply(args, lambda: int(self.state.referenced)),
            "MOV": self._mov,
            "MVR": self._mvr,
            "MOV?": lambda args: self._axis_reply(args, self.model.target),
            "POS?": lambda args: self._axis_reply(args, lambda: self.model.readout(self.clock())),
            "ONT?": lambda args: self._axis_reply(args, lambda: int(self.model.on_target(self.clock()))),
            "VEL": self._vel,
            "VEL?": lambda args: self._axis_reply(args, self.model.velocity_setting),
            "SPA?": self._spa,
            "TMN?": lambda args: self._axis_reply(args, lambda: self.model.travel_mm[0]),
            "TMX?": lambda args: self._axis_reply(args, lambda: self.model.travel_mm[1]),
            "STP": self._stp,
            "HLT": self._hlt,
        }

    def execute(self, line: str) -> list[str] | None:
        words = line.split()
        if not words:
            return None
        name, args = words[0], words[1:]
        handler = self._handlers.get(name)
        if handler is None:
            self._refuse(2)
            return None
        try:
            return handler(args)
        except _Refused as refused:
            self._refuse(refused.code)
            return None

    def fail(self, code: int) -> None:
        """Set the error register as if the last command had failed (fault injection)."""
        self._refuse(code)

    def _refuse(self, code: int) -> None:
        if self.error == 0:  # GCS keeps the first error until it is read
            self.error = code

    # -- handlers --------------------------------------------------------------------------
    def _err(self, args: list[str]) -> list[str]:
        code, self.error = self.error, 0
        return [str(code)]

    def _help(self, args: list[str]) -> list[str]:
        return [f"{name} (simulated)" for name in sorted(self._handlers)]

    def _axis_reply(self, args: list[str], value: Callable[[], object]) -> list[str]:
        if len(args) > 1:
            raise _Refused(24)
        if args and args[0] != self.axis:
            raise _Refused(15)
        result = value()
        text = gcs.format_number(result) if isinstance(result, float) else str(result)
        return [f"{self.axis}={text}"]

    def _axis_value(self, args: list[str]) -> float:
        if len(args) != 2:
            raise _Refused(24 if args else 26)
        if args[0] != self.axis:
            raise _Refused(15)
        try:
            value = float(args[1])
        except ValueError:
            raise _Refused(1) from None
        if not math.isfinite(value):
            raise _Refused(25)
        return value

    def _svo(self, args: list[str]) -> None:
        value = self._axis_value(args)
        if value not in (0.0, 1.0):
            raise _Refused(17)
        self.state.servo = value == 1.0
        if not self.state.servo:
            self.model.stop(self.clock())

    def _frf(self, args: list[str]) -> None:
        if args and args != [self.axis]:
            raise _Refused(15)
        if not self.state.servo:
            raise _Refused(5)
        if self.reference_mm is not None:
            self.model.move_to(self.reference_mm, self.clock())
        self.state.referenced = True

    def _move_allowed(self, target: float) -> None:
        if not (self.state.servo and self.state.referenced):
            raise _Refused(5)
        low, high = self.model.travel_mm
        if not low <= target <= high:
            raise _Refused(7)

    def _mov(self, args: list[str]) -> None:
        self._move(self._axis_value(args))

    def _mvr(self, args: list[str]) -> None:
        self._move(self.model.target() + self._axis_value(args))

    def _move(self, target: float) -> None:
        self._move_allowed(target)
        try:
            self.model.move_to(target, self.clock())
        except ValueError:  # the axis model's own limits
            raise _Refused(7) from None

    def _spa(self, args: list[str]) -> list[str]:
        """``SPA? axis param``: the one parameter a client needs here, 0xA, the closed-loop velocity limit."""
        if len(args) != 2:
            raise _Refused(24)
        if args[0] != self.axis:
            raise _Refused(15)
        try:
            parameter = int(args[1], 0)
        except ValueError:
            raise _Refused(1) from None
        if parameter != MAX_VELOCITY_PARAMETER:
            raise _Refused(54)
        return [f"{self.axis} {args[1]}={MAX_VELOCITY_MM_S:.6f}"]

    def _vel(self, args: list[str]) -> None:
        value = self._axis_value(args)
        if not 0.0 < value <= MAX_VELOCITY_MM_S:
            raise _Refused(8)
        try:
            self.model.set_velocity(value)
        except ValueError:  # the axis model has a lower limit than the controller
            raise _Refused(8) from None

    def _stp(self, args: list[str]) -> None:
        if args:
            raise _Refused(24)
        self.model.stop(self.clock())
        self._refuse(10)

    def _hlt(self, args: list[str]) -> None:
        if args and args != [self.axis]:
            raise _Refused(15)
        self.model.stop(self.clock())
        self._refuse(10)
