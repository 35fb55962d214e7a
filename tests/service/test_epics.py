"""``graytrack epics`` as a process between a real daemon (``graytrack serve``) and caproto's client.

Every server and client here speaks Channel Access on loopback only, on ports of its own
(search, beacons), so parallel runs never collide and nothing is broadcast.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from caproto import AlarmSeverity, AlarmStatus, ErrorResponseReceived
from caproto.sync.client import read, write

from tests.service.helpers import ServeProcess, free_port, wait_for

TIMEOUT_S = 2.0


@dataclass
class Bridge:
    """A running ``graytrack epics`` and the CA environment its clients need."""

    prefix: str
    process: subprocess.Popen[str]

    def read(self, name: str) -> Any:
        return read(self.prefix + name, data_type="time", timeout=TIMEOUT_S, repeater=False)

    def value(self, name: str) -> Any:
        data = self.read(name).data
        return data[0]

    def write(self, name: str, value: Any) -> Any:
        return write(self.prefix + name, value, notify=True, timeout=TIMEOUT_S, repeater=False)


@contextmanager
def ca_ports() -> Iterator[None]:
    """Loopback-only Channel Access on free ports of its own, for a bridge started inside and for this
    process's client; a UDP socket takes the bridge's beacons (a repeater's job). One bridge per
    port: two servers on one search port would each hide the other's PVs."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as beacons, pytest.MonkeyPatch.context() as mp:
        beacons.bind(("127.0.0.1", 0))
        port = str(free_port())
        env = {"EPICS_CA_SERVER_PORT": port, "EPICS_CAS_SERVER_PORT": port, "EPICS_CA_ADDR_LIST": "127.0.0.1",
               "EPICS_CA_AUTO_ADDR_LIST": "NO", "EPICS_CAS_INTF_ADDR_LIST": "127.0.0.1",
               "EPICS_CAS_BEACON_ADDR_LIST": "127.0.0.1", "EPICS_CAS_AUTO_BEACON_ADDR_LIST": "NO",
               "EPICS_CAS_BEACON_PORT": str(beacons.getsockname()[1])}
        for key, value in env.items():
            mp.setenv(key, value)
        yield


def start_bridge(url: str, *token: str) -> Bridge:
    prefix = f"TEST{uuid.uuid4().hex[:8]}:"
    process = subprocess.Popen([sys.executable, "-m", "graytrack", "epics", "--url", url, "--prefix", prefix, *token],
                               stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    bridge = Bridge(prefix, process)

    def serving() -> bool:
        assert process.poll() is None, f"graytrack epics exited: {process.communicate()[1]}"
        try:
            return bridge.read("STATE").metadata.severity != AlarmSeverity.INVALID_ALARM
        except (TimeoutError, OSError):
            return False

    wait_for(serving, 20.0, "the bridge to serve STATE from the daemon")
    return bridge


def stop_bridge(bridge: Bridge) -> str:
    bridge.process.terminate()
    _, stderr = bridge.process.communicate(timeout=10)
    assert bridge.process.returncode == 0, stderr
    return stderr


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Iterator[ServeProcess]:
    folder = tmp_path_factory.mktemp("epics")
    calibrated(folder / "data")  # tracking from its start: the bridge is the test, not the first calibration
    with ServeProcess(folder) as process:
        process.wait_state("tracking", 40.0)
        yield process


@pytest.fixture(scope="module")
def bridge(daemon: ServeProcess) -> Iterator[Bridge]:
    with ca_ports():
        running = start_bridge(daemon.base, "--data-dir", str(daemon.folder / "data"))
        yield running
        assert "Traceback" not in stop_bridge(running)


def refusal(exc: ErrorResponseReceived) -> str:
    """The sentence the bridge sent back with ECA_PUTFAIL."""
    response = exc.args[0]
    assert response.status.name == "ECA_PUTFAIL"
    return bytes(response.error_message).decode().rstrip("\x00")


def status(daemon: ServeProcess) -> dict[str, Any]:
    answer = daemon.status()
    assert answer is not None
    return answer


def test_the_pvs_follow_the_stream_and_the_status(bridge: Bridge, daemon: ServeProcess) -> None:
    wait_for(lambda: status(daemon)["state"] == "tracking" and not status(daemon)["moving"], 20.0, "a resting stage")
    before = status(daemon)["position_mm"]
    first = bridge.read("X_MM")
    after = status(daemon)["position_mm"]
    x = first.data[0]
    # a steady rig at rest is measured, not flagged (the model's own stretch and focus at the resting place,
    # core/place_spread.py; the grating paired at rest only once a command's motion is seen, daemon/grating.py)
    assert first.metadata.severity == AlarmSeverity.NO_ALARM, (status(daemon)["stale_reason"], after)
    # the stage rests: X_MM is the daemon's position within a few bounds of noise (each ~2 µm)
    assert min(before, after) - 0.01 < x < max(before, after) + 0.01
    assert abs(first.metadata.timestamp - time.time()) < 2.0, "stamped with the frame's time, not old"
    # a live value: the next frames give other numbers (noise) with later timestamps
    later = wait_for(lambda: (r := bridge.read("X_MM")).data[0] != x and r, 5.0, "X_MM to change")
    assert later.metadata.timestamp > first.metadata.timestamp
    assert bridge.value("LOCKED") == 1 and bridge.value("STALE") == 0
    assert 0.0 < bridge.value("CRLB_UM") < 50.0
    assert bridge.value("STATE") == b"tracking"
    assert bridge.read("STATE").metadata.severity == AlarmSeverity.NO_ALARM
    assert bridge.value("CALIBRATE") == 0


def test_a_target_write_moves_the_stage(bridge: Bridge, daemon: ServeProcess) -> None:
    target = 6.25 if abs(status(daemon)["position_mm"] - 6.25) > 1.0 else 3.5
    bridge.write("TARGET_MM", target)
    wait_for(lambda: abs(bridge.value("X_MM") - target) < 0.005, 20.0, f"X_MM near {target}")
    assert status(daemon)["target_mm"] == pytest.approx(target)
    assert bridge.value("TARGET_MM") == pytest.approx(target)


def test_an_out_of_limits_target_fails_with_the_daemons_reason(bridge: Bridge, daemon: ServeProcess) -> None:
    target_before = status(daemon)["target_mm"]
    with pytest.raises(ErrorResponseReceived) as refused:
        bridge.write("TARGET_MM", 1000.0)
    assert "outside the soft limits" in refusal(refused.value)
    assert status(daemon)["target_mm"] == target_before, "the daemon was not asked to move"
    assert bridge.read("TARGET_MM").metadata.severity == AlarmSeverity.MAJOR_ALARM  # the last write failed


def test_a_calibrate_write_starts_a_calibration(bridge: Bridge, daemon: ServeProcess) -> None:
    with pytest.raises(ErrorResponseReceived) as refused:
        bridge.write("CALIBRATE", 2)
    assert "write 1 to start a calibration" in refusal(refused.value)
    before = httpx.get(f"{daemon.base}/api/calibration/latest").json()["id"]
    bridge.write("CALIBRATE", 1)
    wait_for(lambda: httpx.get(f"{daemon.base}/api/calibration/latest").json()["id"] != before, 5.0,
             "a new calibration")
    daemon.wait_state("tracking", 30.0)  # it ends installing its model; the next test starts from tracking


def test_without_a_token_writes_fail_and_a_dead_daemon_makes_every_pv_invalid(
        tmp_path: Path, calibrated) -> None:
    calibrated(tmp_path / "data")
    with ServeProcess(tmp_path) as daemon, ca_ports():
        daemon.wait_state("tracking", 40.0)
        bridge = start_bridge(daemon.base)
        try:
            with pytest.raises(ErrorResponseReceived) as refused:
                bridge.write("CALIBRATE", 1)
            assert "401" in refusal(refused.value)
            wait_for(lambda: bridge.read("X_MM").metadata.severity == AlarmSeverity.NO_ALARM, 10.0, "a valid X_MM")
            assert daemon.terminate() == 0
            killed = time.monotonic()
            names = ("X_MM", "CRLB_UM", "LOCKED", "STALE", "STATE", "TARGET_MM", "CALIBRATE")

            def all_invalid() -> bool:
                alarms = [bridge.read(name).metadata for name in names]
                return all(a.severity == AlarmSeverity.INVALID_ALARM and a.status == AlarmStatus.COMM
                           for a in alarms)

            wait_for(all_invalid, 5.0, "every PV INVALID/COMM")
            assert time.monotonic() - killed < 5.0
            assert bridge.value("STATE") == b"unreachable"
        finally:
            stderr = stop_bridge(bridge)
    assert "daemon unreachable" in stderr and "Traceback" not in stderr


def test_without_caproto_the_command_names_the_extra() -> None:
    blocked = ("import sys; sys.modules['caproto'] = None; from graytrack.service.cli import main; "
               "sys.exit(main(['epics', '--url', 'http://127.0.0.1:9', '--prefix', 'X']))")
    done = subprocess.run([sys.executable, "-c", blocked], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == "graytrack epics: error: caproto is not installed: pip install 'graytrack[epics]'"
