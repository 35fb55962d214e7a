"""Shadows and veils the robustness sweep does not name, tracked by the estimator and scored against the truth.

The sweep's moving shadow and veil are one seed and one shape each; a band of shadow or veil followed as states
(core/estimator/filter.py) must hold beyond them. Two calibrations each of the paper rig and the 16-row strip,
each measured on: the sweep's shadow, a deeper narrower shadow crossing in 2 s, the sweep's veil, a deeper veil
over 60 % of the line from the other end, and a clean run; with the grating read and without it. Per run: the
error std over the noise floor, the rms pull, the share flagged, frames 4+ bounds off the truth and of them
unflagged; the last line their totals.

    .venv/bin/python bench/band_variants.py [name=value ...]

``name=value``: the estimator's tunables set as estimator_sweep.py sets them (an unknown name exits, naming the known).
"""

from __future__ import annotations

import sys

from estimator_sweep import scored, settings_of
from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig

CHANGES = ("moving_shadow:passes=2:period_s=4:start_s=2",
           "moving_shadow:depth=0.5:width_mm=2:pass_s=2:passes=2:period_s=4:start_s=1",
           "veil", "veil:cover=0.6:side=0:depth=0.3", "")
SEEDS = (4, 5)


def main() -> None:
    settings = settings_of(sys.argv[1:])
    far = silent = 0
    for scenario in ("paper", "strip16"):
        for seed in SEEDS:
            model = calibrate(build_rig(scenario, "", seed=seed).record(20.0)[0], "paper").model
            for later in CHANGES:
                run, truth = build_rig(scenario, later, seed=seed, run=1).record(10.0)
                for grating in ("check", "none"):
                    score = scored(model, run, truth, grating, settings)
                    far, silent = far + score["far"], silent + score["silent"]
                    print(f"{scenario:8} {seed} {later or 'clean':72} {grating:6} ratio {score['ratio']:6.2f} "
                          f"pull {score['pull']:5.2f} flag {100 * score['flagged'] / score['frames']:5.1f}% "
                          f"far {score['far']:4d} silent {score['silent']:3d} lost {score['lost']}", flush=True)
    print(f"total: 4+ bounds off {far}, of them unflagged {silent}")


if __name__ == "__main__":
    main()
