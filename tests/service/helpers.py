"""Daemon test helpers: fast settings on the virtual rig, waiting on state, a camera that can fail."""

from __future__ import annotations

import dataclasses
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import httpx
from fastapi.testclient import TestClient

from graytrack.drivers.camera.base import Camera, CameraError, CameraTimeout, Frame
from graytrack.drivers.clock import ScaledClock
from graytrack.drivers.factory import Hardware, open_hardware
from graytrack.service.daemon.settings import Settings, parse_settings

# The sim clock runs 10x wall time: a 21-stop sweep with real moves and settles takes well under a second.
FAST_TABLES: dict[str, Any] = {
    # a long serial timeout: a loaded CI machine can starve the simulated controller's thread
    "stage": {"kind": "sim", "velocity_mm_s": 20.0, "timeout_s": 5.0},
    # 20 simulated frames/s = 200 per wall second: enough to test, light enough for a loaded CI machine
    "camera": {"kind": "sim", "frame_rate_hz": 20.0},
    # step and settle, paper model: the quickest calibration (the scan and the closed loop: test_sweep_scan.py)
    "sweep": {"kind": "stops", "positions": 21, "frames_per_position": 3, "model": "paper"},
    # the page's tests reach the daemon as "testserver" (TestClient's Host)
    # fault and staleness thresholds a loaded CI machine does not cross by itself
    # normal scheduling: the suite's daemons share 2 cores with the test processes (one test checks realtime)
    "daemon": {"realtime_priority": 0, "sim_clock_scale": 10.0, "camera_fault_after_s": 1.0, "stale_after_s": 1.0, "reopen_interval_s": 0.1,
               "allowed_hosts": ["testserver"]},
}


def fast_settings(data_dir: Path, tables: dict[str, dict[str, Any]] | None = None, **daemon: Any) -> Settings:
    """FAST_TABLES with ``data_dir``, ``daemon`` keys and whole-table ``tables`` updates."""
    merged = {name: {**table, **(tables or {}).get(name, {})} for name, table in FAST_TABLES.items()}
    merged["daemon"].update(data_dir=str(data_dir), **daemon)
    return parse_settings(merged)


