"""A simulated PI GCS controller serving the real byte protocol on a pseudo-terminal.

The driver under test opens :attr:`SimGCSController.path` with pyserial exactly as it would open
``/dev/ttyUSB0``. That path is a symlink to the current pty's slave, which makes a USB adapter's
disappearance reproducible: :meth:`vanish` closes the pty and removes the link (reads and writes
on the driver's side fail with EIO, reopening fails with ENOENT), :meth:`reappear` creates a new
pty behind the same path. The axis state survives, as it does on a controller that stayed powered.

Received bytes are cut into text lines and single-character commands (``#5`` is the byte 05h,
sent without a line end) by :class:`~.gcs_protocol.CommandFramer`; the latter are logged in
:attr:`SimGCSController.received` as ``#5``.

Faults are queued with :meth:`inject` and consumed by the next command they match: line noise
before a reply, a reply cut short, a reply never sent, a reply sent late, or a command refused
with a given GCS error number.
"""

from __future__ import annotations

import os
import random
import select
import tempfile
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

from graytrack.drivers.stage import gcs_protocol as gcs
from graytrack.drivers.stage.axis_model import AxisModel, TrapezoidAxis
from graytrack.drivers.registry import stages
from graytrack.drivers.stage.sim_gcs import DEFAULT_IDN, SimGCSInterpreter

FaultKind = Literal["garbage", "partial", "drop", "slow", "error"]
RECEIVED_KEPT = 1000  # command lines kept for tests and logs; a daemon polls POS? for days


@dataclass
class Fault:
    """One injected fault, applied to the next command named ``command`` (any command if None).

    ``garbage`` writes ``payload`` (random noise if None) before the reply; ``partial`` sends the
    first half of the reply and nothing more; ``drop`` sends nothing; ``slow`` waits ``delay_s``
    before replying; ``error`` refuses the command with GCS error ``code``.
    """

    kind: FaultKind
    command: str | None = None
    delay_s: float = 0.0
    code: int = 555
    payload: bytes | None = None
    count: int = 1


@stages.register("sim", simulated=True)  # the virtual rig's controller, which GCSStage drives: drivers/factory.py
class SimGCSController:
    def __init__(
        self,
        model: AxisModel | None = None,
        path: str | os.PathLike[str] | None = None,
        axis: str = "1",
        idn: str = DEFAULT_IDN,
        reference_mm: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        seed: int = 0,
        keep_received: int = RECEIVED_KEPT,
    ) -> None:
        self.model = model if model is not None else TrapezoidAxis()
        self.interpreter = SimGCSInterpreter(self.model, clock, axis=axis, idn=idn, reference_mm=reference_mm)
        self._tmpdir: tempfile.TemporaryDirectory[str] | None = None
        if path is None:
            self._tmpdir = tempfile.TemporaryDirectory(prefix="simgcs-")
            path = Path(self._tmpdir.name) / "ttyGCS0"
        self.path = str(path)
        # The newest command lines, oldest first, for tests and logs. Bounded: the daemon's
        # grating poller sends hundreds of POS? a second, and an unbounded log grew ~1.4 GB a day.
        self.received: deque[str] = deque(maxlen=keep_received)
        self._rng = random.Random(seed)
        self._faults: list[Fault] = []
        self._lock = threading.Lock()  # guards the pty fds and the interpreter
        self._master: int | None = None
        self._slave: int | None = None
        self._generation = 0
        self._stopping = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread: threading.Thread | None = None

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> "SimGCSController":
        self.reappear()
        self._thread = threading.Thread(target=self._serve, name="sim-gcs", daemon=True)
        self._thread.start()
        return self

    @property
    def native_id(self) -> int | None:
        """The serving thread's kernel id (None before it runs): what a process that raises its
        camera's priority raises too, the serving thread taking the interpreter lock the camera needs."""
        return self._thread.native_id if self._thread is not None else None

    def stop(self) -> None:
        self._stopping.set()
        os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.vanish()
        os.close(self._wake_r)
        os.close(self._wake_w)
        if self._tmpdir is not None:
            self._tmpdir.cleanup()

    def __enter__(self) -> "SimGCSController":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def vanish(self) -> None:
        """The port disappears: pty closed, path removed."""
        with self._lock:
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            self._generation += 1
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
        os.write(self._wake_w, b"x")

    def reappear(self) -> None:
        """A new pty behind the same path (like a re-enumerated USB adapter)."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no CR/LF translation: bytes pass as written
            self._master, self._slave = master, slave
            self._generation += 1
            link = Path(self.path)
            link.unlink(missing_ok=True)
            link.symlink_to(os.ttyname(slave))
        os.write(self._wake_w, b"x")

    def inject(self, fault: Fault) -> None:
        with self._lock:
            self._faults.append(fault)

    # -- serving ---------------------------------------------------------------------------
    def _serve(self) -> None:
        framer = gcs.CommandFramer()
        while not self._stopping.is_set():
            with self._lock:
                master, generation = self._master, self._generation
            watched = [self._wake_r] + ([master] if master is not None else [])
            try:
                readable, _, _ = select.select(watched, [], [], 0.5)
            except (OSError, ValueError):
                continue
            if self._wake_r in readable:
                os.read(self._wake_r, 64)
            if master is None or master not in readable:
                continue
            data = self._read(master, generation)
            if data is None:
                framer.clear()
                continue
            for command in framer.feed(data):
                self._handle(command, generation)

    def _read(self, master: int, generation: int) -> bytes | None:
        with self._lock:
            if generation != self._generation:
                return None
            try:
                return os.read(master, 4096)
            except OSError:
                return None

    def _handle(self, command: str | int, generation: int) -> None:
        """A text line, or a single-character command (its control byte, logged as ``#5``)."""
        line = command if isinstance(command, str) else f"#{command}"
        with self._lock:
            self.received.append(line)
            fault = self._take_fault(line)
            if fault is not None and fault.kind == "error":
                self.interpreter.fail(fault.code)
                return
            if isinstance(command, str):
                reply = self.interpreter.execute(command)
            else:
                reply = self.interpreter.execute_single(command)
        if reply is None:
            return
        # latin-1: #7 answers the single byte B1h/B0h; everything else is ASCII
        data = b"".join(text.encode("latin-1") + gcs.CONTINUATION for text in reply[:-1])
        data += reply[-1].encode("latin-1") + gcs.LF
        if fault is not None:
            data = self._apply(fault, data)
        if data:
            self._write(data, generation)

    def _take_fault(self, line: str) -> Fault | None:
        name = line.split()[0] if line.split() else ""
        for fault in self._faults:
            if fault.command is None or fault.command == name:
                fault.count -= 1
                if fault.count <= 0:
                    self._faults.remove(fault)
                return fault
        return None

    def _apply(self, fault: Fault, data: bytes) -> bytes:
        if fault.kind == "drop":
            return b""
        if fault.kind == "partial":
            return data[: max(1, len(data) // 2)]
        if fault.kind == "slow":
            time.sleep(fault.delay_s)
            return data
        if fault.kind == "garbage":
            noise = fault.payload
            if noise is None:
                noise = bytes(self._rng.choice(b"\x00\x7f\xfe\xff#~=?!abc012") for _ in range(12))
            return noise + data
        return data

    def _write(self, data: bytes, generation: int) -> None:
        with self._lock:
            if generation != self._generation or self._master is None:
                return
            try:
                os.write(self._master, data)
            except OSError:
                pass
