"""PI's own Python library against ``graytrack sim-controller``, run as a real process on a real pty.

PIPython is what a lab's control system uses to drive the controller; whatever it sends must be
answered as a real C-863 answers it. Without PI's shared library (not on Linux CI), PIPython's
documented way to an RS-232 port is its ``PISerial`` gateway, connected with ``ConnectRS232``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pipython import GCSDevice, GCSError, gcserror, pitools
from pipython.pidevice.interfaces.piserial import PISerial

from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.stage.sim_gcs import DEFAULT_STAGE, MAX_VELOCITY_MM_S

BAUD = 115200
AXIS = "1"
START_S = 20.0  # the process is up in about a second; generous for a loaded machine
TIMEOUT_MS = 3000  # PIPython's reply timeout for normal traffic (its default is 7 s)
REFUSED_QUERY_TIMEOUT_MS = 300  # a refused query gets no reply at all: wait only this long for it


@dataclass
class Served:
    process: subprocess.Popen[str]
    link: Path
    banner: str


def _start(link: Path) -> Served:
    process = subprocess.Popen([sys.executable, "-m", "graytrack", "sim-controller", "--link", str(link),
                                "--baud", str(BAUD)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.append(process.stdout.readline()), daemon=True)  # type: ignore[union-attr]
    reader.start()
    reader.join(START_S)
    if not lines or not lines[0]:
        process.kill()
        _, err = process.communicate()
        pytest.fail(f"sim-controller printed nothing within {START_S} s: {err}")
    return Served(process, link, lines[0])


def _stop(served: Served, sig: int = signal.SIGTERM) -> tuple[int, str]:
    if served.process.poll() is None:
        served.process.send_signal(sig)
    try:
        out, _ = served.process.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        served.process.kill()
        raise
    return served.process.returncode, out


@contextlib.contextmanager
def _running(link: Path) -> Iterator[Served]:
    served = _start(link)
    try:
        yield served
    finally:
        _stop(served)


@contextlib.contextmanager
def _connected(served: Served) -> Iterator[GCSDevice]:
    gateway = PISerial(str(served.link), BAUD, autoconnect=False)
    with GCSDevice(gateway=gateway) as device:
        gateway.ConnectRS232(port=str(served.link), baudrate=BAUD)
        device.timeout = TIMEOUT_MS
        yield device


@pytest.fixture(scope="module")
def _shared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """One controller process for the module's tests that leave its axis as they found it (no servo, reference,
    stage name or motion of their own): each connects afresh and leaves the error register cleared."""
    with _running(tmp_path_factory.mktemp("pi") / "ttyPI") as served:
        yield served


@pytest.fixture
def served(_shared: Served) -> Served:
    assert _shared.process.poll() is None, "the module's controller process exited"
    return _shared


@pytest.fixture
def pidevice(served: Served) -> Iterator[GCSDevice]:
    with _connected(served) as device:
        yield device
        device.errcheck, device.timeout = False, TIMEOUT_MS
        device.qERR()  # read back: the next test's connection starts with an empty register


@pytest.fixture
def fresh_pidevice(tmp_path: Path) -> Iterator[GCSDevice]:
    """A controller process of the test's own, as at power-on: no servo, unreferenced, where the rig put its axis."""
    with _running(tmp_path / "ttyPI") as served, _connected(served) as device:
        yield device


