"""Clean runs, many of them: what the estimator learns and flags where nothing changes.

A steady rig must leave the sensor's map untouched (core/estimator/sensor_map.py: nothing landed, so
nothing learned) and the print's map without a mark learned (print_map.py), stay flagged on fewer than
1 % of its frames and state a bound its errors agree with (the rms of error over the frames' part of the
bound within 0.8–1.25: estimator_sweep.py ``pulls``).
One steady run a mode (bench/estimator_sweep.py) says little about a rate of false landings; this script
tracks clean runs of every scenario over several
seeds (each seed its own calibration and its own run), in each mode (grating read, ``--trim``,
``--no-reference``), scored frame by frame against the rig's truth:

    .venv/bin/python bench/steady_maps.py [--seeds N] [--shard K/N] [--cache DIR] [--only RIG] [name=value ...]

Per run: the error std over the noise floor, the rms pull over the whole bound and over the frames' part of it
(``tested``), the share flagged, frames 4+ bounds off
(and unflagged), the samples the sensor's map touched (something landed) and learned, the print's nodes
learned. The last lines: how
many runs touched or learned anything, the largest share flagged and the range of the tested pulls.
"""

from __future__ import annotations

from estimator_sweep import STEADY_FLAGGED, cached_case, level_scaled, scored, seeded_arguments
from truth_score import MODES

# seeds a scenario is run with at the default --seeds: 8 + 8 + 4 = 20 clean runs, each in three modes
# (the 16 × 128 lab strip costs four times a paper run; four of its seeds keep the script to minutes)
SCENARIOS = {"paper": 1.0, "strip16": 1.0, "lab": 0.5}


def main() -> None:
    # (--seeds: of a paper or strip16 run, the lab's half; --only: the scenarios whose name holds it)
    args, settings, shard, shards = seeded_arguments(__doc__, 8, "run", "graytrack-steady")
    runs = [(scenario, seed) for scenario, share in SCENARIOS.items() if args.only in scenario
            for seed in range(max(1, round(share * args.seeds)))]
    touched = learned = printed = flagged_runs = 0
    pulls, worst_flagged, scored_runs = [], 0.0, 0
    for number, (scenario, seed) in enumerate(runs):
        if number % shards != shard:
            continue
        model, run, truth = cached_case(args.cache, scenario, "", "", seed)
        for mode, options in MODES.items():
            grating = "none" if options["no_reference"] else ("fuse" if options["trim"] else "check")
            score = scored(level_scaled(model, args.level_scale), run, truth, grating, settings)
            share = score["flagged"] / max(score["frames"], 1)
            scored_runs += 1
            touched += score["touched"] > 0
            learned += score["map"] > 0
            printed += score["print"] > 0
            flagged_runs += share > STEADY_FLAGGED
            worst_flagged = max(worst_flagged, share)
            pulls.append(score["tested"])
            print(f"{scenario:8} seed {seed:2d} {mode:15} ratio {score['ratio']:5.2f} pull {score['pull']:5.2f} "
                  f"tested {score['tested']:5.2f} "
                  f"flag {100 * share:5.1f}% far {score['far']:4d} silent {score['silent']:4d} "
                  f"touched {score['touched']:3d} learned {score['map']:3d} print {score['print']:3d}", flush=True)
    if scored_runs:
        print(f"total: {scored_runs} clean runs (run x mode): the sensor's map touched on {touched}, learned on "
              f"{learned}; the print's map learned on {printed}; flagged on more than "
              f"{100 * STEADY_FLAGGED:.0f} % of the frames in {flagged_runs} "
              f"(largest {100 * worst_flagged:.1f} %); rms pull on the frames' part {min(pulls):.2f}-{max(pulls):.2f}")


if __name__ == "__main__":
    main()
