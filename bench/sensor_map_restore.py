"""A daemon restarted on the same model with dust on the camera's window, with and without the sensor map it
had learned (service/daemon/sensor_map_store.py keeps it in DATA/sensor_map.json; core/estimator/sensor_map.py's
state/restore).

Per seed: a clean calibration run (`calibrate --model paper`); the live estimator (as the daemon runs it with
`engine = "estimator"`) learns on a session during which six specks land on the window (`window_dust`, run 1),
its map kept through JSON; then another session of the same rig with the same specks on the window from its
first frame (`window_dust:start_s=0,over_s=0`, run 2: other noise) is tracked once by an estimator restored
from that map and once by one that starts from the sensor as calibrated (what a restart without it does).
Scored against the truth: frames not placed, frames flagged, rms error and its ratio to the rms bound, the
samples learned, and the size of the kept state.

    .venv/bin/python bench/sensor_map_restore.py
"""

from __future__ import annotations

import json

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.estimator.live import LiveEstimator
from graytrack.drivers.sim.scenarios import build_rig

SEEDS = (4, 5, 6)
LANDING = "window_dust"  # six specks landing between 1 and 7 s of the 10 s session
ON_THE_WINDOW = "window_dust:start_s=0,over_s=0"  # the same specks, there from the first frame


def session(model, recording, state=None) -> tuple[LiveEstimator, list]:
    live = LiveEstimator(model, float(recording.reference[0]), sensor_map=state)
    fixes = [live.update(recording.frames[k], float(recording.reference[k]), float(recording.t[k]))
             for k in range(len(recording.frames))]
    return live, fixes


def main() -> None:
    print("seed  learned  bytes  | restored: unplaced  flagged  rms µm  /bound | fresh: unplaced  flagged  rms µm  "
          "/bound  learned")
    for seed in SEEDS:
        calibration, _ = build_rig("paper", "", seed=seed).record(20.0)
        model = calibrate(calibration, "paper").model
        first, _ = build_rig("paper", LANDING, seed=seed, run=1).record(10.0)
        learner, _ = session(model, first)
        text = json.dumps(learner.sensor_map.state(), separators=(",", ":"))
        other, truth = build_rig("paper", ON_THE_WINDOW, seed=seed, run=2).record(10.0)
        row = f"{seed:4d}  {int(learner.sensor_map.learned().sum()):7d}  {len(text):5d}  |"
        for state in (json.loads(text), None):
            live, fixes = session(model, other, state)
            placed = np.array([fix.x_mm for fix in fixes])
            bound = np.array([fix.crlb_mm for fix in fixes]) * 1e3
            error = (placed - truth.x_mm) * 1e3
            flagged = np.mean([bool(fix.stale) for fix in fixes])
            rms = float(np.sqrt(np.nanmean(error ** 2)))
            row += (f" {100 * np.mean(~np.isfinite(error)):15.1f} % {100 * flagged:6.1f} % {rms:7.2f} "
                    f"{rms / float(np.sqrt(np.nanmean(bound ** 2))):6.2f}")
            if state is None:
                row += f"  {int(live.sensor_map.learned().sum()):7d}"
            else:
                row += " |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
