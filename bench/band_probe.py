"""What the shadow's band follower (core/moving_band.py) does to runs with no shadow in them.

Calibrated (`calibrate --model paper`) on a clean run of the paper rig; each measured run has one
other change after calibration (none, a smudge, dust settling, a lamp dimmed, glints, a new
vignetting or gradient, a blur, the magnification drifting, a pixel failing) and is tracked as
`graytrack track` does (its scale watch, learning on), with the grating and without it. Per run:
the error std against the truth over the clean run's bound, frames lost, flagged, flagged `light`
(a band's answers among them), and placed frames 4+ bounds off the truth left unflagged.

    .venv/bin/python bench/band_probe.py
"""

from __future__ import annotations

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.commands.track_scale import check, scale_watch

SECONDS = 10.0
FAR = 4.0
CASES = ["", "smudge:depth=0.35", "dust_settling", "light_change:gain=0.85:ambient_gray=8:start_s=2", "glints:p=0.15",
         "vignetting:edge=0.05", "gradient:per_10mm=0.05", "focus_drift:px=0.5",
         "magnification_drift:ppm=1500:ramp_s=10", "bad_pixels:stuck=1:dead=0:hot=0:row=0:pixel=40:start_s=2.5"]


def main() -> None:
    calibration, _ = build_rig("paper", "", seed=3).record(2 * SECONDS)
    model = calibrate(calibration, "paper").model
    clean, _ = build_rig("paper", "", seed=3, run=1).record(SECONDS)
    clean_bound = float(np.sqrt(np.nanmean((track(model, clean, light="auto", robust=True).crlb_mm * 1e3) ** 2)))
    for later in CASES:
        run, truth = build_rig("paper", later, seed=3, run=1).record(SECONDS)
        for grating in (True, False):
            reference = run.reference if grating else np.full(run.n_frames, np.nan)
            watch = scale_watch(run, model, reference)
            result = track(model, run.frames, reference=reference, x0_mm=float(run.reference[0]), light="auto",
                           robust=True, learn=True, watches=[watch] if watch else [])
            flagged = result.stale | (check(run, model, result, False, watch).columns["scale_stale"] == 1)
            error = (result.x_mm - truth.x_mm) * 1e3
            placed = np.isfinite(error)
            silent = placed & ~flagged & (np.abs(error) > FAR * result.crlb_mm * 1e3)
            print(f"{later or 'steady':60.60} {'grating' if grating else 'none   '}: std/clean bound "
                  f"{np.nanstd(error) / clean_bound:6.2f}, lost {(~placed).sum():3d}, flagged {flagged.sum():3d} "
                  f"(light {(result.stale_reason == 'light').sum():3d}), far unflagged {silent.sum()}", flush=True)


if __name__ == "__main__":
    main()
