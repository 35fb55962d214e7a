"""The virtual rig in a process of its own: the stage's true motion, the simulated PI controller on
its pty, and the camera's rendering, out of the daemon's interpreter.

In one process the virtual rig costs the daemon what real hardware never does: per frame the stage's
true positions during the exposure and the frame's rendering (``FrameRenderer``), and per grating
poll the controller's command interpreter, all under the interpreter lock the frame thread and the
event loop need (py-spy at 1 kHz × 4 clients, 16 rows: about a third of the frame thread's samples).
Here they run in a child process, and the daemon talks to it as to hardware: the stage through the
controller's pty (the same :class:`GCSStage` as on the bench), the camera through a socket pair
(:meth:`RigProcess.render`: one small request per frame, the strip back as raw bytes).

Faithful to the in-process rig: the child receives the rig object itself (pickled, its noise stream
at the same state), builds the stage and the controller as :func:`factory.virtual_rig_controller`
does, and renders exactly the frames asked for, in order, with :class:`FrameRenderer` (which falls back
to :meth:`VirtualRig.render` as it does in process): for a given seed, the same frames
(tests/drivers/test_rig_process.py). The frame clock stays with the camera driver in the daemon.

Lifecycle: :meth:`RigProcess.start` spawns ``python -m graytrack.drivers.sim.process`` and waits for
its pty; :meth:`stop` closes the socket (the child's request loop ends on EOF, it stops its controller
and exits) and kills it if it does not. A child that dies or hangs never takes the daemon with it:
:meth:`render` raises :class:`RigProcessDied` naming the exit status (the camera driver reports it as a
camera error, the controller's pty closes and the stage reports its own fault), or
:class:`RigProcessTimeout` when no frame comes back in time (a camera that stops delivering).
"""

from __future__ import annotations

import os
import pickle
import signal
import socket
import struct
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

START_TIMEOUT_S = 60.0  # the child imports numpy and the rig (seconds on a loaded machine)
STOP_TIMEOUT_S = 2.0
_REQUEST = struct.Struct("!qdd")  # sequence number, mid-exposure (simulated clock), exposure; then the instants
_REPLY = struct.Struct("!qB3s")  # sequence number, 0 = pixels follow / 1 = an error message follows, pixel dtype


class RigProcessError(RuntimeError):
    """The rig process could not be started or used."""


class RigProcessDied(RigProcessError):
    """The rig process has ended (its exit status in the message)."""


class RigProcessTimeout(RigProcessError, TimeoutError):
    """No frame came back from the rig process in time."""


