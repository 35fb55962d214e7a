"""The closed loop on 16-row strips with dust, judged as the instrument tracks: plainly and robustly.

For each case: a calibration recording, `diagnose` on it, and a second run of the same rig tracked
by the loop's model both ways (robust = `graytrack track` and the daemon's default), against the
noise floor of the same frames. A model that holds the dust only in part leaves the two apart.

    .venv/bin/python bench/lab_dust.py [SUBSTRING]    (about 5 min a case on a quiet 2-core machine)
"""

from __future__ import annotations

import sys
import time

import numpy as np

from graytrack.core.diagnosis import diagnose
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

CASES = [  # (label, scenario, rig effects, calibration seconds, run seconds)
    ("lab 16x128, 12 bit, vibration, PRNU, gradient, 6 dust spots", "lab",
     "photon_transfer:full_well=20000:read_e=6:bits=12:black_gray=4,vibration:um=1:hz=120,prnu:sigma=0.01,"
     "gradient:per_10mm=0.05,dust:count=6", 3.0, 5.0),
    ("strip 16x100, 8 dust spots of 60 µm", "strip16", "dust:count=8:size_um=60", 6.0, 3.0),
    ("lab 16x128 as built", "lab", "", 3.0, 5.0),
]


def main(selection: str = "") -> None:
    print(f"{'case':62} {'loop added':44} {'robust µm':>9} {'plain µm':>9} {'bound µm':>9} {'loop s':>7}")
    for label, scenario, effects, calibration_s, run_s in CASES:
        if selection not in label:
            continue
        calibration, _ = build_rig(scenario, effects, seed=3).record(calibration_s)
        run, _ = build_rig(scenario, effects, seed=3, run=1).record(run_s)
        started = time.perf_counter()
        loop = diagnose(calibration)
        seconds = time.perf_counter() - started
        errors, bound = {}, float("nan")
        for robust in (True, False):
            result = track(loop.final_model, run, light="auto", robust=robust)
            error = result.error_um(run.reference)
            errors[robust] = float(np.sqrt(np.mean(error[np.isfinite(error)] ** 2)))
            bound = float(np.sqrt(np.nanmean(result.crlb_mm**2)) * 1e3)
        added = ", ".join(step.effect for step in loop.steps) or "nothing"
        print(f"{label:62.62} {added:44.44} {errors[True]:9.3f} {errors[False]:9.3f} {bound:9.3f} {seconds:7.0f}",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
