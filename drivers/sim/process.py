"""The virtual rig in a process of its own: the stage's true motion, the simulated PI controller on
its pty, and the camera's rendering, out of the daemon's interpreter.

In one process the virtual rig costs the daemon what real hardware never does: per frame the stage's
true positions during the exposure and the frame's rendering (``FrameRenderer``), and per grating
poll the controller's command interpreter, all under the interpreter lock the frame thread and the
event loop need (py-spy at 1 kHz × 4 clients, 16 rows: about a third of the frame thread's samples).
Here they run in a child process, and the daemon talks to it as to hardware: the stage through the
controller's pty (the same :class:`GCSStage` as on the bench), the camera through a socket pair
(:meth:`RigProcess.render`). Per frame, the frame thread makes one ``send`` and one blocking ``recv``
(a ``SOCK_SEQPACKET`` pair: one message per call, no framing of our own): the child waits for the
exposure's end on the rig's clock, renders, and sends the strip back as raw bytes. Each call that
lets go of the interpreter lock is a chance to wait for it again, behind the event loop; two is the
least a frame can cost.

Faithful to the in-process rig: the child receives the rig object itself (pickled, its noise stream
at the same state), builds the stage and the controller as :func:`factory.virtual_rig_controller`
does, and renders exactly the frames asked for, in order, with :class:`FrameRenderer` (which falls back
to :meth:`VirtualRig.render` as it does in process): for a given seed, the same frames
(tests/drivers/test_rig_process.py). The frame clock stays with the camera driver in the daemon.

Lifecycle: :meth:`RigProcess.start` spawns ``python -m graytrack.drivers.sim.process``, hands it the
rig on its stdin and waits for its pty; :meth:`stop` closes the socket (the child's request loop ends on EOF, it stops its controller
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
from typing import Any

import numpy as np

START_TIMEOUT_S = 60.0  # the child imports numpy and the rig (seconds on a loaded machine)
STOP_TIMEOUT_S = 2.0
MAX_MESSAGE = 1 << 22  # bytes of one frame's reply at most (a 16-row strip of 100 float32 pixels: 6.4 kB)
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
        self._sock: socket.socket | None = None
        self._shape: tuple[int, ...] = ()
        self._seq = 0
        self._lock = threading.Lock()

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "RigProcess":
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "graytrack.drivers.sim.process", str(theirs.fileno())],
                pass_fds=(theirs.fileno(),), stdin=subprocess.PIPE, close_fds=True)
        except OSError as exc:
            ours.close()
            raise RigProcessError(f"cannot start the virtual rig's process: {exc}") from exc
        finally:
            theirs.close()
        self._sock = ours
        try:
            assert self.process.stdin is not None
            with self.process.stdin:  # the rig itself, its noise stream's state included
                pickle.dump((self.rig, self.clock, self.link), self.process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            ours.settimeout(START_TIMEOUT_S)
            try:
                reply = ours.recv(MAX_MESSAGE)
            except TimeoutError:
                raise RigProcessTimeout(f"the virtual rig's process did not start within {START_TIMEOUT_S:g} s") from None
            ours.settimeout(None)
            if not reply:
                raise EOFError
            kind, *rest = pickle.loads(reply)
        except RigProcessError:
            self.stop()
            raise
        except (EOFError, OSError) as exc:
            self.stop()
            raise RigProcessDied(f"the virtual rig's process ended while starting: it {self._death()}") from exc
        if kind != "ready":
            self.stop()
            raise RigProcessError(f"the virtual rig's process could not start: {rest[0]}")
        self.path, self._shape = rest
        return self

    def stop(self) -> None:
        """End the child (EOF on its socket, then SIGKILL if it lingers); safe to call twice."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
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
        return self.process is not None and self.process.poll() is None and self._sock is not None

    def describe(self) -> str:
        """Why the process cannot render ('' while it runs)."""
        if self.process is None:
            return "the virtual rig's process was never started"
        if self._sock is None and self.process.poll() is None:
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
        """The strip ``(R, n)`` exposed around ``t_mid_s`` (simulated clock), handed over once the exposure
        has ended (the child waits for it), the stage's true positions taken in the child at ``instants``:
        what ``FrameRenderer.render(truth.position(instants), ...)`` gives in process. ``timeout_s``
        (host seconds) bounds the whole wait. Raises :class:`RigProcessDied` or :class:`RigProcessTimeout`."""
        with self._lock:
            sock = self._sock
            if sock is None:
                raise RigProcessDied(self.describe() or "the virtual rig's process is not running")
            self._seq += 1
            seq = self._seq
            request = _REQUEST.pack(seq, t_mid_s, exposure_s) + np.ascontiguousarray(instants, dtype="<f8").tobytes()
            # the timeout in the kernel (SO_RCVTIMEO): the recv stays one call, no poll before it
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(timeout_s))
            try:
                sock.send(request)
                while True:
                    try:
                        reply = sock.recv(MAX_MESSAGE)
                    except BlockingIOError:
                        raise RigProcessTimeout(
                            f"no frame from the virtual rig's process within {timeout_s:.3g} s") from None
                    if not reply:
                        raise EOFError
                    got, status, dtype = _REPLY.unpack_from(reply)
                    if got == seq:
                        break  # older replies: frames given up on after a timeout
            except RigProcessTimeout:  # a TimeoutError, hence an OSError: not a death
                raise
            except (EOFError, OSError) as exc:
                raise RigProcessDied(f"the virtual rig's process {self._death()}") from exc
            if status:
                raise RigProcessError(f"the virtual rig's process could not render: "
                                      f"{reply[_REPLY.size:].decode(errors='replace')}")
            # a copy: writable, and owned by the frame (the reply's bytes are not)
            return np.frombuffer(reply, np.dtype(dtype.decode()), offset=_REPLY.size).reshape(self._shape).copy()