def _wait_on_target(device: GCSDevice, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not device.qONT(AXIS)[AXIS]:
        assert time.monotonic() < deadline, f"not on target within {timeout_s} s"
        time.sleep(0.02)


def test_the_banner_names_the_pty_and_the_link(served: Served) -> None:
    assert served.link.is_symlink() and os.readlink(served.link).startswith("/dev/pts/")
    assert os.readlink(served.link) in served.banner and str(served.link) in served.banner
    assert f"{BAUD} baud" in served.banner


def test_identification_and_what_the_controller_says_about_itself(pidevice: GCSDevice) -> None:
    assert type(pidevice.gcsdevice).__name__ == "GCS2Device", "CSV? says GCS 2.0"
    assert "Physik Instrumente" in pidevice.qIDN() and "C-863" in pidevice.qIDN()
    assert pidevice.qCSV() == 2.0
    assert pidevice.qSAI() == [AXIS] and pidevice.qSAI_ALL() == [AXIS]
    assert pidevice.qCST() == {AXIS: DEFAULT_STAGE}
    assert pidevice.qLIM() == {AXIS: True} and pidevice.qTRS() == {AXIS: True}
    version = pidevice.qVER()
    assert version.startswith("FW_ARM: V01.001") and "graytrack" in version
    low, high = build_rig("paper").config.stage.soft_limits_mm  # the daemon's virtual rig
    assert pidevice.qTMN() == {AXIS: low} and pidevice.qTMX() == {AXIS: high}
    assert pidevice.qERR() == 0


def test_parameters_listed_by_hpa_are_read_with_their_types(pidevice: GCSDevice) -> None:
    listing = pidevice.qHPA()
    assert listing.splitlines()[0].startswith("The following parameters") and listing.endswith("end of help\n")
    assert "0xA=\t0\t1\tFLOAT" in listing
    # qSPA converts values with the types qHPA announced: the whole chain has to parse
    assert pidevice.qSPA(AXIS, 0xA) == {AXIS: {0xA: MAX_VELOCITY_MM_S}}
    assert pidevice.qSPA(AXIS, 0x3C) == {AXIS: {0x3C: DEFAULT_STAGE}}
    assert pidevice.HasqHPA() and pidevice.HasIsMoving() and pidevice.HasStopAll()


def test_servo_reference_move_and_position(fresh_pidevice: GCSDevice) -> None:
    fresh_pidevice.SVO(AXIS, True)
    assert fresh_pidevice.qSVO() == {AXIS: True}
    fresh_pidevice.FRF(AXIS)
    assert fresh_pidevice.qFRF(AXIS) == {AXIS: True}
    start = fresh_pidevice.qPOS(AXIS)[AXIS]
    target = start + 4.0  # 0.8 s at the rig's 5 mm/s
    fresh_pidevice.MOV(AXIS, target)
    assert fresh_pidevice.qMOV(AXIS) == {AXIS: pytest.approx(target, abs=1e-9)}
    assert fresh_pidevice.IsMoving(AXIS) == {AXIS: True}
    _wait_on_target(fresh_pidevice)
    assert fresh_pidevice.IsMoving() == {AXIS: False}
    # POS? is the rig's grating: 0.5 µm steps, settled within the 0.5 µm on-target window
    assert fresh_pidevice.qPOS(AXIS)[AXIS] == pytest.approx(target, abs=1.5e-3)
    assert fresh_pidevice.qERR() == 0


def test_single_character_commands_answer_and_leave_the_next_line_intact(pidevice: GCSDevice) -> None:
    idn = pidevice.qIDN()
    assert pidevice.IsControllerReady() is True
    assert pidevice.qIDN() == idn, "#7 (no line end) did not merge into the next command"
    assert pidevice.IsMoving() == {AXIS: False}
    assert pidevice.qIDN() == idn
    with pytest.raises(GCSError) as stopped:
        pidevice.StopAll()  # #24 leaves error 10, which PIPython reads back with ERR?
    assert stopped.value.val == gcserror.E10_PI_CNTR_STOP
    assert pidevice.qIDN() == idn and pidevice.qERR() == 0


def test_stop_all_interrupts_a_move(fresh_pidevice: GCSDevice) -> None:
    fresh_pidevice.SVO(AXIS, True)
    fresh_pidevice.FRF(AXIS)
    start = fresh_pidevice.qPOS(AXIS)[AXIS]
    target = fresh_pidevice.qTMX(AXIS)[AXIS] - 1.0  # 5 s at the rig's 5 mm/s from its stroke start
    fresh_pidevice.MOV(AXIS, target)
    time.sleep(0.2)
    fresh_pidevice.StopAll(noraise=True)
    deadline = time.monotonic() + 5.0
    while fresh_pidevice.IsMoving()[AXIS]:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    stopped_at = fresh_pidevice.qPOS(AXIS)[AXIS]
    assert start < stopped_at < target - 5.0
    assert fresh_pidevice.qERR() == 0


@pytest.mark.parametrize("stages", [DEFAULT_STAGE, "OTHER-STAGE"])
def test_pitools_startup_references_and_switches_the_servo_on(fresh_pidevice: GCSDevice, stages: str) -> None:
    """The fresh controller is unreferenced with the servo off: FRF is refused (5), PIPython switches the
    servo on and retries, waits with #7 and FRF?, then sets the servo; another stage name goes out as CST."""
    assert fresh_pidevice.qFRF(AXIS) == {AXIS: False} and fresh_pidevice.qSVO(AXIS) == {AXIS: False}
    pitools.startup(fresh_pidevice, stages=stages, refmodes="FRF")
    assert fresh_pidevice.qFRF(AXIS) == {AXIS: True} and fresh_pidevice.qSVO(AXIS) == {AXIS: True}
    assert fresh_pidevice.qCST() == {AXIS: stages}
    assert fresh_pidevice.qERR() == 0
    pitools.moveandwait(fresh_pidevice, AXIS, 3.0)
    assert fresh_pidevice.qPOS(AXIS)[AXIS] == pytest.approx(3.0, abs=1.5e-3)


def test_an_unknown_command_sets_error_2_and_the_next_command_works(pidevice: GCSDevice) -> None:
    with pytest.raises(GCSError) as unknown:
        pidevice.send("XYZ 1 2")  # PIPython asks ERR? after every command
    assert unknown.value.val == gcserror.E2_PI_CNTR_UNKNOWN_COMMAND
    assert "C-863" in pidevice.qIDN()
    pidevice.errcheck = False
    pidevice.send("XYZ")
    assert pidevice.qERR() == gcserror.E2_PI_CNTR_UNKNOWN_COMMAND
    assert pidevice.qERR() == 0, "ERR? clears the register"
    pidevice.errcheck = True
    assert pidevice.qSAI() == [AXIS]


def test_a_refused_query_gets_no_reply_and_its_error_waits_in_the_register(pidevice: GCSDevice) -> None:
    """As on a real controller: ``POS? 1 2`` names an axis it does not have, so no answer comes
    (PIPython times out) and ERR? then says 15; the following command is answered normally."""
    pidevice.timeout = REFUSED_QUERY_TIMEOUT_MS
    with pytest.raises(GCSError) as silent:
        pidevice.qPOS([AXIS, "2"])
    assert silent.value.val == gcserror.E_7_COM_TIMEOUT
    pidevice.timeout = TIMEOUT_MS
    assert pidevice.qERR() == gcserror.E15_PI_CNTR_INVALID_AXIS_IDENTIFIER
    assert AXIS in pidevice.qPOS(AXIS)
    assert pidevice.qERR() == 0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_removes_the_link_and_exits_0(tmp_path: Path, sig: int) -> None:
    served = _start(tmp_path / "ttyPI")
    assert served.link.is_symlink()
    code, out = _stop(served, sig)
    assert code == 0
    assert not served.link.is_symlink() and not served.link.exists()
    assert f"stopped by {signal.Signals(sig).name}" in out


def test_an_existing_file_at_the_link_path_is_never_replaced(tmp_path: Path) -> None:
    precious = tmp_path / "ttyUSB0"
    precious.write_text("keep me")
    run = subprocess.run([sys.executable, "-m", "graytrack", "sim-controller", "--link", str(precious)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and precious.read_text() == "keep me"
    assert run.stderr.count("\n") == 1 and "already exists" in run.stderr
    missing = subprocess.run([sys.executable, "-m", "graytrack", "sim-controller", "--link",
                              str(tmp_path / "nowhere" / "tty")], capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "does not exist" in missing.stderr
