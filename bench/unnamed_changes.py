"""Every effect the virtual rig knows, arriving after calibration: the changes no issue names.

The sweep (robustness_sweep.py) names the changes it tries after calibration: a light change, a shadow, dust, a
knock... An outside check tries the rest of the family. Here each effect of drivers/sim/effects.py at its defaults is
added to a rig calibrated without it (the paper rig and the 16-row strip, ``--scenarios``), as though it arrived
between calibration and the run (a print changed, a lens swapped, a sensor warmed, a camera's clock or link changed),
and the run is tracked by the estimator in every mode (grating read, ``--trim``, ``--no-reference``) and scored frame
by frame against the rig's truth as bench/estimator_sweep.py scores it.

The command refuses frames reversed against the model at the grating's positions before either engine tracks them
(``graytrack track``: a print mirrored); the bench tracks them anyway, as the library does. What it asks of each run
is the acceptance's "never silently wrong": ≤ 0.5 % of placed frames 4+ bounds off the truth
without a flag (marked ``<<<``). The error over the noise floor and the share flagged say what the change cost; a
change the model cannot follow may be flagged on every frame, and should be. With ``--against`` today's path is
scored on the same run (the ratio on today's floor, ``>>>`` where the estimator errs more than 5 % more).

    .venv/bin/python bench/unnamed_changes.py [--cache DIR] [--shard K/N] [--only TEXT] [--against]
        [--scenarios paper,strip16] [name=value ...]

Each run's model, run and truth are kept in the cache (``$TMPDIR/graytrack-unnamed``) the first time.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from estimator_sweep import FAR_PULL, RATIO_KEPT, SILENT_SHARE, cached_case, scored, settings_of, todays
from graytrack.core.errors import TrackingError
from graytrack.drivers.sim.effects import EFFECTS
from truth_score import MODES

GRATING = {"grating": "check", "--trim": "fuse", "--no-reference": "none"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "graytrack-unnamed",
                        help="where each run's model, run and truth (and today's score) are kept")
    parser.add_argument("--shard", default="0/1", help="K/N: every N-th run from the K-th (run N side by side)")
    parser.add_argument("--only", default="", help="the runs whose scenario and effect hold this text")
    parser.add_argument("--scenarios", default="paper,strip16", help="the rigs calibrated clean, comma-separated")
    parser.add_argument("--against", action="store_true", help="also score today's path on each run")
    parser.add_argument("settings", nargs="*", help="name=value of the estimator's tunables")
    args = parser.parse_args()
    settings = settings_of(args.settings)
    shard, shards = (int(part) for part in args.shard.split("/"))
    args.cache.mkdir(parents=True, exist_ok=True)
    runs = [(scenario, name) for scenario in args.scenarios.split(",") for name in sorted(EFFECTS)]
    silent_runs, worse, refused = [], [], []
    totals = dict.fromkeys(("placed", "far", "silent", "flagged", "frames", "lost"), 0)
    for number, (scenario, name) in enumerate(runs):
        label = f"{scenario} {name}"
        if args.only not in label or number % shards != shard:
            continue
        try:
            model, run, truth = cached_case(args.cache, scenario, "", name)
        except ValueError as error:  # an effect that cannot arrive on this rig (EffectError, ScenarioError)
            refused.append(f"{label}: {error}")
            print(f"{label:34} refused: {error}", flush=True)
            continue
        for mode, options in MODES.items():
            score = scored(model, run, truth, GRATING[mode], settings)
            for key in totals:
                totals[key] += score[key]
            silent = score["silent"] > SILENT_SHARE * max(score["placed"], 1)
            line = (f"{label:34} {mode:15} ratio {score['ratio']:7.2f} pull {score['pull']:5.2f} "
                    f"lost {score['lost']:4d} flag {100 * score['flagged'] / score['frames']:5.1f}% "
                    f"far {score['far']:4d} silent {score['silent']:4d}" + (" <<<" if silent else ""))
            if silent:
                silent_runs.append(line)
            if args.against:
                try:
                    today = todays(args.cache, model, run, truth, label, mode)
                except TrackingError as refusal:  # (today's path refuses what it cannot track: a reversed print)
                    line += f" | today refused: {str(refusal)[:60]}"
                else:
                    ours = score["std"] / today.bound_um
                    above = bool(np.isfinite(ours)) and ours > RATIO_KEPT * today.ratio
                    line += f" | on today's floor {ours:7.2f} today {today.ratio:7.2f} silent {today.silent:4d}" + \
                        (" >>>" if above else "")
                    if above:
                        worse.append(line)
            print(line, flush=True)
    placed = max(totals["placed"], 1)
    print(f"total: placed {totals['placed']}, {FAR_PULL:g}+ bounds off {totals['far']}, unflagged {totals['silent']} "
          f"({100 * totals['silent'] / placed:.3f} %), flagged {totals['flagged']} of {totals['frames']}, "
          f"lost {totals['lost']}; {len(refused)} effects refused")
    print(f"runs over {100 * SILENT_SHARE:.1f} % of their placed frames far off unflagged: {len(silent_runs)}")
    for line in silent_runs:
        print("  " + line)
    if args.against:
        print(f"runs more than {100 * (RATIO_KEPT - 1):.0f} % above today's path: {len(worse)}")


if __name__ == "__main__":
    sys.exit(main())
