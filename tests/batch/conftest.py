"""An archive of short virtual-rig recordings (two rigs' data directories, a loose recording and a
corrupt file) and an in-process Dask cluster to run batches on (threads: fast to start)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.models import save_model
from graytrack.core.recording import Recording, save
from graytrack.drivers.sim.scenarios import build_rig

SECONDS = 2.0  # 100 frames of the paper rig: a full sweep, a second of work per recording
CALIBRATION_IDS = ("20260105T080000000000Z", "20260112T080000000000Z")
# rig-b's second sweep sees a target printed 0.3 % long: a τ_w change far beyond its uncertainty
EFFECTS = {("rig-b", 1): "pitch_scale:ppm=3000"}


def record(path: Path, seed: int, effects: str = "") -> Recording:
    rec, _ = build_rig("paper", effects, seed=seed).record(SECONDS)
    save(rec, path)
    return rec


@pytest.fixture(scope="session")
def archive(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("archive")
    seed = 0
    for rig in ("rig-a", "rig-b"):
        for index, calibration_id in enumerate(CALIBRATION_IDS):
            folder = root / rig / "calibrations" / calibration_id
            recording = record(folder / "recording.npz", seed, EFFECTS.get((rig, index), ""))
            save_model(calibrate(recording, "paper").model, folder / "model.json")  # as the daemon keeps it
            seed += 1
    record(root / "loose" / "sweep.npz", seed)
    corrupt = root / "loose" / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 this is not a zip archive")
    return {"root": root, "rig-a": root / "rig-a", "rig-b": root / "rig-b", "loose": root / "loose" / "sweep.npz",
            "corrupt": corrupt}


# package scope (and so the fixture that uses it): the cluster is closed once this folder's tests are done; left
# to the session's end, its heartbeats took ~0.04 s of CPU a second beside every later test of its worker.
@pytest.fixture(scope="package")
def in_process_scheduler() -> str:
    """Address of a Dask scheduler with two single-threaded workers inside this process."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, host="127.0.0.1",
                                       protocol="tcp",
                                       dashboard_address=None)
    yield cluster.scheduler_address
    cluster.close()


@pytest.fixture(scope="package")
def calibrated(archive, in_process_scheduler, tmp_path_factory) -> dict:
    """``graytrack batch calibrate`` over the whole archive once: exit code, rows, output, stderr."""
    from graytrack.service.batch.summary import read_summary
    from graytrack.service.cli import main

    out = tmp_path_factory.mktemp("calibrated")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["batch", "calibrate", *batch_paths(archive), "--out", str(out), "--scheduler",
                     in_process_scheduler])
    return {"code": code, "rows": read_summary(out / "summary.csv"), "out": out, "stderr": err.getvalue()}


def batch_paths(archive: dict[str, Path]) -> list[str]:
    return [str(archive["rig-a"]), str(archive["rig-b"]), str(archive["root"] / "loose")]


def without_time(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """Rows as compared between runs: everything but the time each took."""
    return [{key: value for key, value in row.items() if key != "seconds"} for row in rows]
