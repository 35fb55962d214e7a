"""Rigs set up wrongly: what calibration, the closed loop and tracking make of them.

For each case a virtual rig whose recording declares nothing is calibrated (`calibrate --model
paper`, then `diagnose`) on one run; the verdict of the geometry check is printed with its cause,
and where a model comes out (or `--flip` gives one) another run is tracked with it: error std over
the rms of the frames' bounds, and the frames called locked.

    .venv/bin/python bench/geometry_cases.py [CASE-SUBSTRING]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis import diagnose
from graytrack.core.geometry_check import GeometryError
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

SECONDS = {"lab": 6.0, "strip16": 10.0}
# (scenario, effects, reverse the pixel axis before calibrating and tracking, as --flip does)
CASES = [
    ("paper", "", False),
    ("strip16", "", False),
    ("lab", "", False),
    ("paper", "mirrored", False),
    ("paper", "mirrored", True),
    ("lab", "mirrored", False),
    ("lab", "mirrored", True),
    ("paper", "pitch_scale:ppm=120000", False),
    ("paper", "pitch_scale:ppm=-400000", False),
    ("paper", "magnification:percent=20", False),
    ("paper", "off_target:share=0.3", False),
    ("strip16", "off_target:share=0:rows=4", False),
    ("paper", "smudge:depth=0.35", False),
]


def tracked(model, run) -> str:
    result = track(model, run, light="auto", robust=True)
    error = result.error_um(run.reference)
    bound = float(np.sqrt(np.nanmean(np.square(result.crlb_mm * 1e3))))
    return f"{np.nanstd(error) / bound:6.2f} ({np.nanstd(error):7.2f} µm), locked {result.locked.mean():4.0%}"


def main(selection: str = "") -> None:
    for scenario, rig_effects, flip in CASES:
        label = f"{scenario} {rig_effects or '-'}{' --flip' if flip else ''}"
        if selection not in label:
            continue
        started = time.perf_counter()
        seconds = SECONDS.get(scenario, 20.0)
        calibration, _ = build_rig(scenario, rig_effects, seed=3).record(seconds)
        run, _ = build_rig(scenario, rig_effects, seed=3, run=1).record(seconds / 2)
        if flip:
            calibration, run = calibration.flipped(), run.flipped()
        try:
            result = calibrate(calibration, "paper")
            check = result.geometry
            paper = (f"{check.status} ({check.cause or '-'}, rms {check.residual_ratio:.2f}x σ): "
                     f"{tracked(result.model, run)}")
        except GeometryError as exc:
            check = exc.check
            paper = f"REFUSED ({check.cause}, rms {check.residual_ratio:.1f}x σ)"
        loop = diagnose(calibration)
        verdict = loop.geometry
        closed = (f"REFUSED ({verdict.cause})" if loop.refused else
                  f"{verdict.status if verdict else 'ok'}: {tracked(loop.final_model, run)}")
        print(f"{label:42} paper: {paper:70} loop: {closed}  ({time.perf_counter() - started:.0f} s)", flush=True)
        if check.message:
            print(f"{'':42} {check.message}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
