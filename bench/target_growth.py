"""The camera against the grating on a print that grew after calibration, and on steady runs.

Calibrates the seed paper's model on one run of a virtual rig (20 s, 1,000 frames), then follows
another session (`--run 1`) with `graytrack track`'s monitor, with and without `--trim`. Prints,
per case: the frame of the first `scale` flag, the share of frames flagged, the error (rms against
the true stage position) over the rms of the frames' bounds for the whole run and for the frames
after the first flag, and the last window's line.

    .venv/bin/python bench/target_growth.py [paper|strip16] [CASE-SUBSTRING]
"""

from __future__ import annotations

import sys

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.reference_monitor import ReferenceMonitor, follow
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

CASES = [  # (effects of the measured run, seconds)
    ("", 10.0),
    ("vibration:um=2", 10.0),
    ("grating_resolution", 10.0),
    ("cyclic_error", 10.0),
    ("vibration:um=2,grating_resolution,cyclic_error", 30.0),
    ("target_growth:ppm=250", 10.0),
    ("target_growth:ppm=250:at=0", 10.0),
    ("target_growth:ppm=250", 30.0),
    ("target_growth:ppm=250:start_s=10", 30.0),
    ("target_growth:ppm=250:ramp_s=20", 30.0),
]


def main(scenario: str = "paper", selection: str = "") -> None:
    calibration, _ = build_rig(scenario, seed=3).record(20.0)
    model = calibrate(calibration, "paper").model
    print(f"{scenario}: calibration's own line: {model.info['reference_line']['scale_ppm']:+.1f} +/- "
          f"{model.info['reference_line']['scale_sigma_ppm']:.1f} ppm")
    print(f"{'measured run':48} {'s':>3} {'trim':>4} {'first flag':>10} {'flagged':>8} {'run':>6} {'after':>6}  last "
          "window")
    for effects, seconds in CASES:
        if selection not in effects:
            continue
        run, truth = build_rig(scenario, effects, seed=3, run=1).record(seconds)
        result = track(model, run, light="auto", robust=True)
        bound = float(np.sqrt(np.nanmean(np.square(result.crlb_mm)))) * 1e3
        for trim in (False, True):
            monitor = ReferenceMonitor.for_model(model, float(run.meta.get("grating_resolution_mm", 0.0)))
            followed = follow(monitor, result.x_mm, run.reference, result.crlb_mm, result.locked, trim=trim)
            error = (followed.x_mm - truth.x_mm) * 1e3
            first = int(np.argmax(followed.stale)) if followed.stale.any() else None
            after = error[first:] if first is not None else error[:0]
            line = followed.final
            print(f"{effects or '-':48} {seconds:3.0f} {'on' if trim else 'off':>4} "
                  f"{first if first is not None else '-':>10} "
                  f"{100 * followed.stale.mean():7.1f}% {np.sqrt(np.nanmean(error ** 2)) / bound:6.2f} "
                  f"{np.sqrt(np.nanmean(after ** 2)) / bound if after.size else float('nan'):6.2f}  "
                  f"{line.scale_ppm:+.0f} +/- {line.scale_sigma_ppm:.0f} ppm, {line.offset_um:+.3f} +/- "
                  f"{line.offset_sigma_um:.3f} um", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:3])
