"""Daemon test helpers: fast settings on the virtual rig, waiting on state, a camera that can fail."""

from __future__ import annotations

import dataclasses
import json
import logging
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
    # the virtual rig in the test process: tests reach into its controller and its stage
    # (test_rig_process.py runs it apart)
    "camera": {"kind": "sim", "frame_rate_hz": 20.0, "rig_process": False},
    # step and settle, paper model: the quickest calibration (the scan and the closed loop: test_sweep_scan.py)
    "sweep": {"kind": "stops", "positions": 21, "frames_per_position": 3, "model": "paper"},
    # the page's tests reach the daemon as "testserver" (TestClient's Host)
    # fault and staleness thresholds a loaded CI machine does not cross by itself
    # normal scheduling: the suite's daemons share 2 cores with the test processes (one test checks realtime)
    "daemon": {"realtime_priority": 0, "sim_clock_scale": 10.0, "camera_fault_after_s": 1.0, "stale_after_s": 1.0,
               "reopen_interval_s": 0.1,
               "allowed_hosts": ["testserver"]},
}


def fast_settings(data_dir: Path, tables: dict[str, dict[str, Any]] | None = None, **daemon: Any) -> Settings:
    """FAST_TABLES with ``data_dir``, ``daemon`` keys and whole-table ``tables`` updates."""
    merged = {name: {**table, **(tables or {}).get(name, {})} for name, table in FAST_TABLES.items()}
    merged["daemon"].update(data_dir=str(data_dir), **daemon)
    return parse_settings(merged)


LAST_SEEN_CHARS = 400  # of the last value a timed-out wait reports


def wait_for(predicate: Callable[[], Any], timeout_s: float = 10.0, what: str = "condition",
             show: Callable[[], Any] | None = None) -> Any:
    """The first truthy value of ``predicate()``, polled on the wall clock (a system test's wait: real
    threads and devices move at their own pace). On a timeout the message says what was seen last,
    ``show()`` when given (a predicate that returns a bare True/False says nothing), else the
    predicate's last value: a timeout on a loaded machine then shows where it was stuck."""
    deadline = time.monotonic() + timeout_s
    value: Any = None
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    seen = show() if show is not None else value
    text = repr(seen)
    if len(text) > LAST_SEEN_CHARS:
        text = text[:LAST_SEEN_CHARS] + "…"
    raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}; last seen: {text}")


def _document_waiter(read: Callable[[], dict[str, Any] | None], accept: Callable[[dict[str, Any]], bool],
                     keys: tuple[str, ...], timeout_s: float, what: str) -> dict[str, Any]:
    """Wait until ``accept(read())``; on a timeout the message gives ``keys`` of the last document read
    (where the daemon or the job was instead), not only that time ran out."""
    seen: list[dict[str, Any] | None] = [None]

    def check() -> dict[str, Any] | None:
        document = seen[0] = read()
        return document if document is not None and accept(document) else None

    def where() -> Any:
        last = seen[0] or {}
        return {key: last.get(key) for key in keys if key in last} or "no answer"

    return wait_for(check, timeout_s, what, show=where)


STATUS_KEYS = ("state", "reason", "faults", "calibration", "model_stale")
JOB_KEYS = ("id", "state", "progress", "message", "error")


def _state_waiter(read: Callable[[], dict[str, Any] | None], state: str, timeout_s: float,
                  what: str) -> dict[str, Any]:
    """Wait for the daemon's ``state``; a timeout says its state, reason, faults and calibration progress."""
    return _document_waiter(read, lambda status: status["state"] == state, STATUS_KEYS, timeout_s, what)


def wait_state(client: TestClient, state: str, timeout_s: float = 10.0) -> dict[str, Any]:
    return _state_waiter(lambda: client.get("/api/status").json(), state, timeout_s, f"state {state!r}")


def wait_job(get: Callable[[str], Any], job_id: str, states: str | tuple[str, ...] = "done",
             timeout_s: float = 30.0) -> dict[str, Any]:
    """The document of calibration ``job_id`` once its state is one of ``states``; ``get(path)`` is the
    client's GET (TestClient, LiveServer or httpx on a base URL). A timeout says where the job was
    (its state, progress and message), or that the daemon did not answer."""
    wanted = (states,) if isinstance(states, str) else states

    def read() -> dict[str, Any] | None:
        try:
            return get(f"/api/calibration/{job_id}").json()
        except httpx.TransportError:
            return None

    return _document_waiter(read, lambda job: job.get("state") in wanted, JOB_KEYS, timeout_s,
                            f"calibration {job_id} to be {' or '.join(wanted)}")


