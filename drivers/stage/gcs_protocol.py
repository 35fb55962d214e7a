"""PI GCS 2 ASCII syntax: formatting commands, framing replies, parsing axis values.

Pure functions and a byte-level framer with no I/O, so the wire rules are tested on their own and
shared by the driver and by the simulated controller.

Wire rules used here:
- a command is one line: ``NAME [ARG ...]`` terminated by LF; queries end in ``?``;
- a reply is one or more lines; every line but the last ends with a space before its LF, the last
  ends with a plain LF (the framing GCS uses for multi-line answers such as ``HLP?`` or ``POS?``
  over several axes);
- axis values come as ``AXIS=VALUE``;
- set commands never answer; their success is read back with ``ERR?`` (an integer, 0 = fine);
- single-character commands are one control byte with no line end (``#5`` is ``chr(5)``); a
  controller acts on them the moment they arrive, even in the middle of a text line.
"""

from __future__ import annotations

import math
import re

LF = b"\n"
CONTINUATION = b" \n"

_AXIS_VALUE = re.compile(r"^([A-Za-z0-9_]+)=(\S+)$")
_INTEGER = re.compile(r"^-?\d+$")
SMALLEST_NUMBER = 1e-9  # the smallest positive value format_number writes (9 decimals)


def format_number(value: float) -> str:
    """A float as GCS expects it: plain decimal, no exponent, enough digits for 0.1 nm in mm."""
    if not math.isfinite(value):
        raise ValueError(f"not a finite number: {value!r}")
    text = f"{value:.9f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def format_command(name: str, *args: object) -> bytes:
    """``name`` and its arguments as one LF-terminated line."""
    parts = [name]
    for arg in args:
        parts.append(format_number(arg) if isinstance(arg, float) else str(arg))
    line = " ".join(parts)
    if "\n" in line or "\r" in line:
        raise ValueError(f"GCS command must be a single line: {line!r}")
    return line.encode("ascii") + LF


class ReplyFramer:
    """Cuts a byte stream into complete GCS replies (lists of lines).

    Bytes arrive in arbitrary chunks; a reply is complete at the first line that does not end with
    the continuation space. Undecodable bytes (line noise) are kept as replacement characters so
    that the caller sees a malformed line rather than an exception.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._lines: list[str] = []

    def feed(self, data: bytes) -> list[list[str]]:
        """Add bytes; return every reply they complete, oldest first."""
        self._buffer.extend(data)
        replies: list[list[str]] = []
        while True:
            end = self._buffer.find(LF)
            if end < 0:
                return replies
            raw = bytes(self._buffer[: end + 1])
            del self._buffer[: end + 1]
            more = raw.endswith(CONTINUATION)
            self._lines.append(raw[: -2 if more else -1].rstrip(b"\r").decode("ascii", errors="replace"))
            if not more:
                replies.append(self._lines)
                self._lines = []

    def pending(self) -> bool:
        """True while a reply has started but not finished (partial line or open continuation)."""
        return bool(self._buffer) or bool(self._lines)

    def clear(self) -> None:
        self._buffer.clear()
        self._lines = []


class CommandFramer:
    """The controller's side of the wire: cuts received bytes into commands, in arrival order.

    A command is either a text line (``str``, without its line end, surrounding blanks removed)
    or a single-character command (``int``, the control byte: 5 for ``#5``). Control bytes are
    taken out of the stream wherever they fall, so ``#5`` sent while a line is half received
    neither ends nor corrupts that line: it is what PIPython's ``IsMoving`` relies on.
    """

    def __init__(self) -> None:
        self._line = bytearray()

    def feed(self, data: bytes) -> list[str | int]:
        commands: list[str | int] = []
        for byte in data:
            if byte == _LF_BYTE:
                commands.append(bytes(self._line).decode("ascii", errors="replace").strip())
                self._line.clear()
            elif byte < 0x20 and byte not in _LINE_WHITESPACE:
                commands.append(byte)
            else:
                self._line.append(byte)
        return commands

    def clear(self) -> None:
        self._line.clear()


_LF_BYTE = LF[0]
_LINE_WHITESPACE = frozenset(b"\r\t")


def parse_axis_value(line: str, axis: str) -> str:
    """The VALUE of an ``AXIS=VALUE`` line for the expected axis; anything else is malformed."""
    match = _AXIS_VALUE.match(line.strip())
    if match is None or match.group(1) != axis:
        raise ValueError(f"expected '{axis}=<value>', got {line!r}")
    return match.group(2)


def parse_axis_float(line: str, axis: str) -> float:
    value = float(parse_axis_value(line, axis))
    if not math.isfinite(value):
        raise ValueError(f"non-finite value in {line!r}")
    return value


def parse_parameter(line: str, axis: str, parameter: str) -> float:
    """``SPA?`` answer ``"1 0xA=50.000000"`` for ``axis`` and ``parameter`` as a float."""
    key, sep, value = line.partition("=")
    words = key.split()
    if not sep or len(words) != 2 or words[0] != axis or int(words[1], 0) != int(parameter, 0):
        raise ValueError(f"expected '{axis} {parameter}=<value>', got {line!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"non-finite value in {line!r}")
    return number


def parse_axis_bool(line: str, axis: str) -> bool:
    value = parse_axis_value(line, axis)
    if value not in ("0", "1"):
        raise ValueError(f"expected '{axis}=0' or '{axis}=1', got {line!r}")
    return value == "1"


def parse_error_code(line: str) -> int:
    text = line.strip()
    if not _INTEGER.match(text):
        raise ValueError(f"expected an integer error code, got {line!r}")
    return int(text)


def single_line(lines: list[str]) -> str:
    """The only line of a reply that must have exactly one."""
    if len(lines) != 1:
        raise ValueError(f"expected one line, got {len(lines)}: {lines!r}")
    return lines[0]
