"""The virtual rig in a process of its own: the stage's true motion, the simulated PI controller on
its pty, and the camera's exposures, out of the daemon's interpreter.

In one process the virtual rig costs the daemon what real hardware never does: per frame the stage's
true positions during the exposure and the frame's rendering (``FrameRenderer``), and per grating
poll the controller's command interpreter, all under the interpreter lock the frame thread and the
event loop need (py-spy at 1 kHz × 4 clients, 16 rows: about a third of the frame thread's samples).
Here they run in a child process, and the daemon talks to it as to hardware: the stage through the
controller's pty (the same :class:`GCSStage` as on the bench), the camera through a ``SOCK_SEQPACKET``
socket pair (one message per frame, no framing of our own).

The child is a free-running camera: once configured (:meth:`RigProcess.configure`: the frame clock's
origin, rate, exposure and lag budget, all on the rig's clock) it exposes slot after slot, rendering
each as its exposure ends and sending it at once; the socket's buffer is the camera's buffer pool (a
frame that finds it full is lost, as a real camera loses it, and shows as a gap in the slot numbers).
The daemon's frame thread makes one ``recv`` per frame and nothing else: a request/response per frame
(the first version) put two wake-ups in series per frame, the child's and the frame thread's, and on a
loaded 2-core machine the child's alone cost more than a frame period. A child that falls behind skips
the slots older than the lag budget, as :func:`backlog.first_slot` does for every driver.

Faithful to the in-process rig: the child receives the rig object itself (on its stdin, pickled, its
noise stream at the same state), builds the stage and the controller as
:func:`factory.virtual_rig_controller` does, and renders with :class:`FrameRenderer` (which falls back to
:meth:`VirtualRig.render` as it does in process): for a given seed, the frames a reader takes without a
gap are, draw for draw, those :class:`SimCamera` renders in process (tests/drivers/test_rig_process.py).
A slot skipped here is still exposed, and draws its noise, as on a real camera.

Lifecycle: :meth:`RigProcess.start` spawns ``python -m graytrack.drivers.sim.process``, hands it the
rig and waits for its pty; :meth:`stop` closes the socket (the child sees EOF, stops its controller and
exits) and kills it if it does not. A child that dies or hangs never takes the daemon with it:
:meth:`next_frame` raises :class:`RigProcessDied` naming the exit status (the camera driver reports it
as a camera error, the controller's pty closes and the stage reports its own fault), or
:class:`RigProcessTimeout` when no frame comes in time (a camera that stops delivering).
"""

from __future__ import annotations

import gc
import os
import math
import pickle
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
from typing import Any

import numpy as np

from graytrack.drivers.realtime import spare_cores

START_TIMEOUT_S = 60.0  # the child imports numpy and the rig (seconds on a loaded machine)
STOP_TIMEOUT_S = 2.0
SWITCH_INTERVAL_S = 0.0005  # the child's interpreter lock handed over within half a frame at 1 kHz
MAX_MESSAGE = 1 << 22  # bytes of one frame at most (a 16-row strip of 100 float32 pixels: 6.4 kB)
# the frame clock: epoch, origin, rate, exposure, lag budget (rig clock), SCHED_FIFO level of the child (0: normal)
_CONFIG = struct.Struct("!qddddi")
# a frame: epoch, slot, 0 = pixels follow / 1 = an error message follows, pixel dtype
_FRAME = struct.Struct("!qqB3s")


class RigProcessError(RuntimeError):
    """The rig process could not be started or used."""


class RigProcessDied(RigProcessError):
    """The rig process has ended (its exit status in the message)."""


class RigProcessTimeout(RigProcessError, TimeoutError):
    """No frame came back from the rig process in time."""


