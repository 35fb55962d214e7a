"""The daemon as a process: signals and kill -9 never leave a calibration misreported, one daemon
per data directory, and a bad address or a busy port is one line and exit status 2."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from graytrack.service.cli import main
from tests.service.helpers import ServeProcess, wait_job

# no automatic calibration, and a fit long enough to be caught in the act
SLOW_FIT = {"daemon": {"auto_calibrate": "never"}, "sweep": {"positions": 41, "frames_per_position": 6}}


def _start_calibration(daemon: ServeProcess) -> str:
    daemon.wait_state("idle")
    response = httpx.post(f"{daemon.base}/api/calibration", headers=daemon.auth(), timeout=5)
    assert response.status_code == 202, response.text
    return response.json()["id"]


def _status_file(folder: Path, job_id: str) -> dict:
    return json.loads((folder / "data" / "calibrations" / job_id / "status.json").read_text())


def test_sigterm_during_the_fit_leaves_no_done_job_without_its_model(tmp_path: Path) -> None:
    with ServeProcess(tmp_path, **SLOW_FIT) as daemon:
        job_id = _start_calibration(daemon)
        wait_job(daemon.get, job_id, "fitting", 30.0)
        assert daemon.terminate() == 0, daemon.stderr
    on_disk = _status_file(tmp_path, job_id)
    installed = tmp_path / "data" / "model.json"
    # the fit may end before the shutdown reaches the job: then it is done *and* installed
    if on_disk["state"] == "done":
        assert installed.read_text() == Path(on_disk["files"]["model"]).read_text()
        assert (tmp_path / "data" / "active").read_text().strip() == job_id
    else:
        assert on_disk["state"] == "aborted", on_disk
        assert on_disk["message"] == "calibration aborted: the daemon is shutting down"
        assert not installed.exists(), "no model was installed for an aborted job"
    assert "Traceback" not in daemon.stderr


def test_kill_9_in_the_sweep_or_the_fit_leaves_the_job_interrupted_at_the_next_start(tmp_path: Path) -> None:
    killed: list[tuple[str, str]] = []
    for phase in ("sweeping", "fitting", None):
        with ServeProcess(tmp_path, **SLOW_FIT) as daemon:  # the kernel released the lock with the process
            daemon.wait_state("idle")
            for job_id, state in killed:
                job = httpx.get(f"{daemon.base}/api/calibration/{job_id}", timeout=5).json()
                assert job["state"] == "interrupted"
                assert job["message"] == f"interrupted while {state} (the daemon stopped)"
            if phase is None:
                break
            job_id = _start_calibration(daemon)
            wait_job(daemon.get, job_id, phase, 30.0)
            daemon.process.kill()
            daemon.process.wait()
        assert _status_file(tmp_path, job_id)["state"] == phase, "kill -9 left it active on disk"
        killed.append((job_id, phase))
    assert len(killed) == 2


def test_a_second_daemon_on_the_same_data_directory_exits_2_naming_the_first(tmp_path: Path) -> None:
    with ServeProcess(tmp_path, **SLOW_FIT) as first:
        first.wait_state("idle")
        second = subprocess.run([sys.executable, "-m", "graytrack", "serve", "--config", str(first.config),
                                 "--port", "0"], capture_output=True, text=True, timeout=60)
        assert second.returncode == 2
        lines = second.stderr.strip().splitlines()
        assert lines == [f"graytrack serve: error: data directory {tmp_path / 'data'} is in use by another "
                         f"graytrack serve (pid {first.process.pid})"], second.stderr
        assert first.status()["state"] == "idle", "the first daemon is untouched"


def test_a_bad_host_or_a_busy_port_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["serve", "--data-dir", str(tmp_path / "data")]
    assert main([*args, "--host", "999.1.2.3"]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("graytrack serve: error: --host '999.1.2.3': not an address") and "\n" not in line
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main([*args, "--port", str(port)]) == 2
    line = capsys.readouterr().err.strip()
    assert line == (f"graytrack serve: error: port {port} on 127.0.0.1 is already in use "
                    "(another graytrack serve? choose --port)")
    # the failed starts released the directory: a third start may lock it
    from graytrack.service.daemon.storage import Storage

    storage = Storage(tmp_path / "data")
    storage.lock()
    storage.unlock()


def test_the_token_is_created_whole_by_concurrent_first_starts(tmp_path: Path) -> None:
    code = ("import sys; from graytrack.service.daemon.storage import Storage; "
            "print(Storage(sys.argv[1]).token()[0])")
    processes = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
                 for _ in range(6)]
    tokens = {p.communicate(timeout=60)[0].strip() for p in processes}
    assert len(tokens) == 1 and len(tokens.pop()) >= 32, "every start read the one complete token"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".token")], "no temporary file left"


@pytest.mark.parametrize("planted, mode, could", [("directory", 0o777, "could change it"),
                                                   ("token", 0o666, "could read and change it"),
                                                   ("token", 0o644, "could read it")])
def test_a_directory_or_token_others_can_write_is_refused_with_the_fix(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], planted: str, mode: int, could: str) -> None:
    """A world-writable data directory lets another user plant DATA/token before the first start
    (that token would then move the stage); a token file others can read or write leaks or plants it."""
    import os

    data = tmp_path / "data"
    data.mkdir()
    if planted == "directory":
        data.chmod(mode)
        fix = f"chmod go-w {data}"
    else:
        (data / "token").write_text("planted-by-another-user-0123456789\n")
        (data / "token").chmod(mode)
        fix = f"chmod 600 {data / 'token'}"
    assert main(["serve", "--data-dir", str(data), "--port", "0"]) == 2
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and f"other users {could}" in line and line.endswith(fix)  # 644: read, not change
    assert not (data / "lock").exists() or planted == "token"  # refused before anything was written
    (data if planted == "directory" else data / "token").chmod(0o700 if planted == "directory" else 0o600)
    from graytrack.service.daemon.storage import Storage

    Storage(data).token()  # accepted once fixed
    assert os.stat(data).st_mode & 0o022 == 0


def _crash_mid_install(tmp_path: Path, ids: list[str], step: int) -> tuple[str, str]:
    """The data directory of two calibrations done through a real daemon (``ids``), as a kill -9
    after ``step`` of a third one's install leaves it: 0 = the job's model written, 1 = the pointer
    switched, 2 = the copy in DATA written (its status still says ``installing``)."""
    import shutil

    data = tmp_path / "data"
    first, second = ids
    third = second[:9] + "235959" + second[15:]  # a later id of the same day
    shutil.copytree(data / "calibrations" / first, data / "calibrations" / third)
    status = _status_file(tmp_path, first)
    status.update(id=third, state="installing")
    (data / "calibrations" / third / "status.json").write_text(json.dumps(status))
    if step >= 1:
        (data / "active").write_text(third + "\n")
    if step >= 2:
        shutil.copy(data / "calibrations" / third / "model.json", data / "model.json")
    return second, third


@pytest.mark.parametrize("step", [0, 1, 2])
def test_a_crash_anywhere_in_an_install_leaves_the_pointer_and_the_model_agreeing(
        tmp_path: Path, step: int, two_calibrations: list[str]) -> None:
    before, crashed = _crash_mid_install(tmp_path, two_calibrations, step)
    data = tmp_path / "data"
    with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as daemon:
        status = daemon.wait_state("tracking")
        assert httpx.get(f"{daemon.base}/api/calibration/{crashed}", timeout=5).json()["state"] == "interrupted"
        assert status["active_calibration"]["id"] == before, "the newest calibration that finished installing"
        assert (data / "model.json").read_bytes() == (data / "calibrations" / before / "model.json").read_bytes()
        events = httpx.get(f"{daemon.base}/api/events", timeout=5).json()
        reconciled = [e["message"] for e in events if e["kind"] == "model_reconciled"]
        assert bool(reconciled) == (step > 0), "the start-up check says what it set right, and only then"
