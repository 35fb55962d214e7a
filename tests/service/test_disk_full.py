"""A real ``graytrack serve`` on a real small file system (a tmpfs) that fills up, turns read-only, or
loses its data directory: what it reports is what it does, nothing is lost, and it recovers by
itself. Skipped where a tmpfs cannot be mounted (not root, no mount permission in a container)."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from tests.service.helpers import ServeProcess, wait_for, wait_job, write_config

SERVE = {"daemon": {"auto_calibrate": "never", "events_max_count": 60}}


def as_root(*command: str) -> list[str]:
    """``command`` as root: itself when this is root, else through ``sudo -n`` (CI runs as a user with sudo)."""
    return list(command) if os.geteuid() == 0 else ["sudo", "-n", *command]


def mount(*arguments: str) -> None:
    subprocess.run(as_root("mount", *arguments), check=True, capture_output=True)


@contextmanager
def small_disk(where: Path, size: str, data: Path | None = None) -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``where`` (with a copy of the data directory ``data`` in it), unmounted after;
    owned by this user, so the daemon under test writes it as it would its own directory."""
    where.mkdir()
    options = f"size={size},mode=0700,uid={os.geteuid()},gid={os.getegid()}"
    try:
        done = subprocess.run(as_root("mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)),
                              capture_output=True, text=True)
    except FileNotFoundError as exc:  # no mount or no sudo on this machine
        done = subprocess.CompletedProcess(exc.filename, 127, "", str(exc))
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode}): these tests need a real "
                    f"small file system (root, or sudo without a password)")
    try:
        if data is not None:
            shutil.copytree(data, where / "data")
        yield where
    finally:
        subprocess.run(as_root("umount", "-l", str(where)), capture_output=True)


def fill(disk: Path, leave: int = 0) -> Path:
    """Fill ``disk`` up, leaving ``leave`` bytes free (the filler is removed to give the space back)."""
    filler = disk / f"filler-{time.monotonic_ns()}"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        for chunk in (1 << 20, 1 << 12):
            try:
                while True:
                    os.write(fd, b"\xa5" * chunk)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
        if leave:
            os.ftruncate(fd, os.fstat(fd).st_size - leave)
    finally:
        os.close(fd)
    return filler


def free(disk: Path) -> int:
    vfs = os.statvfs(disk)
    return vfs.f_bavail * vfs.f_frsize


