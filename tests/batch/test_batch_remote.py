"""``graytrack batch --scheduler``: a real ``dask scheduler`` and two ``dask worker`` processes on
loopback, started and stopped here, give the same summary rows as the in-process cluster."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from graytrack.service.batch import cluster
from graytrack.service.batch.summary import read_summary
from graytrack.service.cli import main

from tests.batch.conftest import batch_paths, without_time

pytest.importorskip("distributed")
DASK = Path(sys.executable).with_name("dask")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start(args: list[str], log: Path) -> subprocess.Popen:
    with open(log, "wb") as fh:
        return subprocess.Popen([str(DASK), *args], stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)


def stop(process: subprocess.Popen) -> None:
    """SIGTERM to the process (and the worker a nanny runs for it), SIGKILL if it lingers."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)


@pytest.fixture
def loopback_cluster(tmp_path):
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    processes = [start(["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                       tmp_path / "scheduler.log")]
    try:
        for index in range(2):
            processes.append(start(["worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--nworkers", "1",
                                    "--no-dashboard", "--death-timeout", "60",
                                    "--local-directory", str(tmp_path / f"worker{index}")],
                                   tmp_path / f"worker{index}.log"))
        yield address
    finally:
        for process in reversed(processes):
            stop(process)
    assert all(process.poll() is not None for process in processes)


def test_real_scheduler_and_two_workers_give_the_same_rows(archive, calibrated, loopback_cluster, tmp_path):
    paths = batch_paths(archive)
    local, remote = calibrated["out"], tmp_path / "remote"
    # --workers 2 with a scheduler: wait until both worker processes have joined
    assert main(["batch", "calibrate", *paths, "--out", str(remote), "--scheduler", loopback_cluster,
                 "--workers", "2"]) == 1
    local_rows, remote_rows = read_summary(local / "summary.csv"), read_summary(remote / "summary.csv")
    assert without_time(remote_rows) == without_time(local_rows)
    assert [row["status"] for row in remote_rows].count("failed") == 1
    for row in remote_rows:
        if row["status"] == "ok":
            remote_model, local_model = remote / row["name"] / "model.json", local / row["name"] / "model.json"
            assert remote_model.read_bytes() == local_model.read_bytes()


def test_unreachable_scheduler_is_one_line(archive, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 2.0)
    code = main(["batch", "calibrate", str(archive["loose"]), "--out", str(tmp_path),
                 "--scheduler", f"tcp://127.0.0.1:{free_port()}"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Dask scheduler" in err[0]
