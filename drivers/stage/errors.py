"""Exceptions of the stage drivers.

Callers (the daemon's rig lifecycle, the calibration sweep) need to tell apart four situations
that call for different reactions: the controller refused a command (a GCS error number: report
it, the link is fine), the reply did not come in time (retry or fault), the reply was not GCS
(line noise: already resynchronised, retry), and the port is gone (wait: the driver reconnects on
its own). Each gets its own class; all derive from :class:`StageError`.
"""

from __future__ import annotations

# Texts for the GCS controller error numbers a linear closed-loop axis actually produces. They
# are paraphrased from the meaning of each code so the message stands on its own in a log line.
GCS_ERROR_TEXT: dict[int, str] = {
    0: "no error",
    1: "parameter syntax error",
    2: "unknown command",
    3: "command too long",
    5: "move refused: axis not referenced or servo off",
    7: "target position out of limits",
    8: "velocity out of limits",
    10: "motion stopped by STP or HLT",
    15: "invalid axis identifier",
    17: "parameter out of range",
    23: "illegal axis",
    24: "wrong number of parameters",
    25: "invalid floating point number",
    26: "parameter missing",
    45: "reference move failed",
    54: "unknown parameter",
    93: "command not allowed while the axis is moving",
    555: "unknown controller error",
}


def gcs_error_text(code: int) -> str:
    return GCS_ERROR_TEXT.get(code, f"controller error {code} (see the controller manual)")


class StageError(Exception):
    """Base of everything the stage drivers raise."""


class GCSControllerError(StageError):
    """The controller reported a nonzero error number (``ERR?``) after a command."""

    def __init__(self, code: int, command: str, text: str | None = None) -> None:
        self.code = int(code)
        self.command = command
        self.text = text if text is not None else gcs_error_text(self.code)
        super().__init__(f"GCS error {self.code} ({self.text}) after {command!r}")


class StageTimeoutError(StageError, TimeoutError):
    """No complete reply within the transaction timeout."""


class StageProtocolError(StageError):
    """A reply that is not what the command calls for (line noise, truncated or foreign data)."""


class StageConnectionError(StageError, ConnectionError):
    """The serial port is missing or failed; the driver reopens it on the next transaction."""


class StageLimitError(StageError, ValueError):
    """A move the driver refuses before sending it: outside the soft limits or the travel range."""
