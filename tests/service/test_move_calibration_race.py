"""Moves racing a calibration's start on the virtual rig: a move either reached the controller before the
sweep's first command (which then replaces it) or is refused 409; the sweep's stops are where they were
planned, or the job failed saying something else moved the stage. The stage never leaves its limits.

The race is between the rig's own calls (what the API routes call on their worker threads), from four
threads released together with the calibration's start: the same code the HTTP requests run, without the
HTTP round trips that would spread the threads apart. The movers' link to the controller is slowed by
:data:`LINK_DELAY_S` (a serial command's round trip on a busy line): without one lock over "is a
calibration running?" and the command, that is the window in which the sweep's first move overtakes a
checked move, and the sweep then finds its first stop at the move's target.
"""

from __future__ import annotations

import random
import threading
from collections import Counter
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from graytrack.core.recording import load
from graytrack.service.daemon.app import create_app
from graytrack.service.daemon.errors import Busy
from graytrack.service.daemon.sweep import sweep_positions
from tests.service.helpers import fast_settings, wait_for, wait_state

RACES = 100
MOVERS = 4
MOVE_TARGET_MM = 2.0  # far from the first planned stop (0.1 mm): a stop recorded there is plain to see
# two stops of three frames: the shortest sweep that has stops to check (the fit may refuse so few frames;
# the recording, written before the fit, is what the stops are checked on)
LINK_DELAY_S = 0.005
SWEEP = {"kind": "stops", "positions": 2, "frames_per_position": 3, "model": "paper", "stop_tolerance_um": 10.0}
# The race is decided in the first milliseconds of each start; the sweep after it only has to end. Its
# simulated time runs 40x the wall clock (the camera at 5 simulated frames/s, the usual 200 a wall second):
# a race takes ~0.1 s of wall time instead of ~0.2 s.
QUICK_SWEEP = {"sim_clock_scale": 40.0}
QUICK_CAMERA = {"frame_rate_hz": 5.0}


def test_moves_racing_a_starting_calibration_never_put_a_stop_elsewhere(tmp_path: Path) -> None:
    app = create_app(fast_settings(tmp_path, tables={"sweep": SWEEP, "camera": QUICK_CAMERA}, auto_calibrate="never",
                                   **QUICK_SWEEP))
    with TestClient(app) as client:
        wait_state(client, "idle", 20.0)
        rig = app.state.rig
        low, high = rig.hardware.stage.limits()
        planned = sweep_positions((low, high), rig.settings.sweep)
        tolerance_mm = SWEEP["stop_tolerance_um"] * 1e-3
        stage = rig.hardware.stage
        command = stage.move_to

        def slow_link(target_mm: float) -> None:
            if threading.current_thread().name.startswith("mover"):
                threading.Event().wait(LINK_DELAY_S)
            command(target_mm)

        stage.move_to = slow_link
        outcomes: Counter[str] = Counter()
        answers: Counter[str] = Counter()
        errors: Counter[str] = Counter()
        displaced = 0
        chance = random.Random(48)
        for race in range(RACES):
            start = threading.Barrier(MOVERS + 1)

            def mover(delay_s: float) -> None:
                start.wait()
                threading.Event().wait(delay_s)
                try:
                    rig.stage.move(MOVE_TARGET_MM)
                    answers["moved"] += 1
                except Busy:
                    answers["busy"] += 1
                except Exception as exc:  # noqa: BLE001 - any other answer is counted, and named by the assert below
                    answers[f"{type(exc).__name__}: {exc}"] += 1

            threads = [threading.Thread(target=mover, args=(chance.uniform(0, 0.002),), name=f"mover-{k}")
                       for k in range(MOVERS)]
            for thread in threads:
                thread.start()
            start.wait()
            threading.Event().wait(chance.uniform(0, 0.002))
            job = rig.start_calibration()
            for thread in threads:  # (a loaded machine may take seconds over a move; none is left behind)
                thread.join(60.0)
                assert not thread.is_alive(), (race, thread.name)
            wait_for(lambda: not job.active, 30.0, f"race {race}'s calibration to end", show=job.to_dict)
            outcomes[job.state] += 1
            errors[(job.error or "")[:90]] += 1
            recording = Path(job.files["recording"]) if "recording" in job.files else None
            if recording is not None:  # the stops were all reached: each where it was planned
                reference = load(recording).reference
                stops = reference.reshape(len(planned), -1)[:, 0]
                assert np.all(np.abs(stops - planned) <= tolerance_mm), (race, stops, planned)
            else:  # the sweep's own check; with the lock it is never needed here
                assert job.state == "failed" and "something else moved the stage" in (job.error or ""), job.to_dict()
                displaced += 1
            position = rig.hardware.stage.position().position_mm
            assert low <= position <= high, (race, position)
        assert set(answers) <= {"moved", "busy"} and sum(answers.values()) == RACES * MOVERS, answers
        assert answers["moved"] and answers["busy"], f"both sides won some races: {answers}"
        assert displaced == 0, f"{displaced} of {RACES} sweeps found a stop displaced by a move ({errors})"
        assert set(outcomes) <= {"done", "failed"} and sum(outcomes.values()) == RACES, outcomes
