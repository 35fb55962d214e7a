"""A running daemon on the virtual rig (real app, real GCS driver on a pty), shared by a module."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.conftest import shared_once
from tests.service.helpers import LiveServer, ServeProcess, fast_settings, wait_job, wait_state


@pytest.fixture(scope="module")
def tracking(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """Started without a model: it calibrates itself (auto_calibrate = "sim") and tracks."""
    app = create_app(fast_settings(tmp_path_factory.mktemp("daemon")))
    with TestClient(app) as client:
        wait_state(client, "tracking", 20.0)
        yield client


@pytest.fixture(scope="module")
def token(tracking: TestClient) -> dict[str, str]:
    storage = tracking.app.state.storage
    return {"Authorization": f"Bearer {storage.token_path.read_text().strip()}"}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Path:
    """The data directory of :func:`daemon` (its token is ``data_dir / "token"``): the run's first
    calibration in it (tests/conftest.py calibrated)."""
    return calibrated(tmp_path_factory.mktemp("live"))


@pytest.fixture(scope="module")
def daemon(data_dir: Path) -> Iterator[LiveServer]:
    """The daemon on a real uvicorn server (a client connects over the network), tracking from its start on the
    calibration in :func:`data_dir`."""
    with LiveServer(create_app(fast_settings(data_dir))) as server:
        server.wait_state("tracking", 40.0)
        yield server


@pytest.fixture(scope="session")
def _two_calibrations(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """Made once for the run (tests/conftest.py shared_once: the test workers share it) and read only: its users
    copy the data directory before a daemon writes into it."""

    def make(folder: Path) -> None:
        with ServeProcess(folder, daemon={"auto_calibrate": "never"}) as first:
            first.wait_state("idle")
            done: list[str] = []
            for _ in range(2):
                job = httpx.post(f"{first.base}/api/calibration", headers=first.auth(), timeout=5).json()["id"]
                wait_job(first.get, job, "done", 60.0)
                done.append(job)
            assert first.terminate() == 0
        (folder / "done.json").write_text(json.dumps(done))

    folder = shared_once(tmp_path_factory, "two-calibrations", make)
    return folder / "data", json.loads((folder / "done.json").read_text())


@pytest.fixture
def two_calibrations(_two_calibrations: tuple[Path, list[str]], tmp_path: Path) -> list[str]:
    """``tmp_path / "data"``: a data directory with two calibrations a real ``graytrack serve`` made
    and finished (made once per test process, copied for each test); their ids, oldest first."""
    data, done = _two_calibrations
    shutil.copytree(data, tmp_path / "data")
    return list(done)