class GatedCamera(Camera):
    """Wraps a camera: ``gate_open = False`` starves the reader, ``fail_reads = n`` raises n errors,
    ``lose = n`` loses the next n frames (read and thrown away, as a link that lost them)."""

    def __init__(self, inner: Camera) -> None:
        super().__init__(inner.settings)
        self.inner = inner
        self.gate_open = True
        self.fail_reads = 0
        self.lose = 0
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
        while self.lose > 0:
            self.lose -= 1
            self.inner.read(timeout_s)
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


def activate_refused(client: TestClient, events: str, *said: str) -> dict[str, Any]:
    """The daemon ``client`` started in fault over its saved model: the last event of kind ``events`` holds every
    text of ``said``, and activating the newest calibration again is refused as a conflict with the camera's
    configuration (409), not a wait; returns the refusal's body."""
    wait_for(lambda: [e for e in client.get("/api/events").json() if e["kind"] == events
                      and all(text in e["message"] for text in said)], 10.0, f"a {events} event")
    calibration_id = client.get("/api/calibrations").json()["items"][0]["id"]
    token = client.app.state.storage.token_path.read_text().strip()
    reply = client.post(f"/api/calibrations/{calibration_id}/activate", headers={"Authorization": f"Bearer {token}"})
    assert reply.status_code == 409, reply.text
    return reply.json()


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
    """``python -m graytrack serve`` on a free loopback port; SIGTERM on exit, stderr kept (and stdout, uvicorn's
    access log, in ``stdout_path`` when given). The fast test rig (:data:`FAST_TABLES` updated by ``tables``), or
    with ``default_rig`` no configuration at all: the embedded default, as ``make run`` starts it (data in
    ``folder / "data"``)."""

    def __init__(self, folder: Path, default_rig: bool = False, stdout_path: Path | None = None,
                 **tables: dict[str, Any]) -> None:
        self.folder = folder
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.stderr = ""
        if default_rig:
            assert not tables, "the default rig takes no tables"
            where = ["--data-dir", str(folder / "data")]
        else:
            self.config = write_config(folder, **tables)
            where = ["--config", str(self.config)]
        self.process = subprocess.Popen(
            [sys.executable, "-m", "graytrack", "serve", *where, "--port", str(self.port)],
            stderr=subprocess.PIPE, text=True, stdout=None if stdout_path is None else stdout_path.open("w"))

    def status(self) -> dict[str, Any] | None:
        token = self.folder / "data" / "token"  # reads need it under [daemon] read_token = "always"
        try:
            headers = self.auth() if token.exists() else None  # (not yet written: the daemon is not up either)
            document = httpx.get(f"{self.base}/api/status", timeout=2.0, headers=headers).json()
            return document if "state" in document else None
        except httpx.TransportError:
            return None

    def wait_state(self, state: str, timeout_s: float = 60.0) -> dict[str, Any]:
        # A real process calibrates itself on the wall clock first: ~13 s on a quiet machine, 30+ on a busy one.
        return _state_waiter(self.status, state, timeout_s, f"the daemon to reach {state!r}")

    def get(self, path: str, **kwargs: Any) -> httpx.Response:
        return httpx.get(self.base + path, timeout=5.0, **kwargs)

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

    def __init__(self, app: Any, log_level: str = "warning") -> None:
        import threading

        import uvicorn

        self.app = app
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        # the access log only at debug, as `graytrack serve` has it
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level=log_level,
                                access_log=log_level == "debug", **app.state.server_options)
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

    def after_calibration(self, change: tuple[float, float]) -> dict[str, Any]:
        """Tracking on a model of the rig as it was calibrated, the stage at rest where the sweep's last stop left it,
        then waited on the rig's own clock until a change of the rig timed ``change`` = (from, to) rig seconds has
        happened: the status then. A daemon that calibrated itself at its start rests there already; one started on
        a saved calibration (tests/conftest.py calibrated) has its stage where the rig put it, at 0 mm, outside the
        calibrated stroke, and is moved there first, so that the change meets the rig as a start-up calibration
        leaves it. The change must begin once the stage rests: on a saved model that is a second or two of the rig's
        clock (the test's clock runs at 10x); after a start-up calibration it is after the sweep, which takes the
        rig's clock ~40 s on a quiet machine and over 100 s on a loaded one (its serial exchanges run on the wall
        clock). Otherwise the daemon would start from the changed rig, or the sweep would calibrate the change in,
        and the test's premise — a change after calibration, the stage at rest — would not hold."""
        from graytrack.service.daemon.sweep import sweep_positions

        tracking = self.wait_state("tracking", 60.0)
        rest = float(sweep_positions(self.rig.hardware.stage.limits(), self.rig.settings.sweep)[-1])
        assert self.post("/api/stage/move", json={"target_mm": rest}, headers=self.auth()).status_code == 202
        wait_for(lambda: (s := self.status())["grating_mm"] is not None and abs(s["grating_mm"] - rest) < 0.001
                 and not s["moving"], 20.0, f"the stage at rest at {rest:g} mm",
                 show=lambda: {key: self.status()[key] for key in ("state", "grating_mm", "moving")})
        began = self.rig.clock.now()
        assert began < change[0], (f"the stage came to rest after the change had begun (at {began:.0f} s of the "
                                   f"rig's clock, the change from {change[0]:g} s)")
        time.sleep(self.rig.clock.duration_to_host(change[1] - began))
        return tracking

    def __enter__(self) -> "LiveServer":
        self.thread.start()
        wait_for(lambda: self.server.started, 10.0, "uvicorn to start")
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=20.0)