class RigProcess:
    """The parent's side: ``start``, ``configure`` the frame clock, take frames (``next_frame``), ``stop``.
    ``path`` is the controller's pty."""

    def __init__(self, rig: Any, clock: Any, link: str | None = None) -> None:
        self.rig = rig
        self.clock = clock
        self.link = link
        self.path: str | None = None
        self.process: subprocess.Popen[bytes] | None = None
        self._sock: socket.socket | None = None
        self._shape: tuple[int, ...] = ()
        self._epoch = 0
        self._lock = threading.Lock()

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "RigProcess":
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            # the daemon pinned to cores of its own: this process stands in for separate hardware, beside it
            cores = ",".join(map(str, sorted(spare_cores())))
            self.process = subprocess.Popen(
                [sys.executable, "-m", "graytrack.drivers.sim.process", str(theirs.fileno()), cores],
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
                raise RigProcessTimeout(
                    f"the virtual rig's process did not start within {START_TIMEOUT_S:g} s") from None
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
            try:
                sock.shutdown(socket.SHUT_RDWR)  # EOF for the child, and a reader blocked on it wakes now
            except OSError:
                pass
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
    def configure(self, t0_s: float, frame_rate_hz: float, exposure_s: float, max_lag_s: float,
                  priority: int = 0) -> None:
        """Start (or restart) the child's frame clock: slot k is exposed over ``t0_s + k / frame_rate_hz``
        + [0, exposure_s] (rig clock); frames of an earlier configuration are never handed out after
        this. ``priority``: the child's rendering thread's SCHED_FIFO level (the daemon's frame loop's)."""
        with self._lock:
            sock = self._sock
            if sock is None:
                raise RigProcessDied(self.describe() or "the virtual rig's process is not running")
            self._epoch += 1
            try:
                sock.send(_CONFIG.pack(self._epoch, t0_s, frame_rate_hz, exposure_s, max_lag_s, priority))
            except OSError as exc:
                raise RigProcessDied(f"the virtual rig's process {self._death()}") from exc

    def next_frame(self, timeout_s: float, wait: bool = True) -> tuple[int, np.ndarray] | None:
        """The oldest frame not handed out yet, as (slot, strip ``(R, n)``), waiting up to ``timeout_s``
        (host seconds) for one; with ``wait`` False, None when none is there now. Raises
        :class:`RigProcessDied` or :class:`RigProcessTimeout`."""
        with self._lock:
            sock = self._sock
            if sock is None:
                raise RigProcessDied(self.describe() or "the virtual rig's process is not running")
            if wait:  # the timeout in the kernel (SO_RCVTIMEO): the wait stays one recv, no poll before it
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _timeval(timeout_s))
            try:
                while True:
                    try:
                        reply = sock.recv(MAX_MESSAGE, 0 if wait else socket.MSG_DONTWAIT)
                    except BlockingIOError:
                        if not wait:
                            return None
                        raise RigProcessTimeout(
                            f"no frame from the virtual rig's process within {timeout_s:.3g} s") from None
                    if not reply:
                        raise EOFError
                    epoch, slot, status, dtype = _FRAME.unpack_from(reply)
                    if epoch == self._epoch:
                        break  # frames of an earlier configuration: skipped
            except RigProcessTimeout:  # a TimeoutError, hence an OSError: not a death
                raise
            except (EOFError, OSError) as exc:
                raise RigProcessDied(f"the virtual rig's process {self._death()}") from exc
            if status:
                raise RigProcessError(f"the virtual rig's process could not render slot {slot}: "
                                      f"{reply[_FRAME.size:].decode(errors='replace')}")
            # a copy: writable, and owned by the frame (the message's bytes are not)
            return slot, np.frombuffer(reply, np.dtype(dtype.decode()), offset=_FRAME.size).reshape(self._shape).copy()


def _timeval(seconds: float) -> bytes:
    whole = int(max(seconds, 1e-3))
    return struct.pack("@ll", whole, int((max(seconds, 1e-3) - whole) * 1e6))


