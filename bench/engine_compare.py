"""The two per-frame paths side by side: today's solver with its watches and the one recursive
estimator (`graytrack track --engine estimator`, core/estimator/), on the robustness sweep's cases
with the seed paper's model, each run scored frame by frame against the rig's truth in every mode
(grating read, ``--trim``, ``--no-reference``), and each timed in the same process.

For each case and mode: the error std over the rms bound (each engine's own bound: the watches'
noise floor, the estimator's posterior σ), frames lost, flagged, placed 4+ bounds off the truth and
those unflagged, and frames/s. The last lines total the unflagged far frames and the speed ratio.

    .venv/bin/python bench/engine_compare.py [CASE-SUBSTRING]
"""

from __future__ import annotations

import sys
import time

from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig
from robustness_sweep import CASES, SECONDS, measured_motion
from truth_score import MODES, scored

ENGINES = ("watches", "estimator")


def main(selection: str = "") -> None:
    totals = {engine: [0, 0, 0, 0.0, 0] for engine in ENGINES}  # placed, far, silent, seconds, frames
    models: dict[tuple[str, str], object] = {}
    print(f"{'case':70} {'mode':15} " + "  ".join(f"{engine:>62}" for engine in ENGINES))
    for scenario, rig_effects, later in CASES:
        label = f"{scenario} {rig_effects} {later}".strip()
        if selection not in label:
            continue
        seconds = SECONDS.get(scenario, 20.0)
        if (scenario, rig_effects) not in models:
            calibration, _ = build_rig(scenario, rig_effects, seed=3).record(seconds)
            models[scenario, rig_effects] = calibrate(calibration, "paper").model
        model = models[scenario, rig_effects]
        run_effects = ",".join(part for part in (rig_effects, later) if part)
        measured = build_rig(scenario, run_effects, seed=3, run=1)
        run, truth = measured.record(seconds / 2, measured_motion(measured, later, seconds / 2))
        for mode, options in MODES.items():
            cells = []
            for engine in ENGINES:
                started = time.perf_counter()
                score = scored(model, run, truth, engine=engine, **options)
                elapsed = time.perf_counter() - started
                total = totals[engine]
                total[0] += score.placed
                total[1] += score.far
                total[2] += score.silent
                total[3] += elapsed
                total[4] += score.frames
                flagged = 100 * score.flagged / score.frames
                cells.append(f"{score.ratio:6.2f}x lost {score.lost:4d} flagged {flagged:5.1f}"
                             f" % far {score.far:4d} silent {score.silent:4d} {score.frames / elapsed:7.0f}/s")
            print(f"{label[:70]:70} {mode:15} " + "  ".join(f"{cell:>62}" for cell in cells), flush=True)
    for engine, (placed, far, silent, elapsed, frames) in totals.items():
        print(f"{engine:10} placed {placed}, 4+ bounds off {far}, unflagged {silent} "
              f"({100 * silent / max(placed, 1):.3f} %); {frames / max(elapsed, 1e-9):.0f} frames/s over the runs")
    if all(totals[engine][3] for engine in ENGINES):
        speed = {engine: totals[engine][4] / totals[engine][3] for engine in ENGINES}
        ratio = speed["estimator"] / speed["watches"]
        print(f"estimator / watches frames/s (side by side, scoring included): {ratio:.2f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
