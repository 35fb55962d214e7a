"""A typed client for the graytrack daemon, blocking (:class:`Client`) and asyncio (:class:`AsyncClient`).

::

    from graytrack.client import Client

    with Client("http://127.0.0.1:8000", data_dir="~/.local/state/graytrack") as daemon:
        daemon.ensure_calibrated(progress=lambda fraction, message: print(f"{fraction:.0%} {message}"))
        daemon.move(5.0, wait=True)
        with daemon.stream() as positions:
            for p in positions:          # reconnects by itself; p.gap counts the messages missed
                print(p.seq, p.x_mm, p.locked)

Answers are the daemon's own response models (``graytrack.wire``); refusals
raise a :class:`GraytrackClientError` carrying the HTTP status and the daemon's sentence.
"""

from graytrack.client.aio import AsyncClient, AsyncPositionStream
from graytrack.client.errors import (AuthError, CalibrationFailed, Conflict, GraytrackClientError, Invalid, NotFound,
                                     NotReady, ProtocolError, StreamRefused, StreamSilent, Unreachable, WaitTimeout)
from graytrack.client.stream import Position
from graytrack.client.sync import Client, PositionStream

__all__ = ["AsyncClient", "AsyncPositionStream", "AuthError", "CalibrationFailed", "Client", "Conflict",
           "GraytrackClientError", "Invalid", "NotFound", "NotReady", "Position", "PositionStream", "ProtocolError",
           "StreamRefused", "StreamSilent", "Unreachable", "WaitTimeout"]
