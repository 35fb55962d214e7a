"""Print texture learned while tracking (core/texture.py): dust settling during a run, and steady runs.

For each case and seed: a calibration run of the virtual rig (`calibrate --model paper`), a second
session with dust landing on the print one by one (`dust_settling`, its strength as given), and the
same session without it; both tracked as `graytrack track` does (light auto, robust, learning on).
Scored against the truth (the rig's true position), not the grating, which vouches for the marks'
places. Printed: frames lost, rms error over the clean run's bound, frames flagged, placed frames
4+ of their bounds off without a flag, and what was learned (marks; candidates opened). The steady
rows (no dust) give the false-learning rate: marks learned where nothing landed.

    .venv/bin/python bench/texture_learning.py [CASE-SUBSTRING] [--no-reference]
    .venv/bin/python bench/texture_learning.py live     (the live tracker's time a frame, learning or not)
"""

from __future__ import annotations

import sys
import time

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import LiveTracker, track
from graytrack.drivers.sim.scenarios import build_rig

SEEDS = (3, 4, 5, 6, 7)
CASES = [  # (scenario, what changes in the measured run, seeds)
    ("paper", "dust_settling", SEEDS),
    ("paper", "dust_settling:count=50", SEEDS[:3]),
    ("paper", "dust_settling:depth=0.3", SEEDS[:3]),
    ("strip16", "dust_settling", SEEDS[:3]),
    ("paper", "", SEEDS + (8,)),
    ("strip16", "", SEEDS[:3]),
    ("paper", "glints:p=0.15", SEEDS[:3]),
    ("paper", "bad_pixels:stuck=1:dead=0:hot=0:row=0:pixel=40:start_s=2.5", SEEDS[:3]),
]
FAR_PULL = 4.0


def scored(model, run, truth, no_reference: bool = False) -> tuple[int, float, int, int, dict]:
    """(frames lost, rms error µm against the truth, frames flagged, placed frames 4+ bounds off
    unflagged, what the run learned). ``no_reference``: no grating read (the marks' places are then
    the frames' own; the origin known up to whole periods, which the score takes out)."""
    if no_reference:
        result = track(model, run.frames, reference=np.full(run.n_frames, np.nan), light="auto", robust=True,
                       learn=True)
    else:
        result = track(model, run, light="auto", robust=True, learn=True)
    error = (result.x_mm - truth.x_mm) * 1e3
    if no_reference:
        period_um = model.period_mm * 1e3
        error -= period_um * np.round(np.nanmedian(error) / period_um)
    placed = np.isfinite(error)
    far = placed & (np.abs(np.where(placed, error, 0.0)) > FAR_PULL * result.crlb_mm * 1e3)
    return (int((~placed & ~result.repeated).sum()), float(np.sqrt(np.mean(error[placed] ** 2))),
            int(result.stale.sum()), int((far & ~result.stale).sum()), result.texture)


def main(selection: str = "", no_reference: bool = False) -> None:
    print(f"{'scenario':8} {'measured run':58} {'seed':>4} {'lost':>5} {'rms/clean bound':>17} {'flagged':>7} "
          f"{'silent':>6} {'learned':>7} {'opened':>6}")
    for scenario, later, seeds in CASES:
        if selection not in f"{scenario} {later}":
            continue
        for seed in seeds:
            calibration, _ = build_rig(scenario, "", seed=seed).record(20.0)
            model = calibrate(calibration, "paper").model
            clean, clean_truth = build_rig(scenario, "", seed=seed, run=1).record(10.0)
            clean_bound = float(np.sqrt(np.nanmean(np.square(
                track(model, clean, light="auto", robust=True).crlb_mm * 1e3))))
            run, truth = build_rig(scenario, later, seed=seed, run=1).record(10.0) if later else (clean, clean_truth)
            lost, rms, flagged, silent, learned = scored(model, run, truth, no_reference)
            print(f"{scenario:8} {later or '-':58.58} {seed:4d} {lost:5d} {rms:7.3f}/{clean_bound:.3f}="
                  f"{rms / clean_bound:4.2f} {flagged:7d} {silent:6d} {learned['learned']:7d} {learned['opened']:6d}",
                  flush=True)


def live_cost(seed: int = 3) -> None:
    """The daemon's tracker (LiveTracker) frame by frame on a steady and a dust-settling paper run,
    learning and not: the best of three passes, µs a frame, and its rms error against the truth
    over the clean run's bound."""
    calibration, _ = build_rig("paper", "", seed=seed).record(20.0)
    model = calibrate(calibration, "paper").model
    clean, _ = build_rig("paper", "", seed=seed, run=1).record(10.0)
    clean_bound = float(np.sqrt(np.nanmean(np.square(track(model, clean, light="auto", robust=True).crlb_mm * 1e3))))
    for later in ("", "dust_settling"):
        run, truth = build_rig("paper", later, seed=seed, run=1).record(10.0)
        for learn in (False, True):
            best, placed = np.inf, np.full(run.n_frames, np.nan)
            for _ in range(3):
                tracker = LiveTracker(model, x0_mm=float(run.reference[0]), learn=learn)
                started = time.perf_counter()
                for k, (frame, reference) in enumerate(zip(run.frames, run.reference)):
                    placed[k] = tracker.update(frame, float(reference)).x_mm
                best = min(best, (time.perf_counter() - started) / run.n_frames)
            error = (placed - truth.x_mm) * 1e3
            print(f"paper {later or 'steady':14} learn={learn!s:5} {best * 1e6:7.0f} us a frame, "
                  f"lost {int(np.isnan(error).sum())}, rms {np.sqrt(np.nanmean(error**2)) / clean_bound:.2f}x "
                  "the clean bound", flush=True)


if __name__ == "__main__":
    if sys.argv[1:] == ["live"]:
        live_cost()
    else:
        words = [word for word in sys.argv[1:] if word != "--no-reference"]
        main(words[0] if words else "", "--no-reference" in sys.argv[1:])
