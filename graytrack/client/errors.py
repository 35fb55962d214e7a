"""What the client raises: one root, one class per answer a caller handles differently.

An HTTP refusal keeps the daemon's own sentence (its JSON ``error``) in ``error`` and the status
in ``status``, so a control system can log exactly what the daemon said and branch on the kind
(a missing token is fixed by configuration, a conflict by waiting, an invalid value by the caller).
"""

from __future__ import annotations

from typing import Any


class GraytrackClientError(Exception):
    """Anything the client could not do; ``status`` is the HTTP status when the daemon answered."""

    def __init__(self, error: str, status: int | None = None, request: str | None = None,
                 hint: str | None = None) -> None:
        self.error = error
        self.status = status
        self.request = request
        where = f"{request}: " if request else ""
        code = f"{status} " if status is not None else ""
        super().__init__(f"{where}{code}{error}" + (f" ({hint})" if hint else ""))


class AuthError(GraytrackClientError):
    """401: no bearer token, or not the daemon's (``DATA/token``)."""


class NotFound(GraytrackClientError):
    """404: no such calibration, file or route."""


class Conflict(GraytrackClientError):
    """409: the rig is doing something that excludes the request (a calibration runs, the stage is busy)."""


class Invalid(GraytrackClientError):
    """422: a value the daemon refuses (a target outside the soft limits, a malformed query)."""


class NotReady(GraytrackClientError):
    """503: the hardware is starting or in fault; retrying later may succeed."""


class Unreachable(GraytrackClientError):
    """No answer: the daemon is not listening, the network failed or the request timed out."""


class ProtocolError(GraytrackClientError):
    """An answer this client cannot read (a daemon of another version, or not a graytrack daemon)."""


class CalibrationFailed(GraytrackClientError):
    """The calibration ended ``failed``, ``aborted`` or ``interrupted``; ``job`` is its last document."""

    def __init__(self, job: Any) -> None:
        self.job = job
        reason = job.error or job.message or "no reason given"
        super().__init__(f"calibration {job.id} {job.state}: {reason}")


class WaitTimeout(GraytrackClientError):
    """A wait (calibration, settling) outlasted its timeout; the daemon goes on with the job."""


class StreamRefused(GraytrackClientError):
    """The daemon refused the position stream (Host, Origin, token or ``max_rate``): retrying will not help."""


class StreamSilent(GraytrackClientError):
    """No position message within ``silence_s`` (frames not tracked, or the daemon unreachable)."""


BY_STATUS: dict[int, type[GraytrackClientError]] = {401: AuthError, 404: NotFound, 409: Conflict, 422: Invalid,
                                                      503: NotReady}


def for_status(status: int, error: str, request: str, hint: str | None = None) -> GraytrackClientError:
    """The exception for a refusal with HTTP ``status`` and the daemon's sentence ``error``."""
    return BY_STATUS.get(status, GraytrackClientError)(error, status, request, hint)
