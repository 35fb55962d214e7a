"""A daemon restarted on the same model, with and without the marks it had learned on the print
(service/daemon/texture_store.py keeps them in DATA/texture.json; core/texture.py's state/from_state).

Per seed: a clean calibration run (`calibrate --model paper`); a live tracker (as the daemon runs it)
learns on a dusty session (`dust_settling`, run 1), its marks kept through JSON; then another session
of the same dusty rig (run 2: the same specks, other noise) is tracked from frame START on, when every
speck has landed, once by a tracker restored from those marks and once by one that starts from the
print as calibrated (what a restart without them does). Scored against the truth: frames lost, rms
error, and the size of the kept state.

    .venv/bin/python bench/texture_restore.py
"""

from __future__ import annotations

import json

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import LiveTracker
from graytrack.drivers.sim.scenarios import build_rig

SEEDS = (4, 5, 6)
START = 400  # of 500 frames: the dust has landed (it lands between 0.5 and 8.5 s of the 10 s session)


def main() -> None:
    print("seed  marks  bytes   restored: lost  rms µm   fresh: lost  rms µm")
    for seed in SEEDS:
        calibration, _ = build_rig("paper", "", seed=seed).record(20.0)
        model = calibrate(calibration, "paper").model
        run, _ = build_rig("paper", "dust_settling", seed=seed, run=1).record(10.0)
        live = LiveTracker(model, x0_mm=float(run.reference[0]))
        for frame, reference in zip(run.frames, run.reference):
            live.update(frame, float(reference))
        text = json.dumps(live.state.texture.state(), separators=(",", ":"))
        other, truth = build_rig("paper", "dust_settling", seed=seed, run=2).record(10.0)
        figures = []
        for texture in (json.loads(text), None):
            tracker = LiveTracker(model, x0_mm=float(other.reference[START]), texture=texture)
            placed = np.array([tracker.update(other.frames[k], float(other.reference[k])).x_mm
                               for k in range(START, len(other.frames))])
            error = (placed - truth.x_mm[START:]) * 1e3
            figures += [100.0 * np.mean(~np.isfinite(error)), float(np.sqrt(np.nanmean(error**2)))]
        print(f"{seed:4d}  {len(live.state.texture.learned):5d}  {len(text):5d}   "
              f"{figures[0]:9.1f} % {figures[1]:7.2f}   {figures[2]:7.1f} % {figures[3]:7.2f}", flush=True)


if __name__ == "__main__":
    main()