class RigProcess:
    """The parent's side: start, ``render`` frames, ``stop``. ``path`` is the controller's pty."""

    def __init__(self, rig: Any, clock: Any, link: str | None = None) -> None:
        self.rig = rig
        self.clock = clock
        self.link = link
        self.path: str | None = None
        self.process: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._shape: tuple[int, ...] = ()
        self._seq = 0
        self._lock = threading.Lock()

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "RigProcess":
        ours, theirs = socket.socketpair()
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "graytrack.drivers.sim.process", str(theirs.fileno())],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, close_fds=True)
        except OSError as exc:
            ours.close()
            raise RigProcessError(f"cannot start the virtual rig's process: {exc}") from exc
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        try:
            self._conn.send_bytes(pickle.dumps((self.rig, self.clock, self.link), protocol=pickle.HIGHEST_PROTOCOL))
            if not self._conn.poll(START_TIMEOUT_S):
                raise RigProcessTimeout(f"the virtual rig's process did not start within {START_TIMEOUT_S:g} s")
            kind, *rest = pickle.loads(self._conn.recv_bytes())
        except RigProcessError:
            self.stop()
            raise
        except (EOFError, OSError) as exc:
            self.stop()
            raise RigProcessDied(f"the virtual rig's process ended while starting: {self._death()}") from exc
        if kind != "ready":
            self.stop()
            raise RigProcessError(f"the virtual rig's process could not start: {rest[0]}")
        self.path, self._shape = rest
        return self

    def stop(self) -> None:
        """End the child (EOF on its socket, then SIGKILL if it lingers); safe to call twice."""
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.close()
        process = self.process
        if process is not None and process.poll() is None:
            try:
                process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(STOP_TIMEOUT_S)

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None and self._conn is not None

    def describe(self) -> str:
        """Why the process cannot render ('' while it runs)."""
        if self.process is None:
            return "the virtual rig's process was never started"
        if self._conn is None and self.process.poll() is None:
            return "the virtual rig's process was stopped"
        return "" if self.process.poll() is None else f"the virtual rig's process {self._death()}"

    def _death(self) -> str:
        process = self.process
        if process is None:
            return "was never started"
        try:
            code = process.wait(1.0)
        except subprocess.TimeoutExpired:
            return f"(pid {process.pid}) stopped answering"
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            return f"(pid {process.pid}) was killed by {name}"
        return f"(pid {process.pid}) exited with status {code}"

    # -- frames ----------------------------------------------------------------------------
    def render(self, instants: np.ndarray, t_mid_s: float, exposure_s: float, timeout_s: float) -> np.ndarray:
        """The strip ``(R, n)`` exposed around ``t_mid_s`` (simulated clock), the stage's true positions
        taken in the child at ``instants``: what ``FrameRenderer.render(truth.position(instants), ...)``
        gives in process. Raises :class:`RigProcessDied` or :class:`RigProcessTimeout`."""
        with self._lock:
            conn = self._conn
            if conn is None or self.process is None or self.process.poll() is not None:
                raise RigProcessDied(self.describe() or "the virtual rig's process is not running")
            self._seq += 1
            seq = self._seq
            request = _REQUEST.pack(seq, t_mid_s, exposure_s) + np.ascontiguousarray(instants, dtype="<f8").tobytes()
            try:
                conn.send_bytes(request)
                while True:
                    if not conn.poll(timeout_s):
                        raise RigProcessTimeout(f"no frame from the virtual rig's process within {timeout_s:g} s")
                    reply = conn.recv_bytes()
                    got, status, dtype = _REPLY.unpack_from(reply)
                    if got == seq:
                        break  # older replies: frames given up on after a timeout
            except RigProcessTimeout:  # a TimeoutError, so an OSError: not a death
                raise
            except (EOFError, OSError) as exc:
                raise RigProcessDied(f"the virtual rig's process {self._death()}") from exc
            if status:
                raise RigProcessError(f"the virtual rig's process could not render: "
                                      f"{reply[_REPLY.size:].decode(errors='replace')}")
            # a copy: writable, and owned by the frame (the reply's bytes are not)
            return np.frombuffer(reply, np.dtype(dtype.decode()), offset=_REPLY.size).reshape(self._shape).copy()


# -- the child ---------------------------------------------------------------------------------
def _serve(conn: Connection) -> None:
    from graytrack.drivers.factory import virtual_rig_controller
    from graytrack.drivers.sim.frame_render import FrameRenderer

    try:
        rig, clock, link = pickle.loads(conn.recv_bytes())
        truth, controller = virtual_rig_controller(rig, clock, link)
        renderer = FrameRenderer(rig)
        controller.start()
    except Exception as exc:  # noqa: BLE001 - said to the parent, which raises it
        conn.send_bytes(pickle.dumps(("error", f"{type(exc).__name__}: {exc}")))
        return
    try:
        shape = (rig.n_rows, rig.n_pixels)
        conn.send_bytes(pickle.dumps(("ready", controller.path, shape)))
        while True:
            try:
                request = conn.recv_bytes()
            except (EOFError, OSError):
                return  # the daemon closed its end (or died): done
            seq, t_mid, exposure = _REQUEST.unpack_from(request)
            instants = np.frombuffer(request, "<f8", offset=_REQUEST.size)
            try:
                strip = renderer.render(truth.position(instants), t_mid, exposure)
                strip = np.ascontiguousarray(strip)
                reply = _REPLY.pack(seq, 0, strip.dtype.str.encode()) + strip.tobytes()
            except Exception as exc:  # noqa: BLE001 - one frame that cannot be rendered: the daemon says why
                reply = _REPLY.pack(seq, 1, b"|u1") + f"{type(exc).__name__}: {exc}".encode()
            try:
                conn.send_bytes(reply)
            except OSError:
                return
    finally:
        controller.stop()


def main(argv: list[str] | None = None) -> None:
    fd = int((argv if argv is not None else sys.argv[1:])[0])
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the daemon's terminal: the daemon stops us
    conn = Connection(fd)
    try:
        _serve(conn)
    finally:
        conn.close()


if __name__ == "__main__":
    main()