def digest(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` and its content's hash (nothing renamed, nothing truncated)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def tracked_calibration(port: int, expected: str | None = None) -> str:
    """The calibration of the model the tracker runs, as its own frames say (each stream message names it)."""
    def newest() -> str | None:
        with connect(f"ws://127.0.0.1:{port}/ws/position", open_timeout=5) as ws:
            messages = [json.loads(ws.recv(timeout=5)) for _ in range(20)]
        names = {m.get("calibration") for m in messages}
        value = messages[-1].get("calibration")
        return value if len(names) == 1 and (expected is None or value == expected) else None

    return wait_for(newest, 10.0, f"the tracker to run calibration {expected}'s model")


def assert_one_calibration(daemon: ServeProcess, data: Path, expected: str) -> None:
    """``/api/status``, ``/api/calibrations``, ``DATA/active``, ``DATA/model.json`` and the tracker's own
    model all name ``expected``."""
    status = daemon.status()
    assert status["active_calibration"]["id"] == expected, status
    rows = daemon.get("/api/calibrations").json()["items"]
    assert [r["id"] for r in rows if r["active"]] == [expected], rows
    assert status["model"] == [r["model"] for r in rows if r["id"] == expected][0]
    assert (data / "active").read_text().strip() == expected
    assert (data / "model.json").read_bytes() == (data / "calibrations" / expected / "model.json").read_bytes()
    assert tracked_calibration(daemon.port, expected) == expected


@pytest.fixture(scope="module")
def disk(tmp_path_factory: pytest.TempPathFactory, _two_calibrations: tuple[Path, list[str]]) -> Iterator[Path]:
    """A 24 MiB tmpfs holding a data directory with two finished calibrations (room for one more sweep)."""
    with small_disk(tmp_path_factory.mktemp("small-disk") / "disk", "24m", _two_calibrations[0]) as where:
        yield where


@pytest.fixture(scope="module")
def served(disk: Path) -> Iterator[ServeProcess]:
    """One ``graytrack serve`` on that disk, tracking with the newer calibration (shared by the tests in order)."""
    with ServeProcess(disk, **SERVE) as daemon:
        daemon.wait_state("tracking")
        yield daemon


def test_a_failed_activate_on_a_full_disk_changes_nothing_answers_507_and_recovers(
        served: ServeProcess, disk: Path, _two_calibrations: tuple[Path, list[str]]) -> None:
    older, newer = _two_calibrations[1]
    data = disk / "data"
    assert_one_calibration(served, data, newer)
    filler = fill(disk)
    assert free(disk) == 0

    refused = httpx.post(f"{served.base}/api/calibrations/{older}/activate", headers=served.auth(), timeout=10)
    assert refused.status_code == 507, refused.text
    assert "disk full" in refused.json()["error"] and "0 B free" in refused.json()["error"]
    assert_one_calibration(served, data, newer)  # the daemon reports what it tracks: nothing moved
    status = served.status()
    assert status["state"] == "fault" and "disk full" in status["faults"]["storage"], status
    assert served.get("/healthz").status_code == 503
    started = httpx.post(f"{served.base}/api/calibration", headers=served.auth(), timeout=10)
    assert started.status_code == 507 and "disk full" in started.json()["error"]

    filler.unlink()  # space returns: the faults clear by themselves (no request writes anything meanwhile)
    status = served.wait_state("tracking", 10.0)
    assert "storage" not in status["faults"] and "record" not in status["faults"]
    events = served.get("/api/events").json()
    storage = [e["kind"] for e in events if e["details"].get("source") == "storage"]
    assert storage[-2:] == ["fault", "recovered"], "the events of the full disk were kept and written afterwards"

    done = httpx.post(f"{served.base}/api/calibrations/{older}/activate", headers=served.auth(), timeout=10)
    assert done.status_code == 200 and done.json()["active"] == older
    assert_one_calibration(served, data, older)
    assert httpx.post(f"{served.base}/api/calibrations/{newer}/activate", headers=served.auth(),
                      timeout=10).status_code == 200
    assert_one_calibration(served, data, newer)


def test_a_sweep_that_fails_for_a_full_disk_keeps_its_cause_and_writes_it_when_space_returns(
        served: ServeProcess, disk: Path, _two_calibrations: tuple[Path, list[str]]) -> None:
    data = disk / "data"
    job_id = httpx.post(f"{served.base}/api/calibration", headers=served.auth(), timeout=10).json()["id"]
    wait_job(served.get, job_id, "sweeping", 30.0)
    filler = fill(disk)
    job = wait_job(served.get, job_id, "failed", 30.0)
    assert job["error"].startswith("disk full: the data directory"), job
    on_disk = json.loads((data / "calibrations" / job_id / "status.json").read_text())
    assert on_disk["state"] == "sweeping", "nothing could be written: the end waits in memory"
    assert "disk full" in served.status()["faults"]["storage"]

    filler.unlink()
    ended = wait_for(lambda: json.loads((data / "calibrations" / job_id / "status.json").read_text())["state"]
                     == "failed", 10.0, "the final status to be written once space returned")
    assert ended
    on_disk = json.loads((data / "calibrations" / job_id / "status.json").read_text())
    assert on_disk["error"] == job["error"], "a restart reads the cause, not 'interrupted'"
    served.wait_state("tracking", 10.0)
    assert_one_calibration(served, data, _two_calibrations[1][1])


def test_the_event_log_is_bounded_keeping_the_newest_of_each_kind(served: ServeProcess) -> None:
    for i in range(80):
        assert httpx.post(f"{served.base}/api/stage/move", json={"target_mm": 5.0 + 0.01 * (i % 7)},
                          headers=served.auth(), timeout=5).status_code == 202
    events = served.get("/api/events", params={"limit": 500}).json()
    kinds = [e["kind"] for e in events]
    assert len(events) <= 60 + len(set(kinds)), len(events)
    assert "start" in kinds, "the newest of each kind is kept however old"
    moves = [e for e in events if e["message"].startswith("move to")]
    # the moves share the 60 with what they cause (locks lost and found, stale flags, marks learned: 31 of
    # them on a busy machine), and the newest move is there
    assert 10 < len(moves) <= 60 and moves[-1]["message"] == f"move to {5.0 + 0.01 * (79 % 7):g} mm"


def test_a_data_directory_made_read_only_moved_away_or_replaced_is_a_fault_and_nothing_is_written_into_it(
        served: ServeProcess, disk: Path) -> None:
    data, away = disk / "data", disk / "data.away"
    headers = served.auth()
    # read-only over the daemon's open files: a read-only bind mount of the directory on itself (a remount
    # of the whole file system is refused while files are open for writing)
    mount("--bind", str(data), str(data))
    try:
        mount("-o", "remount,bind,ro", str(data))
        status = served.wait_state("fault", 10.0)
        assert status["faults"]["storage"].startswith(f"read-only: the data directory {data}"), status
        assert served.get("/healthz").status_code == 503
        refused = httpx.post(f"{served.base}/api/calibration", headers=headers, timeout=10)
        assert refused.status_code == 507 and "read-only" in refused.json()["error"]
    finally:
        subprocess.run(as_root("umount", str(data)), check=True)
    served.wait_state("tracking", 10.0)

    os.rename(data, away)  # the directory leaves its path: the record there must not be written
    count = sqlite3.connect(away / "record.sqlite").execute("SELECT COUNT(*) FROM events").fetchone()[0]
    status = served.wait_state("fault", 10.0)
    assert f"the data directory {data} was removed" in status["faults"]["storage"], status
    assert served.get("/healthz").status_code == 503
    assert httpx.post(f"{served.base}/api/stage/move", json={"target_mm": 4.5}, headers=headers,
                      timeout=5).status_code == 202
    refused = httpx.post(f"{served.base}/api/calibration", headers=headers, timeout=10)
    assert refused.status_code == 507 and "removed" in refused.json()["error"]
    time.sleep(0.5)  # the watchdog's rounds (0.1 s): none of them may write into the directory that left
    assert sqlite3.connect(away / "record.sqlite").execute("SELECT COUNT(*) FROM events").fetchone()[0] == count
    os.rename(away, data)  # back (the same directory): safe, the fault clears and the kept events are written
    served.wait_state("tracking", 10.0)
    assert "move to 4.5 mm" in [e["message"] for e in served.get("/api/events").json()]

    os.rename(data, away)
    shutil.copytree(away, data)  # another directory at the path: not the one the daemon opened
    status = served.wait_state("fault", 10.0)
    assert "was replaced by another directory" in status["faults"]["storage"]
    time.sleep(0.5)
    assert "replaced" in served.status()["faults"]["storage"], "a replaced directory is not taken as the old one"


@pytest.fixture
def tiny_disk(tmp_path: Path, _two_calibrations: tuple[Path, list[str]]) -> Iterator[Path]:
    with small_disk(tmp_path / "disk", "1m", _two_calibrations[0]) as where:
        yield where


def test_serve_on_a_full_or_read_only_disk_says_so_in_one_line_and_touches_nothing(tiny_disk: Path) -> None:
    config = write_config(tiny_disk, **SERVE)
    data = tiny_disk / "data"
    fill(tiny_disk)
    before = digest(data)

    def serve() -> list[str]:
        done = subprocess.run([sys.executable, "-m", "graytrack", "serve", "--config", str(config), "--port", "0"],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, done.stderr
        return done.stderr.strip().splitlines()

    lines = serve()
    assert len(lines) == 1 and lines[0].startswith(f"graytrack serve: error: cannot start: disk full: the data "
                                                   f"directory {data} has 0 B free"), lines
    assert "free some space" in lines[0]
    assert digest(data) == before, "nothing renamed, truncated or created"
    mount("-o", "remount,ro", str(tiny_disk))
    lines = serve()
    assert len(lines) == 1 and "read-only" in lines[0] and "remount it read-write" in lines[0], lines
    assert digest(data) == before


def test_a_switch_on_a_full_disk_changes_nothing_and_its_undo_needs_no_space(tmp_path: Path) -> None:
    from graytrack.service.daemon.switch import Switch, leftovers

    with small_disk(tmp_path / "disk", "1m") as disk:
        active, model = disk / "active", disk / "model.json"
        active.write_text("B\n")
        model.write_bytes(b"B" * 3000)
        filler = fill(disk)
        with pytest.raises(OSError) as refused:
            Switch([(active, b"A\n"), (model, b"A" * 3000)])
        assert refused.value.errno == errno.ENOSPC
        assert (active.read_text(), model.read_bytes()) == ("B\n", b"B" * 3000) and not leftovers(disk, NAMES)
        filler.unlink()
        switch = Switch([(active, b"A\n"), (model, b"A" * 3000)]).apply()
        assert (active.read_text(), model.read_bytes()) == ("A\n", b"A" * 3000)
        filler = fill(disk)  # the record's row cannot be written now: the undo is renames only
        switch.undo()
        assert (active.read_text(), model.read_bytes()) == ("B\n", b"B" * 3000) and not leftovers(disk, NAMES)
        filler.unlink()
        Switch([(active, b"A\n"), (model, None)]).apply().commit()
        assert active.read_text() == "A\n" and not model.exists() and not leftovers(disk, NAMES)


NAMES = ("active", "model.json")


def test_an_activate_killed_between_its_steps_is_completed_or_taken_back_at_the_next_start(
        tmp_path: Path, two_calibrations: list[str]) -> None:
    """kill -9 after the pointer moved and before the model's copy (the state the switch's order allows,
    made here by hand), then kill -9 at a seeded instant among rapid activations: after each restart the
    status, the list, ``DATA/active``, ``DATA/model.json`` and the tracker name one calibration."""
    import random
    import threading

    older, newer = two_calibrations
    data = tmp_path / "data"
    (data / "active").write_text(older + "\n")  # the model.json is still the newer one's
    (data / ".model.json.1.0000.new").write_bytes((data / "calibrations" / older / "model.json").read_bytes())
    os.link(data / "model.json", data / ".active.1.0000.old")
    with ServeProcess(tmp_path, **SERVE) as daemon:
        daemon.wait_state("tracking")
        assert_one_calibration(daemon, data, older)
        assert not list(data.glob(".*.new")) + list(data.glob(".*.old")), "what the killed switch left is removed"
        stop = threading.Event()

        def activate() -> None:
            with httpx.Client(base_url=daemon.base, headers=daemon.auth(), timeout=5) as client:
                for i in range(10_000):
                    if stop.is_set():
                        return
                    try:
                        client.post(f"/api/calibrations/{two_calibrations[i % 2]}/activate")
                    except httpx.TransportError:
                        return

        worker = threading.Thread(target=activate)
        worker.start()
        time.sleep(random.Random(38).uniform(0.3, 0.8))
        daemon.process.kill()
        daemon.process.wait()
        stop.set()
        worker.join()
    with ServeProcess(tmp_path, **SERVE) as again:
        again.wait_state("tracking")
        assert_one_calibration(again, data, (data / "active").read_text().strip())


def test_an_install_whose_record_row_cannot_be_written_is_undone_whole(
        tmp_path: Path, two_calibrations: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """The install's last disk step fails (SQLite: "database or disk is full"): the pointer and the model's
    copy, already switched, go back; the job fails with the cause; the tracker keeps the old model."""
    from graytrack.service.daemon.app import create_app
    from tests.service.helpers import LiveServer, fast_settings

    data = tmp_path / "data"
    with LiveServer(create_app(fast_settings(data, auto_calibrate="never"))) as daemon:
        daemon.wait_state("tracking")
        history = daemon.rig.history
        monkeypatch.setattr(history, "add_calibration",
                            lambda row: (_ for _ in ()).throw(sqlite3.OperationalError("database or disk is full")))
        job_id = daemon.post("/api/calibration", headers=daemon.auth()).json()["id"]
        job = wait_job(daemon.get, job_id, ("failed", "done"), 30.0)
        assert job["state"] == "failed" and job["error"].startswith("disk full:") and "disk is full" in job["error"]
        assert not list(data.glob(".*.new")) + list(data.glob(".*.old"))
        daemon.wait_state("tracking", 10.0)
        assert_one_calibration(daemon, data, two_calibrations[-1])
