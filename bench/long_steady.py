"""Steady runs six times the sweep's length, tracked by the estimator in every mode, scored quarter by quarter.

Nothing changes after calibration, yet a state no frame sees (the camera's place on the carriage, the lens's
stretch times the optical axis's lever, without the grating) drifts in the posterior at its declared rate, and
the bound grows with it; the sweep's runs (bench/estimator_sweep.py: 10 s on the paper rig) are too short to
show what that does to the flags. Each rig of the sweep (paper, 16 rows, the lab strip) is calibrated as the
sweep does (its cached model) and run for ``--times`` its measured run's length; per mode and quarter of the
run: the share of frames flagged, the rms pull (error over the stated bound, and over the frames' part of it:
estimator_sweep.py ``pulls``), the median bound over the noise
floor and the placed frames 4+ bounds off the truth without a flag. The acceptance asks a steady run for
flagged < 1 % and a pull within 0.8-1.25 throughout.

    .venv/bin/python bench/long_steady.py [--cache DIR] [--times N] [--only RIG] [name=value ...]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
from pathlib import Path

import numpy as np

from estimator_sweep import (CACHE_VERSION, FAR_PULL, STEADY_FLAGGED, STEADY_PULL, cached_case, pulls, settings_of,
                             tracked)
from graytrack.drivers.sim.scenarios import build_rig
from robustness_sweep import SECONDS
from truth_score import MODES

RIGS = ("paper", "strip16", "lab")
QUARTERS = 4


def long_run(folder: Path, scenario: str, times: float):
    """(model, run, truth): the sweep's calibrated model of ``scenario`` and a steady run ``times`` the sweep's
    measured run's length (kept in ``folder`` once made)."""
    model, _, _ = cached_case(folder, scenario, "", "")
    seconds = SECONDS.get(scenario, 20.0) / 2 * times
    label = f"long {scenario} {seconds:g} s"
    path = folder / f"{hashlib.md5((CACHE_VERSION + label).encode()).hexdigest()[:10]}.pkl"
    if path.exists():
        with open(path, "rb") as kept:
            run, truth = pickle.load(kept)
    else:
        run, truth = build_rig(scenario, "", seed=3, run=1).record(seconds)
        with open(path, "wb") as kept:
            pickle.dump((run, truth), kept)
    return model, run, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "graytrack-sweep",
                        help="where each rig's model and run are kept (the sweep's cache serves)")
    parser.add_argument("--times", type=float, default=6.0, help="the run's length over the sweep's measured run's")
    parser.add_argument("--only", default="", help="rigs whose name holds this text")
    parser.add_argument("settings", nargs="*", help="name=value of the estimator's tunables")
    args = parser.parse_args()
    settings = settings_of(args.settings)
    args.cache.mkdir(parents=True, exist_ok=True)
    outside = 0
    for scenario in RIGS:
        if args.only not in scenario:
            continue
        model, run, truth = long_run(args.cache, scenario, args.times)
        for mode, options in MODES.items():
            grating = "none" if options["no_reference"] else ("fuse" if options["trim"] else "check")
            _, _, frames = tracked(model, run, truth, grating, settings)
            error, bound, floor, stale, slide = (frames[key] for key in ("error", "bound", "floor", "stale", "slide"))
            cells = []
            for part in np.array_split(np.arange(error.size), QUARTERS):
                placed = part[np.isfinite(error[part])]
                pull, tested = pulls(error[placed], bound[placed], slide[placed])
                flagged = float(stale[part].mean())
                silent = int(((np.abs(error[placed]) > FAR_PULL * bound[placed]) & ~stale[placed]).sum())
                widened = float(np.median(bound[placed] / floor[placed])) if placed.size else np.nan
                honest = flagged <= STEADY_FLAGGED and STEADY_PULL[0] <= tested <= STEADY_PULL[1] and not silent
                outside += not honest
                cells.append(f"{100 * flagged:5.1f}% {pull:4.2f}/{tested:4.2f} {widened:4.1f}x {silent:3d}"
                             + (" " if honest else "*"))
            print(f"{scenario:8} {run.t[-1] - run.t[0]:5.1f} s {mode:15} " + " | ".join(cells), flush=True)
    print(f"quarters: flagged share, rms pull over the whole bound/the frames' part, median bound over the noise "
          f"floor, unflagged {FAR_PULL:g}+ bounds off; "
          f"{outside} quarters outside the acceptance (*)")


if __name__ == "__main__":
    main()
