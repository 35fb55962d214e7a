"""The calibration scan through a real uvicorn server: frames at rest at both ends, one pass at
constant velocity whose every kept frame carries the grating's position at its mid-exposure, dense
along the stroke, and the closed loop's model fitted on it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graytrack.core.recording import load
from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings

# Alone (after the rest, serially): the pass slows down until a reading's instant is known within the
# pairing tolerance, so its length follows the grating's round trip, which a second test worker on a
# 2-core machine stretches (this module's fixture timed out after 120 s in the sweep's third round trip
# beside other tests under load, and took 71 s alone at the same load).
pytestmark = pytest.mark.alone
SCAN_FRAMES = 600
LOW, HIGH = 0.1, 10.36  # the soft limits, 0.1 mm inside


@pytest.fixture(scope="module")
def scanned(tmp_path_factory: pytest.TempPathFactory):
    # Target-fixed dust (what 21 stops cannot see and a pass can). The clock
    # runs only 2x here: a reading's round trip, as the rig's clock sees it, bounds how fast a pass may
    # go and keep its references within the 1 µm pairing tolerance, and 10x would slow it down 5x more.
    tables = {"sweep": {"kind": "scan", "scan_frames": SCAN_FRAMES, "model": "auto"},
              "camera": {"effects": "dust:count=6", "frame_rate_hz": 100.0}}
    settings = fast_settings(tmp_path_factory.mktemp("scan"), tables, sim_clock_scale=2.0)
    with LiveServer(create_app(settings)) as server:
        status = server.wait_state("tracking", timeout_s=120)
        job = server.get("/api/calibration/latest").json()
        hardware = server.rig.hardware
        recording = load(job["files"]["recording"])
        truth = hardware.camera.stage  # the virtual rig's true motion, on its own clock
        clock = server.rig.clock
        yield status, job, recording, np.asarray(truth.position(clock.from_host(recording.t)), dtype=float)


def test_the_scan_records_dense_passes_both_ways_and_frames_at_rest_at_each_end(scanned) -> None:
    _, job, recording, _ = scanned
    assert job["state"] == "done"
    rest = 3  # frames_per_position of the fast settings, at each end
    reference = recording.reference
    assert np.ptp(reference[:rest]) == 0 and reference[0] == pytest.approx(LOW, abs=1e-3), "the start, at rest"
    at_top = np.flatnonzero(reference == reference.max())
    assert len(at_top) >= rest and reference.max() == pytest.approx(HIGH, abs=1e-3), "the far end, at rest"
    moving = np.delete(reference, np.r_[np.arange(rest), at_top])
    assert len(moving) >= 0.5 * SCAN_FRAMES, f"only {len(moving)} frames of the passes were paired"
    step = np.diff(moving)
    direction = np.sign(step[step != 0])
    turns = int(np.sum(direction[1:] != direction[:-1]))
    assert direction[0] > 0 and turns % 2 == 1, "passes up and down, in pairs (a loaded host may add a round trip)"
    passes = np.split(moving, np.flatnonzero(np.diff(np.sign(np.diff(moving))) != 0) + 1)
    long_passes = [p for p in passes if np.ptp(p) > 0.9 * (HIGH - LOW)]
    assert len(long_passes) >= 2, "each pass covers the whole stroke"
    # scan_frames over two passes: frames this far apart, or a few times that where a loaded
    # machine's late readings paired none; either way far denser than the 21 stops' 0.5 mm
    nominal = 2 * (HIGH - LOW) / SCAN_FRAMES
    assert np.median(np.abs(step)) < 4 * nominal


def test_every_pass_frame_carries_the_position_at_its_mid_exposure(scanned) -> None:
    _, _, recording, true_mm = scanned
    error_um = (recording.reference - true_mm) * 1e3
    # the grating itself reads to a fraction of a micrometre; pairing keeps its error under 1 µm for
    # nearly every frame (a host at load 8 left 1 % of them up to 4 µm off: a reply delayed after the
    # controller sampled, beyond what its round trip told)
    spread = np.percentile(np.abs(error_um), [50, 95, 100])
    assert spread[0] < 0.5 and spread[1] < 1.5 and spread[2] < 6.0, spread


def test_the_closed_loop_calibrates_on_the_scan_near_its_bound(scanned) -> None:
    status, job, _, _ = scanned
    held_out = job["report"]["held_out"]
    # the bound pooled over the held-out frames (rms): with dust in view on some frames only it is
    # bimodal along the stroke, and a median swung 0.65–1.69 µm between runs of this very rig
    assert 0.6 * held_out["bound_um"] <= held_out["error_std_um"] <= 1.6 * held_out["bound_um"], held_out
    assert status["active_calibration"]["id"] == job["id"]
    # the report the job keeps is the file on disk, summary and held-out figures included
    assert json.loads(Path(job["files"]["json"]).read_text()) == job["report"]
