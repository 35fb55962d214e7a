"""The estimator's speed where the rig changes against a steady run of the same camera, side by side.

For each rig of the robustness sweep (bench/robustness_sweep.py) and each change it makes after
calibration (a veil, a moving shadow, dust landing, a knock, a light switched, ...), the same model
tracks the changing run and a steady run of the same camera and length with the one recursive
estimator (core/estimator/), in every grating mode; each timed in CPU time of this process, best of
a few, the changing and the steady run interleaved. Printed: frames/s of both, their ratio (the
changing run's over the steady run's: the acceptance asks ≥ 1/3), and the seconds a 3,000-frame
recording of the changing run would take. The last line: the slowest ratio and recording.

    .venv/bin/python bench/changing_rig_speed.py [CASE-SUBSTRING]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import track
from graytrack.core.timing import model_reference
from graytrack.drivers.sim.scenarios import build_rig
from robustness_sweep import CASES, SECONDS, measured_motion

REPEATS = 3
CLOCK = time.process_time
GRATINGS = ("check", "fuse", "none")  # the grating read, --trim, --no-reference


def seconds_per_frame(model, run, grating: str) -> float:
    reference = run.reference
    if float(model.info.get("reference_skew_s", 0.0)):
        reference = model_reference(model, run.t, reference)
    start = CLOCK()
    track(model, run.frames, run.t, reference, grating=grating)
    return (CLOCK() - start) / run.frames.shape[0]


def main(selection: str = "") -> None:
    worst_ratio, worst_recording = (np.inf, ""), (0.0, "")
    print(f"{'case':64} {'mode':6} {'steady/s':>9} {'changing/s':>11} {'ratio':>6} {'3,000 frames':>13}")
    for scenario in dict.fromkeys(case[0] for case in CASES):
        changes = [later for rig_effects_, later in ((c[1], c[2]) for c in CASES if c[0] == scenario)
                   if not rig_effects_ and later and selection in f"{scenario} {later}"]
        if not changes:
            continue
        seconds = SECONDS.get(scenario, 20.0)
        calibration, _ = build_rig(scenario, "", seed=3).record(seconds)
        model = calibrate(calibration, "paper").model
        steady, _ = build_rig(scenario, "", seed=3, run=1).record(seconds / 2)
        for later in changes:
            rig = build_rig(scenario, later, seed=3, run=1)
            motion = measured_motion(rig, later, seconds / 2)
            run, _ = rig.record(seconds / 2, trajectory=motion)
            calm = steady
            if motion is not None:  # the same camera standing still between moves: its own steady run
                calm_rig = build_rig(scenario, "", seed=3, run=1)
                calm, _ = calm_rig.record(seconds / 2, trajectory=measured_motion(calm_rig, later, seconds / 2))
            for grating in GRATINGS:
                seconds_per = {"steady": np.inf, "changing": np.inf}
                for _ in range(REPEATS):  # interleaved: the machine's load falls on both alike
                    seconds_per["steady"] = min(seconds_per["steady"], seconds_per_frame(model, calm, grating))
                    seconds_per["changing"] = min(seconds_per["changing"], seconds_per_frame(model, run, grating))
                ratio = seconds_per["steady"] / seconds_per["changing"]
                recording = 3000 * seconds_per["changing"]
                label = f"{scenario} {later}"
                worst_ratio = min(worst_ratio, (ratio, f"{label} {grating}"))
                worst_recording = max(worst_recording, (recording, f"{label} {grating}"))
                print(f"{label[:64]:64} {grating:6} {1 / seconds_per['steady']:9.0f} "
                      f"{1 / seconds_per['changing']:11.0f} {ratio:6.2f} {recording:12.1f}s", flush=True)
    print(f"slowest against its steady run: {worst_ratio[0]:.2f} ({worst_ratio[1]}); "
          f"longest 3,000-frame recording: {worst_recording[0]:.1f} s ({worst_recording[1]})")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
