"""The daemon's one error root and the HTTP status each kind maps to.

Every refusal the daemon makes (a request at the wrong time, a target outside the limits, an
unknown calibration) is a :class:`DaemonError`; the app maps ``status`` to the answer in one
handler, so the code that refuses never speaks HTTP and the API never invents a status.
"""

from __future__ import annotations


class DaemonError(Exception):
    """A request the daemon refuses; ``status`` is the HTTP status of the answer."""

    status = 409


class Busy(DaemonError):
    status = 409


class NotReady(DaemonError):
    status = 503


class DamagedCalibration(DaemonError):
    """A calibration whose stored files cannot be read back (its ``model.json`` missing, not JSON, of another
    schema): the request was fine, the calibration is not, and retrying changes nothing."""

    status = 409


class OutOfLimits(DaemonError):
    status = 422


class NotFound(DaemonError):
    status = 404


class Invalid(DaemonError):
    status = 422


class InsufficientStorage(DaemonError):
    """The data directory has no room for what the request would write."""

    status = 507


class UnsafeDataDir(DaemonError):
    """The data directory or its token could be changed by another user (``serve`` exits 2 with the fix)."""

    status = 503


class DataDirInUse(DaemonError):
    """Another daemon holds the data directory's lock (``graytrack serve`` exits 2 with this line)."""

    status = 503