# -- the child ---------------------------------------------------------------------------------
def _serve(sock: socket.socket) -> None:
    from graytrack.drivers.camera.backlog import first_slot
    from graytrack.drivers.factory import virtual_rig_controller
    from graytrack.drivers.realtime import raise_thread_priority
    from graytrack.drivers.sim.frame_render import FrameRenderer

    try:
        rig, clock, link = pickle.load(sys.stdin.buffer)
        truth, controller = virtual_rig_controller(rig, clock, link)
        renderer = FrameRenderer(rig)
        controller.start()
    except Exception as exc:  # noqa: BLE001 - said to the parent, which raises it
        sock.send(pickle.dumps(("error", f"{type(exc).__name__}: {exc}")))
        return
    # Two threads share this interpreter (the exposures here, the controller's): a thread wanting the
    # lock waits up to the switch interval, 5 ms by default, five frame periods at 1 kHz. The heap
    # built so far lives as long as the process: full collections need not walk it (service/heap.py).
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    gc.freeze()
    try:
        sock.send(pickle.dumps(("ready", controller.path, (rig.n_rows, rig.n_pixels))))
        config: tuple[int, float, float, float, float, int] | None = None
        last = -1
        while True:
            wait: float | None = None  # unconfigured: nothing to expose, wait for the daemon
            slot = 0
            if config is not None:
                epoch, t0, rate, exposure, max_lag, _ = config
                now = clock.now()
                newest = math.floor((now - t0 - exposure) * rate)  # the newest slot whose exposure has ended
                if newest > last:
                    slot, wait = first_slot(newest, last + 1, max_lag, 1.0 / rate), 0.0
                else:
                    slot, wait = last + 1, max(0.0, clock.duration_to_host(t0 + exposure + (last + 1) / rate - now))
            if select.select([sock], [], [], wait)[0]:  # a new configuration, or the daemon gone
                try:
                    message = sock.recv(MAX_MESSAGE)
                except OSError:
                    return
                if not message:
                    return  # the daemon closed its end (or died): done
                config, last = _CONFIG.unpack(message), -1
                raise_thread_priority(config[5], "virtual rig's camera")
                # the controller's thread takes the interpreter lock the exposures need: at normal
                # priority, preempted while holding it, it held a raised camera 4–6 ms (an inversion)
                raise_thread_priority(config[5], "virtual rig's controller", controller.native_id or 0)
                continue
            if config is None or wait:
                continue  # woken early: look at the clock again
            t_mid = t0 + 0.5 * exposure + slot / rate
            half = 0.5 * exposure
            instants = np.array([t_mid - half, t_mid, t_mid + half]) if half > 0 else np.array([t_mid])
            try:
                strip = np.ascontiguousarray(renderer.render(truth.position(instants), t_mid, exposure))
                frame = _FRAME.pack(epoch, slot, 0, strip.dtype.str.encode()) + strip.tobytes()
            except Exception as exc:  # noqa: BLE001 - a frame that cannot be rendered: the daemon says why
                frame = _FRAME.pack(epoch, slot, 1, b"|u1") + f"{type(exc).__name__}: {exc}".encode()
            last = slot
            try:
                sock.send(frame, socket.MSG_DONTWAIT)
            except BlockingIOError:
                pass  # the daemon's buffer pool is full: this frame is lost, as on a camera
            except OSError:
                return
    finally:
        controller.stop()


def main(argv: list[str] | None = None) -> None:
    """``process.py FD [CORES]``: serve the rig on the socket FD; CORES (``"2,3"``): the cores to run
    on, set before anything starts a thread (the daemon's spare ones when it is pinned)."""
    args = argv if argv is not None else sys.argv[1:]
    fd = int(args[0])
    if len(args) > 1 and args[1]:
        os.sched_setaffinity(0, {int(core) for core in args[1].split(",")})
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the daemon's terminal: the daemon stops us
    sock = socket.socket(fileno=fd)
    try:
        _serve(sock)
    finally:
        sock.close()


if __name__ == "__main__":
    main()
