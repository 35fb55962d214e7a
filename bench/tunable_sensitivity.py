"""How far each sweep run's figures turn on the estimator's own tunables: the runs on a knife's edge.

A declared rate is a physical judgement, good to a factor of two at best; a run whose error moves several-fold when
one rate is set half as high again (or two thirds as high) is not measured by its figure at the declared value, and
a rig a little unlike the simulated one meets its other outcome. Every case of the robustness sweep
(estimator_sweep.py's, its cache shared) is tracked in each mode at the settings given (name=value, else the
declared) and with each of the chosen tunables scaled by 1/F and by F, one at a time. Per run: the error over the
noise floor at the settings given, its least and most over the scaled ones (with the tunable and factor of the
most), the worst rms pull and the most placed frames 4+ bounds off the truth unflagged. A run is marked ``edge``
where its most error is more than ``EDGE_SPREAD`` times its least and above the noise floor, or where a scaled
setting leaves more frames far off unflagged than the settings given do.

    .venv/bin/python bench/tunable_sensitivity.py [--only SUBSTRING] [--shard K/N] [--factor F]
        [--tunables a,b,...] [--modes grating,--trim,--no-reference] [--each] [--cache DIR] [name=value ...]
"""

from __future__ import annotations

import sys

import numpy as np

from estimator_sweep import PLAIN, cached_case, scored, settings_of, sweep_parser
from graytrack.core.estimator.settings import TUNABLES
from robustness_sweep import CASES
from truth_score import MODES

# the rates of the states every frame updates, each a judgement of how fast something drifts (the false-alarm rate,
# the iteration limits and the priors of a first frame are no such judgement; others by --tunables)
RATES = ("gain_rate", "offset_rate", "light_switch_rate", "field_rate", "focus_rate", "stretch_rate")
FACTOR = 1.5  # a declared rate is good to about this factor either way
EDGE_SPREAD = 2.0  # a run's most error over its least, over the scaled settings, beyond which it sits on an edge
GRATING_OF = {"grating": "check", "--trim": "fuse", "--no-reference": "none"}


def main() -> None:
    parser = sweep_parser(__doc__)
    parser.add_argument("--factor", type=float, default=FACTOR, help="each tunable scaled by 1/F and by F")
    parser.add_argument("--tunables", default=",".join(RATES), help="comma-separated names of the tunables scaled")
    parser.add_argument("--modes", default=",".join(MODES), help="comma-separated modes run")
    parser.add_argument("--each", action="store_true", help="also print each scaled setting's figures")
    parser.add_argument("settings", nargs="*", help="name=value of the estimator's tunables scaled about")
    args = parser.parse_args()
    names = [name for name in args.tunables.split(",") if name]
    unknown = [name for name in names if name not in TUNABLES]
    if unknown:
        sys.exit(f"unknown estimator setting(s) {', '.join(unknown)}; known: {', '.join(TUNABLES)}")
    modes = [mode for mode in args.modes.split(",") if mode]
    if any(mode not in MODES for mode in modes):
        sys.exit(f"modes are among {', '.join(MODES)}")
    if not args.factor > 1.0:
        sys.exit("--factor must be above 1")
    shard, shards = (int(part) for part in args.shard.split("/"))
    args.cache.mkdir(parents=True, exist_ok=True)
    declared = settings_of(args.settings)
    variants = [(f"{name}×{scale:.2g}", declared.replace(**{name: getattr(declared, name) * scale}))
                for name in names for scale in (1.0 / args.factor, args.factor)]
    edges = runs = 0
    for number, (scenario, rig_effects, later) in enumerate(CASES + PLAIN):
        label = f"{scenario} {rig_effects} {later}"
        if args.only not in label or number % shards != shard:
            continue
        model, run, truth = cached_case(args.cache, scenario, rig_effects, later)
        for mode in modes:
            base = scored(model, run, truth, GRATING_OF[mode], declared)
            ratios, pulls, silent = [], [], []
            for name, variant in variants:
                score = scored(model, run, truth, GRATING_OF[mode], variant)
                if args.each:
                    print(f"    {name:>24} ratio {score['ratio']:7.2f} pull {score['pull']:6.2f} "
                          f"flag {100 * score['flagged'] / score['frames']:5.1f}% silent {score['silent']:3d}")
                ratios.append(score["ratio"])
                pulls.append(score["pull"])
                silent.append(score["silent"])
            ratios_all = np.array([base["ratio"], *ratios])
            worst = int(np.nanargmax(ratios)) if np.isfinite(ratios).any() else 0
            spread = float(np.nanmax(ratios_all) / np.nanmin(ratios_all)) if np.isfinite(ratios_all).any() else 1.0
            # (a run whose every outcome stays within its noise floor, as the grating fused holds one, is on no edge
            # that matters however its small error spreads)
            edge = (spread > EDGE_SPREAD and float(np.nanmax(ratios_all)) > 1.0) or \
                max(silent, default=0) > base["silent"]
            runs += 1
            edges += edge
            print(f"{label[:66]:66} {mode:15} ratio {base['ratio']:6.2f} least {np.nanmin(ratios_all):6.2f} "
                  f"most {np.nanmax(ratios_all):7.2f} ({variants[worst][0]:>22}) pull {base['pull']:5.2f} "
                  f"worst {np.nanmax(pulls):5.2f} silent {base['silent']:3d} most {max(silent, default=0):3d}"
                  + (" edge" if edge else ""), flush=True)
    print(f"total: {runs} runs, {edges} on an edge (error spread over {EDGE_SPREAD}x and above the floor, or more "
          f"frames far off unflagged than at the declared settings) with {len(names)} tunables scaled by "
          f"1/{args.factor:g} and {args.factor:g}")


if __name__ == "__main__":
    main()