def wait_for(predicate: Callable[[], Any], timeout_s: float = 10.0, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")


def _state_waiter(read: Callable[[], dict[str, Any] | None], state: str, timeout_s: float,
                  what: str) -> dict[str, Any]:
    """Wait for ``state``; on a timeout the message says where the daemon was instead (its state,
    reason, faults and calibration progress), not only that time ran out."""
    seen: list[dict[str, Any] | None] = [None]

    def check() -> dict[str, Any] | None:
        status = seen[0] = read()
        return status if status is not None and status["state"] == state else None

    try:
        return wait_for(check, timeout_s, what)
    except AssertionError as timeout:
        last = seen[0] or {}
        where = {key: last.get(key) for key in ("state", "reason", "faults", "calibration", "model_stale") if key in last}
        raise AssertionError(f"{timeout}; last seen: {where or 'no answer'}") from None


def wait_state(client: TestClient, state: str, timeout_s: float = 10.0) -> dict[str, Any]:
    return _state_waiter(lambda: client.get("/api/status").json(), state, timeout_s, f"state {state!r}")


class GatedCamera(Camera):
    """Wraps a camera: ``gate_open = False`` starves the reader, ``fail_reads = n`` raises n errors."""

    def __init__(self, inner: Camera) -> None:
        super().__init__(inner.settings)
        self.inner = inner
        self.gate_open = True
        self.fail_reads = 0
        self.narrow_by = 0
        self.opens = 0

    @property
    def exposure_s(self) -> float:
        return getattr(self.inner, "exposure_s", 0.0)

    def _open_device(self) -> None:
        self.inner.open()
        self.opens += 1

    def _close_device(self) -> None:
        self.inner.close()

    def _apply_settings(self) -> None:
        pass

    def _read(self, timeout_s: float) -> Frame:
        if self.narrow_by:  # as after an ROI change on the camera: frames of another width
            frame = self.inner.read(timeout_s)
            return dataclasses.replace(frame, pixels=frame.pixels[..., : -self.narrow_by])
        if self.fail_reads > 0:
            self.fail_reads -= 1
            raise CameraError("simulated camera fault (cable pulled)")
        if not self.gate_open:
            time.sleep(timeout_s)
            raise CameraTimeout("gated")
        return self.inner.read(timeout_s)


class GatedFactory:
    """A hardware factory that wraps the camera in :class:`GatedCamera` and keeps the hardware;
    while ``plugged`` is False opening fails as with an unplugged USB adapter."""

    def __init__(self, plugged: bool = True) -> None:
        self.plugged = plugged
        self.attempts = 0
        self.hardware: Hardware | None = None

    def __call__(self, settings: Settings, clock: ScaledClock) -> Hardware:
        self.attempts += 1
        if not self.plugged:
            raise OSError("no such device: /dev/serial/by-id/usb-PI (unplugged)")
        hardware = open_hardware(settings.hardware, clock)
        hardware.camera = GatedCamera(hardware.camera)
        hardware.camera.open()
        self.hardware = hardware
        return hardware


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_config(folder: Path, **changes: dict[str, Any]) -> Path:
    """The fast test rig (FAST_TABLES, updated by ``changes``) as a TOML file, data directory inside ``folder``."""
    lines = []
    for name, table in FAST_TABLES.items():
        lines.append(f"[{name}]")
        lines += [f"{key} = {json.dumps(value)}" for key, value in {**table, **changes.get(name, {})}.items()]
    lines.append(f"data_dir = {json.dumps(str(folder / 'data'))}")  # ends up in [daemon], the last table
    assert list(FAST_TABLES)[-1] == "daemon"
    config = folder / "graytrack.toml"
    config.write_text("\n".join(lines) + "\n")
    return config


class ServeProcess:
    """``python -m graytrack serve`` on a free loopback port; SIGTERM on exit, stderr kept."""

    def __init__(self, folder: Path, **tables: dict[str, Any]) -> None:
        self.folder = folder
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.stderr = ""
        self.config = write_config(folder, **tables)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "graytrack", "serve", "--config", str(self.config), "--port", str(self.port)],
            stderr=subprocess.PIPE, text=True)

    def status(self) -> dict[str, Any] | None:
        try:
            return httpx.get(f"{self.base}/api/status", timeout=2.0).json()
        except httpx.TransportError:
            return None

    def wait_state(self, state: str, timeout_s: float = 30.0) -> dict[str, Any]:
        return _state_waiter(self.status, state, timeout_s, f"the daemon to reach {state!r}")

    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {(self.folder / 'data' / 'token').read_text().strip()}"}

    def terminate(self) -> int:
        self.process.send_signal(signal.SIGTERM)
        try:
            _, self.stderr = self.process.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            self.process.kill()
            _, self.stderr = self.process.communicate()
        return self.process.returncode

    def __enter__(self) -> "ServeProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.process.returncode is None:
            self.terminate()


class LiveServer:
    """The app on a real uvicorn server in this process (loopback, free port), so a test can inject
    faults into the running rig (monkeypatch, gated hardware) and still talk HTTP/WebSocket to it."""

    def __init__(self, app: Any) -> None:
        import threading

        import uvicorn

        self.app = app
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning", **app.state.server_options)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)

    @property
    def rig(self) -> Any:
        return self.app.state.rig

    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.app.state.policy.token}"}

    def get(self, path: str, **kwargs: Any) -> httpx.Response:
        return httpx.get(self.base + path, timeout=5.0, **kwargs)

    def post(self, path: str, **kwargs: Any) -> httpx.Response:
        return httpx.post(self.base + path, timeout=5.0, **kwargs)

    def status(self) -> dict[str, Any]:
        return self.get("/api/status").json()

    def wait_state(self, state: str, timeout_s: float = 20.0) -> dict[str, Any]:
        return _state_waiter(self.status, state, timeout_s, f"state {state!r}")

    def __enter__(self) -> "LiveServer":
        self.thread.start()
        wait_for(lambda: self.server.started, 10.0, "uvicorn to start")
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=20.0)
