"""A live frame's two routes side by side: reloaded in place (the lean path) against prepared anew.

`LiveTracker.update` reads a frame into one preallocated line and reloads one batch in place when
the model's weights do not follow the signal (core/tracking.py); otherwise, or when it is told
not to, every frame goes through `FourierModel.prepare` and a batch built anew. Both give the same
positions and verdicts (tests/core/test_kernels.py); this prints what the lean one saves, the two
trackers interleaved frame by frame on the same frames (CPU time of this thread, p50 µs, the first
frames not counted), and the largest difference of their positions.

Cases: the daemon's 16-row strip rig (`strip16`, PRNU and tilt: the model `bench/stream_latency.py`
streams) with the closed loop's model and the seed paper's; then the 16-row effect families.

    .venv/bin/python bench/live_routes.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from graytrack.core.calibration import calibrate  # noqa: E402
from graytrack.core.diagnosis import diagnose  # noqa: E402
from graytrack.core.tracking import LiveTracker  # noqa: E402
from graytrack.drivers.sim.causes import EVERY_FORM  # noqa: E402
from graytrack.service.grown_models import model_with  # noqa: E402
from graytrack.drivers.sim.scenarios import build_rig  # noqa: E402

CLOCK = time.thread_time
WARM_FRAMES = 50
STRIP_EFFECTS = "prnu:sigma=0.02,tilt:deg=2"
FAMILIES = ("rows", "target_map:rows")  # the effect families whose models see 16 rows


def compare(model, frames: np.ndarray, reference: np.ndarray) -> tuple[float, float, float, bool]:
    """(lean p50 µs, prepared p50 µs, max |Δx| µm, lean path taken) on the same frames, interleaved."""
    lean = LiveTracker(model, x0_mm=float(reference[0]))
    prepared = LiveTracker(model, x0_mm=float(reference[0]))
    prepared._lean = False
    costs: dict[str, list[float]] = {"lean": [], "prepared": []}
    positions: dict[str, list[float]] = {"lean": [], "prepared": []}
    for k, (frame, grating) in enumerate(zip(frames, reference)):
        for name, tracker in (("lean", lean), ("prepared", prepared)):
            started = CLOCK()
            fix = tracker.update(frame, grating)
            if k >= WARM_FRAMES:
                costs[name].append(CLOCK() - started)
            positions[name].append(fix.x_mm)
    difference = np.abs(np.subtract(positions["lean"], positions["prepared"]))
    return (float(np.median(costs["lean"])) * 1e6, float(np.median(costs["prepared"])) * 1e6,
            float(np.nanmax(difference, initial=0.0)) * 1e3, lean._lean)


def main() -> None:
    print(f"{'case':58} {'lean p50 µs':>12} {'prepared p50 µs':>16} {'ratio':>6} {'max |Δx| µm':>12}")
    calibration, _ = build_rig("strip16", STRIP_EFFECTS, seed=3).record(3.0)
    loop = diagnose(calibration)
    run, _ = build_rig("strip16", STRIP_EFFECTS, seed=3, run=1).record(4.0)
    added = ",".join(step.effect for step in loop.steps) or "nothing"
    cases = [(f"strip16 {STRIP_EFFECTS}: closed loop ({added})", loop.final_model, run),
             (f"strip16 {STRIP_EFFECTS}: seed paper's model", calibrate(calibration, "paper").model, run)]
    for name in FAMILIES:
        model, _, _ = model_with(name, pitch_search=True)
        cause = EVERY_FORM[name]
        family_run, _ = build_rig(cause.scenario, cause.effects, seed=5, run=1).record(4.0)
        cases.append((f"effect {name} ({cause.effects})", model, family_run))
    for label, model, recording in cases:
        lean, prepared, difference, taken = compare(model, recording.frames, recording.reference)
        note = "" if taken else "  (weights follow the signal: prepared either way)"
        print(f"{label:58.58} {lean:12.1f} {prepared:16.1f} {lean / prepared:6.2f} {difference:12.1e}{note}",
              flush=True)


if __name__ == "__main__":
    main()