def _timeval(seconds: float) -> bytes:
    whole = int(max(seconds, 1e-3))
    return struct.pack("@ll", whole, int((max(seconds, 1e-3) - whole) * 1e6))


# -- the child ---------------------------------------------------------------------------------
def _serve(sock: socket.socket) -> None:
    from graytrack.drivers.factory import virtual_rig_controller
    from graytrack.drivers.sim.frame_render import FrameRenderer

    try:
        rig, clock, link = pickle.load(sys.stdin.buffer)
        truth, controller = virtual_rig_controller(rig, clock, link)
        renderer = FrameRenderer(rig)
        controller.start()
    except Exception as exc:  # noqa: BLE001 - said to the parent, which raises it
        sock.send(pickle.dumps(("error", f"{type(exc).__name__}: {exc}")))
        return
    try:
        sock.send(pickle.dumps(("ready", controller.path, (rig.n_rows, rig.n_pixels))))
        while True:
            try:
                request = sock.recv(MAX_MESSAGE)
            except OSError:
                return
            if not request:
                return  # the daemon closed its end (or died): done
            seq, t_mid, exposure = _REQUEST.unpack_from(request)
            instants = np.frombuffer(request, "<f8", offset=_REQUEST.size)
            clock.sleep(t_mid + 0.5 * exposure - clock.now())  # a camera hands a frame over once it is exposed
            try:
                strip = np.ascontiguousarray(renderer.render(truth.position(instants), t_mid, exposure))
                reply = _REPLY.pack(seq, 0, strip.dtype.str.encode()) + strip.tobytes()
            except Exception as exc:  # noqa: BLE001 - one frame that cannot be rendered: the daemon says why
                reply = _REPLY.pack(seq, 1, b"|u1") + f"{type(exc).__name__}: {exc}".encode()
            try:
                sock.send(reply)
            except OSError:
                return
    finally:
        controller.stop()


def main(argv: list[str] | None = None) -> None:
    fd = int((argv if argv is not None else sys.argv[1:])[0])
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the daemon's terminal: the daemon stops us
    sock = socket.socket(fileno=fd)
    try:
        _serve(sock)
    finally:
        sock.close()


if __name__ == "__main__":
    main()
