"""A cable's shadow across the field after calibration, several seeds and depths, scored against the truth.

Calibrated (`calibrate --model paper`) on a clean run of SCENARIO; each measured run has the shadow
pass twice (`moving_shadow:depth=D:passes=2:period_s=4`, starting at a time that varies with the
seed) and is tracked as `graytrack track` does (light auto, robust, learning; the camera-against-grating
check with the grating, and again without it). Per run: frames with the shadow in view, frames
flagged (all, and outside the shadow), frames lost, the error std against the truth over the clean
run's bound (all placed frames, the unflagged ones, those outside the shadow), and the placed frames
4+ bounds off the truth left unflagged.

    .venv/bin/python bench/shadow_sweep.py [SCENARIO] [DEPTHS, e.g. 0.2,0.33,0.5] [SEEDS, e.g. 1,2,3,4]
"""

from __future__ import annotations

import sys

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.commands.track_scale import check, scale_watch

SECONDS = 10.0
FAR = 4.0


def main(scenario: str = "paper", depths: str = "0.2,0.33,0.5", seeds: str = "1,2,3,4") -> None:
    calibration, _ = build_rig(scenario, "", seed=3).record(2 * SECONDS)
    model = calibrate(calibration, "paper").model
    clean, _ = build_rig(scenario, "", seed=3, run=1).record(SECONDS)
    clean_bound = float(np.sqrt(np.nanmean((track(model, clean, light="auto", robust=True).crlb_mm * 1e3) ** 2)))
    print(f"{scenario}: clean run's bound {clean_bound:.3f} µm")
    for depth in map(float, depths.split(",")):
        for seed in map(int, seeds.split(",")):
            rig = build_rig(scenario, f"moving_shadow:depth={depth}:passes=2:period_s=4:start_s={1.5 + 0.5 * seed}",
                            seed=seed, run=1)
            run, truth = rig.record(SECONDS)
            shown = rig.config.illumination.shadow.in_view(truth.t_s, rig.geometry.x_mm)
            for grating in (True, False):
                reference = run.reference if grating else np.full(run.n_frames, np.nan)
                watch = scale_watch(run, model, reference)  # as `track` does: its scale watch, learning on
                result = track(model, run.frames, reference=reference, x0_mm=run.reference[0], light="auto",
                               robust=True, learn=True, watches=[watch] if watch else [])
                flagged = result.stale | (check(run, model, result, False, watch).columns["scale_stale"] == 1)
                error = (result.x_mm - truth.x_mm) * 1e3
                placed = np.isfinite(error)
                silent = placed & ~flagged & (np.abs(error) > FAR * result.crlb_mm * 1e3)
                ratio = lambda where: np.nanstd(error[where]) / clean_bound  # noqa: E731
                label = "grating" if grating else "none   "
                print(f"depth {depth:4.2f} seed {seed} {label}: in view {shown.sum():3d}, flagged {flagged.sum():3d} "
                      f"({(flagged & ~shown).sum():3d} outside), lost {(~placed).sum():2d}, std/clean bound "
                      f"{ratio(placed):6.2f} (unflagged {ratio(~flagged):5.2f}, outside {ratio(~shown):5.2f}), "
                      f"far unflagged {silent.sum()} ({100 * silent.sum() / placed.sum():.2f} %)", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:4])
