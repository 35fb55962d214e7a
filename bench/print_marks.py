"""Broad marks on the print over seeds, widths and depths, the estimator against today's path on the same runs.

A smudge (an ink stain, a finger) is a mark on the print as dust is, but wider than what a sample's own test
catches: its core fails where it is deep, its wings sit within each sample's noise and, over less than a period,
move the light's states and the position with them (docs/robustness.md, twenty-sixth session). Each run here is
calibrated clean and runs with a smudge coming into view mid-run (``drivers/sim/effects.py`` smudge: a Gaussian
darkening across the whole height), in every mode, tracked by the estimator and by today's path and scored frame by
frame against the rig's truth as ``estimator_sweep.py --against`` scores them (both errors over today's noise
floor; today's score kept in the cache).

    .venv/bin/python bench/print_marks.py [--seeds N] [--shard K/N] [--cache DIR] [--only TEXT] [name=value ...]

Per run: the estimator's error std over today's floor and today's, the share flagged, frames 4+ bounds off and
those unflagged, the print's nodes learned. The last lines: by mark and mode, the runs more than 5 % above today's
path, and the totals.
"""

from __future__ import annotations

from estimator_sweep import RATIO_KEPT, SILENT_SHARE, cached_case, level_scaled, scored, seeded_arguments, todays
from truth_score import MODES

# (a smudge's Gaussian σ, µm, and its depth at the centre): the sweep's (700 µm, 0.35), narrower and fainter ones
MARKS = ("smudge:width_um=700:depth=0.35", "smudge:width_um=700:depth=0.15", "smudge:width_um=300:depth=0.35",
         "smudge:width_um=300:depth=0.15", "smudge:width_um=1500:depth=0.25")
SCENARIOS = ("paper", "strip16")


def main() -> None:
    args, settings, shard, shards = seeded_arguments(__doc__, 2, "mark", "graytrack-marks")
    runs = [(scenario, mark, seed) for scenario in SCENARIOS for mark in MARKS
            for seed in range(1, args.seeds + 1) if args.only in f"{scenario} {mark}"]
    counted: dict[tuple[str, str], list[int]] = {}  # (mark, mode): [runs, above today's]
    placed = silent = above = 0
    for number, (scenario, mark, seed) in enumerate(runs):
        if number % shards != shard:
            continue
        model, run, truth = cached_case(args.cache, scenario, "", mark, seed)
        label = f"{scenario}  {mark} seed {seed}"
        for mode, options in MODES.items():
            grating = "none" if options["no_reference"] else ("fuse" if options["trim"] else "check")
            score = scored(level_scaled(model, args.level_scale), run, truth, grating, settings)
            today = todays(args.cache, model, run, truth, label, mode)
            ours = score["std"] / today.bound_um
            worse = ours > RATIO_KEPT * today.ratio
            placed += score["placed"]
            silent += score["silent"]
            above += worse
            tally = counted.setdefault((f"{scenario} {mark}", mode), [0, 0])
            tally[0] += 1
            tally[1] += worse
            marks = (" >>>" if worse else "") + (" <<<" if score["silent"] > SILENT_SHARE * max(score["placed"], 1)
                                                 else "")
            print(f"{label:50} {mode:15} on today's floor {ours:7.2f} today {today.ratio:6.2f} "
                  f"flag {100 * score['flagged'] / max(score['frames'], 1):5.1f}% far {score['far']:4d} "
                  f"silent {score['silent']:4d} (today's {today.silent:4d}) print {score['print']:4d}{marks}",
                  flush=True)
    if counted:
        print(f"more than {100 * (RATIO_KEPT - 1):.0f} % above today's path, by mark and mode (runs above / runs):")
        print(f"  {'':44}" + "".join(f"{mode:>16}" for mode in MODES))
        for case in dict.fromkeys(case for case, _ in counted):
            cells = [counted.get((case, mode)) for mode in MODES]
            print(f"  {case:44}" + "".join(f"{f'{cell[1]}/{cell[0]}' if cell else '-':>16}" for cell in cells))
        print(f"total: {sum(cell[0] for cell in counted.values())} runs (run x mode), {above} more than "
              f"{100 * (RATIO_KEPT - 1):.0f} % above today's path; unflagged 4+ bounds off {silent} of {placed} placed "
              f"frames")


if __name__ == "__main__":
    main()
