"""The command interpreter of a simulated single-axis PI GCS 2 controller (no I/O).

It keeps what a real controller keeps (servo state, referenced flag, stage name, the error
register) and answers the way one does, so that graytrack's driver and PI's own software (PIPython,
which reads ``CSV?``, ``HLP?``, ``HPA?`` to learn what the controller can do) both work against it:

- queries reply ``AXIS=VALUE`` (or free text: ``*IDN?``, ``VER?``, ``HLP?``, ``HPA?``);
- set commands stay silent; a refused command sets the error register (read and cleared by
  ``ERR?``) and, if it was a query, gets no reply at all;
- single-character commands (control bytes sent alone: #4 status register, #5 motion status,
  #7 ready status, #8 macro running, #24 stop all) are handled apart from text lines because
  they arrive without a line end; #7 answers the byte B1h (ready) or B0h (busy).

The byte transport and fault injection live in :mod:`.sim_controller`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from graytrack import __version__
from graytrack.drivers.stage import gcs_protocol as gcs
from graytrack.drivers.stage.axis_model import AxisModel

DEFAULT_IDN = "(c)2024 Physik Instrumente (PI) GmbH & Co. KG, C-863.12 (simulated), 0000000001, 01.001"
DEFAULT_STAGE = "SIM-LINEAR-STAGE"
SYNTAX_VERSION = "2.0"  # CSV?: GCS 2.0; PIPython picks its GCS 2 command set from it
MAX_VELOCITY_MM_S = 50.0
MAX_VELOCITY_PARAMETER = 0xA  # PI's parameter ID of the maximum closed-loop velocity
READY, BUSY = "\xb1", "\xb0"  # #7 answers: the bytes B1h / B0h (cp1252 "±" / "°")

# GCS error numbers the interpreter sets
E_SYNTAX, E_UNKNOWN_COMMAND, E_NOT_ALLOWED, E_POSITION_LIMITS, E_VELOCITY_LIMITS = 1, 2, 5, 7, 8
E_STOPPED, E_INVALID_AXIS, E_OUT_OF_RANGE, E_PARAMETER_COUNT, E_INVALID_FLOAT, E_MISSING = 10, 15, 17, 24, 25, 26
E_UNKNOWN_PARAMETER = 54

# #4 status register bits for the axis (the C-863's layout)
STATUS_ON_TARGET, STATUS_REFERENCING, STATUS_MOVING, STATUS_SERVO, STATUS_ERROR = 0x8000, 0x4000, 0x2000, 0x1000, 0x100


class _Refused(Exception):
    def __init__(self, code: int) -> None:
        self.code = code


@dataclass
class AxisState:
    servo: bool = False
    referenced: bool = False
    referencing: bool = False  # an FRF reference move under way
    stage: str = DEFAULT_STAGE


@dataclass(frozen=True)
class Parameter:
    """One entry of the parameter table (``SPA?`` reads it, ``HPA?`` lists it)."""

    kind: str  # HPA? data type: INT, FLOAT or CHAR
    group: str
    description: str
    value: Callable[[], object]


Handler = Callable[[list[str]], "list[str] | None"]


class SimGCSInterpreter:
    """Executes GCS commands against an :class:`AxisModel`; returns reply lines or None."""

    def __init__(
        self,
        model: AxisModel,
        clock: Callable[[], float],
        axis: str = "1",
        idn: str = DEFAULT_IDN,
        reference_mm: float | None = None,
        stage: str = DEFAULT_STAGE,
    ) -> None:
        self.model = model
        self.clock = clock
        self.axis = axis
        self.idn = idn
        self.reference_mm = reference_mm
        self.state = AxisState(stage=stage)
        self.error = 0
        # name -> (handler, what HLP? says of it); the order is HLP?'s
        self._commands: dict[str, tuple[Handler, str]] = {
            "*IDN?": (lambda args: [self.idn], "get device identification"),
            "CST": (self._cst, "set stage name of axis"),
            "CST?": (lambda args: self._axis_reply(args, lambda: self.state.stage), "get stage name of axis"),
            "CSV?": (lambda args: [SYNTAX_VERSION], "get current GCS syntax version"),
            "ERR?": (self._err, "get number of the last error and reset it to 0"),
            "FRF": (self._frf, "reference move to the reference switch"),
            "FRF?": (lambda args: self._axis_reply(args, lambda: int(self._referenced())), "get referencing result"),
            "HLP?": (self._help, "list the available commands"),
            "HLT": (self._hlt, "halt motion smoothly"),
            "HPA?": (self._parameter_help, "list the available parameters"),
            "LIM?": (lambda args: self._axis_reply(args, lambda: 1), "axis has limit switches?"),
            "MOV": (self._mov, "move to absolute target"),
            "MOV?": (lambda args: self._axis_reply(args, self.model.target), "get target position"),
            "MVR": (self._mvr, "move relative to current target"),
            "ONT?": (lambda args: self._axis_reply(args, lambda: int(self._on_target())), "get on-target state"),
            "POS?": (lambda args: self._axis_reply(args, lambda: self.model.readout(self.clock())),
                     "get real position"),
            "SAI?": (self._sai, "get list of current axis identifiers"),
            "SPA?": (self._spa, "get parameter value in volatile memory"),
            "STP": (self._stp, "stop all axes abruptly"),
            "SVO": (self._svo, "set servo mode"),
            "SVO?": (lambda args: self._axis_reply(args, lambda: int(self.state.servo)), "get servo mode"),
            "TMN?": (lambda args: self._axis_reply(args, lambda: self.model.travel_mm[0]),
                     "get minimum commandable position"),
            "TMX?": (lambda args: self._axis_reply(args, lambda: self.model.travel_mm[1]),
                     "get maximum commandable position"),
            "TRS?": (lambda args: self._axis_reply(args, lambda: 1), "axis has a reference switch?"),
            "VEL": (self._vel, "set closed-loop velocity"),
            "VEL?": (lambda args: self._axis_reply(args, self.model.velocity_setting), "get closed-loop velocity"),
            "VER?": (self._version, "get versions of firmware and drivers"),
        }
        # code of the control byte -> (handler, description); shown by HLP? as "#<code>"
        self._single: dict[int, tuple[Callable[[], list[str] | None], str]] = {
            4: (lambda: [f"0x{self._status_register():04X}"], "request status register"),
            5: (lambda: [f"{int(not self._on_target()):X}"], "request motion status"),
            7: (lambda: [BUSY if self._referencing() else READY], "request controller ready status"),
            8: (lambda: ["0"], "query if macro is running"),
            24: (self._stop_all, "stop all axes"),
        }
        self._parameters: dict[int, Parameter] = {
            MAX_VELOCITY_PARAMETER: Parameter("FLOAT", "motion", "maximum closed-loop velocity (mm/s)",
                                              lambda: MAX_VELOCITY_MM_S),
            0x14: Parameter("INT", "reference", "has reference switch (1 = yes)", lambda: 1),
            0x32: Parameter("INT", "limits", "has no limit switches (0 = has them)", lambda: 0),
            0x3C: Parameter("CHAR", "stage", "stage name", lambda: self.state.stage),
            0x49: Parameter("FLOAT", "motion", "closed-loop velocity (mm/s)", self.model.velocity_setting),
        }

    # -- entry points ----------------------------------------------------------------------
    def execute(self, line: str) -> list[str] | None:
        """One text command line (without its line end)."""
        words = line.split()
        if not words:
            return None
        entry = self._commands.get(words[0])
        if entry is None:
            self._refuse(E_UNKNOWN_COMMAND)
            return None
        return self._run(lambda: entry[0](words[1:]))

    def execute_single(self, code: int) -> list[str] | None:
        """One single-character command: the control byte ``code`` (5 for #5), sent without a line end."""
        entry = self._single.get(code)
        if entry is None:
            self._refuse(E_UNKNOWN_COMMAND)
            return None
        return self._run(entry[0])

    def fail(self, code: int) -> None:
        """Set the error register as if the last command had failed (fault injection)."""
        self._refuse(code)

    def _run(self, call: Callable[[], list[str] | None]) -> list[str] | None:
        try:
            return call()
        except _Refused as refused:
            self._refuse(refused.code)
            return None

    def _refuse(self, code: int) -> None:
        if self.error == 0:  # the first error is kept until it is read
            self.error = code

    # -- state derived from the motion -----------------------------------------------------
    def _on_target(self) -> bool:
        return self.model.on_target(self.clock())

    def _referencing(self) -> bool:
        """True while an FRF move runs; the axis counts as referenced once it has ended on target."""
        if self.state.referencing and self._on_target():
            self.state.referencing = False
            self.state.referenced = True
        return self.state.referencing

    def _referenced(self) -> bool:
        self._referencing()
        return self.state.referenced

    def _stop(self) -> None:
        """Every stop (STP, HLT, #24, servo off) also aborts a reference move, leaving the axis unreferenced."""
        self.model.stop(self.clock())
        self.state.referencing = False

    def _status_register(self) -> int:
        value = STATUS_SERVO if self.state.servo else 0
        if self._referencing():
            value |= STATUS_REFERENCING
        value |= STATUS_ON_TARGET if self._on_target() else STATUS_MOVING
        return value | (STATUS_ERROR if self.error else 0)

    # -- argument checks -------------------------------------------------------------------
    def _check_axes(self, axes: list[str]) -> None:
        """Axis identifiers of a command addressing axes only: unknown first (15), then too many (24)."""
        if any(axis != self.axis for axis in axes):
            raise _Refused(E_INVALID_AXIS)
        if len(axes) > 1:  # the C-863 takes one element per command line
            raise _Refused(E_PARAMETER_COUNT)

    def _axis_reply(self, args: list[str], value: Callable[[], object]) -> list[str]:
        self._check_axes(args)
        result = value()
        text = gcs.format_number(result) if isinstance(result, float) else str(result)
        return [f"{self.axis}={text}"]

    def _axis_argument(self, args: list[str]) -> str:
        """The one argument after the axis of ``CMD AXIS VALUE``."""
        if not args:
            raise _Refused(E_MISSING)
        if any(axis != self.axis for axis in args[::2]):
            raise _Refused(E_INVALID_AXIS)
        if len(args) != 2:
            raise _Refused(E_PARAMETER_COUNT)
        return args[1]

    def _axis_value(self, args: list[str]) -> float:
        try:
            value = float(self._axis_argument(args))
        except ValueError:
            raise _Refused(E_SYNTAX) from None
        if not math.isfinite(value):
            raise _Refused(E_INVALID_FLOAT)
        return value

    # -- handlers --------------------------------------------------------------------------
    def _err(self, args: list[str]) -> list[str]:
        code, self.error = self.error, 0
        return [str(code)]

    def _help(self, args: list[str]) -> list[str]:
        lines = [f"#{code} {text}" for code, (_, text) in self._single.items()]
        lines += [f"{name} {text}" for name, (_, text) in self._commands.items()]
        return ["The following commands are valid:", *lines, "end of help"]

    def _parameter_help(self, args: list[str]) -> list[str]:
        """``HPA?``: ``ID=`` then command level, item count, type, group, description, tab-separated."""
        lines = [f"0x{pid:X}=\t0\t1\t{p.kind}\t{p.group}\t{p.description}" for pid, p in self._parameters.items()]
        return ["The following parameters are valid:", *lines, "end of help"]

    def _version(self, args: list[str]) -> list[str]:
        firmware = self.idn.split(",")[-1].strip()
        return [f"FW_ARM: V{firmware} (simulated)", f"graytrack: {__version__} sim-controller"]

    def _sai(self, args: list[str]) -> list[str]:
        if args not in ([], ["ALL"]):
            raise _Refused(E_SYNTAX)
        return [self.axis]

    def _cst(self, args: list[str]) -> None:
        self.state.stage = self._axis_argument(args)

    def _svo(self, args: list[str]) -> None:
        value = self._axis_value(args)
        if value not in (0.0, 1.0):
            raise _Refused(E_OUT_OF_RANGE)
        self.state.servo = value == 1.0
        if not self.state.servo:
            self._stop()

    def _frf(self, args: list[str]) -> None:
        self._check_axes(args)
        if not self.state.servo:
            raise _Refused(E_NOT_ALLOWED)
        if self.reference_mm is None:
            self.state.referenced = True
            return
        try:
            self.model.move_to(self.reference_mm, self.clock())
        except ValueError:  # a reference position outside the axis model's limits
            raise _Refused(E_POSITION_LIMITS) from None
        self.state.referenced, self.state.referencing = False, True

    def _move_allowed(self, target: float) -> None:
        if not (self.state.servo and self._referenced()):
            raise _Refused(E_NOT_ALLOWED)
        low, high = self.model.travel_mm
        if not low <= target <= high:
            raise _Refused(E_POSITION_LIMITS)

    def _mov(self, args: list[str]) -> None:
        self._move(self._axis_value(args))

    def _mvr(self, args: list[str]) -> None:
        self._move(self.model.target() + self._axis_value(args))

    def _move(self, target: float) -> None:
        self._move_allowed(target)
        try:
            self.model.move_to(target, self.clock())
        except ValueError:  # the axis model's own limits
            raise _Refused(E_POSITION_LIMITS) from None

    def _spa(self, args: list[str]) -> list[str]:
        """``SPA? [AXIS PARAM]``: one parameter, or every one when no argument is given."""
        if not args:
            return [self._parameter_line(f"0x{pid:X}", pid) for pid in self._parameters]
        if len(args) != 2:
            raise _Refused(E_PARAMETER_COUNT)
        if args[0] != self.axis:
            raise _Refused(E_INVALID_AXIS)
        try:
            parameter = int(args[1], 0)
        except ValueError:
            raise _Refused(E_SYNTAX) from None
        if parameter not in self._parameters:
            raise _Refused(E_UNKNOWN_PARAMETER)
        return [self._parameter_line(args[1], parameter)]

    def _parameter_line(self, spelled: str, parameter: int) -> str:
        entry = self._parameters[parameter]
        value = entry.value()
        text = f"{value:.6f}" if entry.kind == "FLOAT" else str(value)
        return f"{self.axis} {spelled}={text}"

    def _vel(self, args: list[str]) -> None:
        value = self._axis_value(args)
        if not 0.0 < value <= MAX_VELOCITY_MM_S:
            raise _Refused(E_VELOCITY_LIMITS)
        try:
            self.model.set_velocity(value)
        except ValueError:  # the axis model has a lower limit than the controller
            raise _Refused(E_VELOCITY_LIMITS) from None

    def _stp(self, args: list[str]) -> None:
        if args:
            raise _Refused(E_PARAMETER_COUNT)
        self._stop_all()

    def _stop_all(self) -> None:
        self._stop()
        self._refuse(E_STOPPED)

    def _hlt(self, args: list[str]) -> None:
        self._check_axes(args)
        self._stop()
        self._refuse(E_STOPPED)