def _rig_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """What a virtual rig states of itself (VirtualRig.meta): its recording's meta less what that run commanded of
    the stage, which the daemon knows from its own settings and commands."""
    from graytrack.core.recording import STAGE_ACCELERATION, STAGE_PHASES

    return {key: value for key, value in meta.items() if key not in (STAGE_ACCELERATION, STAGE_PHASES)}


def stream_through_daemon(model, run, trim_enabled: bool, slide: Any = None, engine: str = "watches",
                          learned: dict[str, Any] | None = None, before_frame: Any = None,
                          rig_meta: dict[str, Any] | None = None) -> tuple[list[dict], list[tuple[str, str]], Any]:
    """Every frame of a recorded ``run`` through the daemon's frame loop (its tracker built and switched
    in as for an installed model, with ``[daemon] trim`` as asked; ``slide``: the rig's LiveSlide when it
    has no grating, ``[daemon] grating = false``; ``learned``: the maps saved with the model, by name, a map
    the tracker refuses an event ``refused`` naming it; ``before_frame(k)``: called before frame ``k`` is tracked,
    for what the rig does meanwhile; ``rig_meta``: what the rig states of itself, the run's meta where None, as the
    daemon on the virtual rig hands its rig's, :func:`_rig_meta`): the published messages, the events and the
    acquisition (its ``trim`` and ``slide`` for the status)."""
    import numpy as np

    from graytrack.service.daemon.acquisition import Acquisition, Sample
    from graytrack.service.daemon.trim import ReferenceTrim

    messages: list[dict] = []
    events: list[tuple[str, str]] = []
    trim = ReferenceTrim(trim_enabled, lambda kind, message: events.append((kind, message)))
    acquisition = Acquisition(None, None, messages.append, lambda *fault: None, 1.0, 1.0,
                              on_event=lambda kind, message: events.append((kind, message)), trim=trim, slide=slide,
                              engine=engine, rig_meta=_rig_meta(run.meta) if rig_meta is None else rig_meta)
    # as install_model does
    acquisition._build(model, float(run.reference[0]), 0, "calibration", learned or {},
                       lambda name, why: events.append(("refused", f"{name}: {why}")))
    for k in range(run.n_frames):
        if before_frame is not None:  # what else happens on the rig up to this frame (commands, readings)
            before_frame(k)
        frame = Frame(np.asarray(run.frames[k]), k, float(run.t[k]))
        acquisition._track(Sample(frame, float(run.t[k]), float(run.reference[k])))
    return messages, events, acquisition


class Lines(logging.Handler):
    """The log lines a handler would write, formatted as the daemon writes them (``emit`` runs under the
    handler's own lock); records of loggers named in ``ignore`` (a test's own HTTP client) are left out."""

    def __init__(self, ignore: tuple[str, ...] = ()) -> None:
        super().__init__(logging.DEBUG)
        self.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        self.lines: list[str] = []
        self.ignore = ignore

    def emit(self, record: logging.LogRecord) -> None:
        if not (self.ignore and record.name.startswith(self.ignore)):
            self.lines.extend(self.format(record).splitlines())
