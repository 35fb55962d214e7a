"""The estimator alone over the robustness sweep's cases, fast enough to try a change of it in a minute.

Every case of bench/robustness_sweep.py with the seed paper's model, tracked by the one recursive
estimator (core/estimator/) in each mode (grating read, ``--trim``, ``--no-reference``) and scored
frame by frame against the rig's truth, as bench/engine_compare.py scores it, without today's path
beside it. Each case's model, run and truth are kept in a cache folder the first time (a few minutes
for the whole sweep), so a later run costs the tracking only (~15 s of CPU).

Tunables are set with ``name=value`` arguments (core/estimator/settings.py), e.g. to try a rate:

    .venv/bin/python bench/estimator_sweep.py [--cache DIR] [--shard K/N] [--only SUBSTRING] [--against]
        [--level-scale S] [name=value ...]

``--level-scale 0.99`` (and 1.01) holds the frames against a calibration χ² level 1 % off: a change no physics would
notice, so the runs it moves beyond 5 % are those whose figures turn on chance (compared with
bench/sweep_diff.py); a try that moves only those has shown nothing.

Per run: the error std over the rms noise floor, the rms pull (error over the stated bound) and the same over the
frames' part of the bound (``tested``: less the lens's slide it states without the grating, ``pulls``), frames
lost, the share flagged, placed frames 4+ bounds off the truth and those unflagged (marked ``<<<``
where they pass 0.5 % of the run's placed frames), the samples the sensor's map holds a change for at the
end (core/estimator/sensor_map.py) and the print's nodes (print_map.py). The last lines: the totals and the steady runs
(nothing changed after calibration, each rig of the sweep plain as well: the acceptance's flagged < 1 % with nothing
learned and an rms pull within 0.8-1.25 on the frames' part of the bound), those outside it marked.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import filter as estimator
from graytrack.core.estimator.settings import TUNABLES, EstimatorSettings
from graytrack.core.recording import acceleration_phases
from graytrack.core.timing import model_reference
from graytrack.drivers.sim.scenarios import build_rig
from robustness_sweep import CASES, SECONDS, measured_motion
from truth_score import MODES
from truth_score import scored as path_scored

CACHE_VERSION = "25"  # what a cached case holds: 3, recordings that state the stage's commanded phases of acceleration
# and models what their calibration's readings showed beyond them (core/estimator/mount.py); 4, recordings that state
# what triggers the camera (core/recording.py CAMERA_TRIGGER); 5, models that state how widely their frames' χ²
# scatters (core/chi2_curve.py frame_spread); 6, and a strip's row banding (core/adequacy.py row_offset_gray); 7, the
# offset each frame draws afresh (core/adequacy.py frame_offset_gray); 8, the print's map its calibration learned
# (core/estimator/filter.py calibration_print_map); 9, and the model's own error as the estimator errs with it
# (calibration_error); 10, print maps its calibration surveyed (filter.py _survey); 11, and the sensor's rough pattern
# (core/estimator/flat_field.py); 13, and the samples that read at one of two levels (core/estimator/two_level.py);
# 14, made again with the latch walking on every rig as before 12 (12 and 13 held a triggered camera's: settings.py
# for_recording); 15, calibrated with those pixels set aside as bad pixels instead (core/calibration.py); 16, what the
# maps and calibration's surveys read of a sample with a row's offset drawn that frame taken out (kernel.residuals);
# 17, and what of the model's error persists over a window of frames (filter.py _persistence); 18, and how fast the
# gain walks from frame to frame (core/adequacy.py frame_gain_rate); 19, and the light along the stroke
# (light_profile) and where the image places the carriage there (filter.py error_map); 20, the map with what it
# leaves of the model's error beside the plain account; 21, what it leaves measured on the frames it was not made
# from; 22, and the map of a pass from the image alone; 24, and that pass's own error before its map is read (23 was
# a try not kept); 25, and that pass weighs the light's shape at its first frames as a run does (shape_contest.py);
# older cases are made again
RATIO_KEPT = 1.05  # the acceptance's ceiling for a run's error against today's path's on the same run
FAR_PULL = 4.0  # bounds off the truth beyond which a placed frame counts as far off
SILENT_SHARE = 0.005  # of a run's placed frames: the acceptance's ceiling for far frames left unflagged
STEADY_FLAGGED = 0.01  # of a steady run's frames: the acceptance's ceiling for flags where nothing changed
STEADY_PULL = (0.8, 1.25)  # the acceptance's band for a steady run's rms error over its stated bound (the frames' part)
# every rig of the sweep also plain, nothing changed after calibration (the sweep names only the paper rig's)
PLAIN = [(scenario, "", "") for scenario in dict.fromkeys(case[0] for case in CASES) if (scenario, "", "") not in CASES]


def pulls(error: np.ndarray, bound: np.ndarray, slide: np.ndarray) -> tuple[float, float]:
    """The rms of ``error`` over the whole stated ``bound`` and over the frames' own part of it (the bound less
    ``slide``, the lens's slide it states without the grating, NaN elsewhere; all µm). The slide is a lever no frame
    sees times a stretch the frames cannot yet tell from a lens drifting at its fastest declared rate: on a steady
    rig it does not happen, so the whole bound's pull there is below 1 by what it states (0.1-0.6 on these rigs,
    undeclared lever), and only the frames' part can be held to the steady band. The whole bound is what the far
    frames are counted against."""
    placed = np.isfinite(error)
    if not placed.any():
        return math.nan, math.nan
    seen = bound[placed] ** 2 - np.nan_to_num(slide[placed]) ** 2
    return (float(np.sqrt(np.mean((error[placed] / bound[placed]) ** 2))),
            float(np.sqrt(np.mean(error[placed] ** 2 / seen))))


def cached_case(folder: Path, scenario: str, rig_effects: str, later: str, seed: int = 3):
    """(model, run, truth) of one case, made once and kept in ``folder``: the scenario with ``rig_effects``
    calibrated, then run with ``later`` added, both with ``seed`` (steady_maps.py, map_seeds.py: several)."""
    label = f"{scenario} {rig_effects} {later}" + (f" seed {seed}" if seed != 3 else "")
    path = folder / f"{hashlib.md5((CACHE_VERSION + label.strip()).encode()).hexdigest()[:10]}.pkl"
    if path.exists():
        with open(path, "rb") as kept:
            return pickle.load(kept)
    seconds = SECONDS.get(scenario, 20.0)
    calibration, _ = build_rig(scenario, rig_effects, seed=seed).record(seconds)
    model = calibrate(calibration, "paper").model
    rig = build_rig(scenario, ",".join(part for part in (rig_effects, later) if part), seed=seed, run=1)
    run, truth = rig.record(seconds / 2, trajectory=measured_motion(rig, later, seconds / 2))
    with open(path, "wb") as kept:
        pickle.dump((model, run, truth), kept)
    return model, run, truth


def tracked(model, run, truth, grating: str, settings: EstimatorSettings):
    """The estimator's run against the truth, frame by frame: (its tracker, CPU seconds, and the arrays ``error``
    (µm, whole periods taken out where placed from the image alone), ``bound``, ``floor`` (µm), ``stale``,
    ``repeated``), with ``grating`` the mode it ran in (none where the run read no grating)."""
    reference = run.reference
    if float(model.info.get("reference_skew_s", 0.0)):
        reference = model_reference(model, run.t, reference)
    if not np.isfinite(reference).any():
        grating = "none"
    start = time.process_time()
    tracker = estimator.Estimator(model, settings=settings.for_recording(run.meta), grating=grating,
                                  stage_phases=acceleration_phases(run.meta))
    estimates = estimator.track(model, run.frames, run.t, reference, estimator=tracker)
    seconds = time.process_time() - start
    x = np.array([e.x_mm for e in estimates])
    bound = np.array([e.crlb_mm for e in estimates]) * 1e3
    floor = np.array([e.floor_mm for e in estimates]) * 1e3
    stale = np.array([e.stale for e in estimates])
    slide = np.array([e.slide_mm for e in estimates]) * 1e3
    repeated = np.array([e.repeated for e in estimates])
    error = (x - truth.x_mm) * 1e3
    if grating == "none":  # placed from the image alone: its origin is known up to whole periods
        period = model.period_mm * 1e3
        error -= period * np.round(np.nanmedian(error) / period)
    return tracker, seconds, {"error": error, "bound": bound, "floor": floor, "stale": stale, "repeated": repeated,
                              "slide": slide}


def scored(model, run, truth, grating: str, settings: EstimatorSettings,
           after: np.ndarray | None = None) -> dict[str, float]:
    """The estimator's run scored against the truth; ``after``: the frames whose flags count apart (the share of
    them flagged, ``flagged_after``: a change's frames once it has settled, map_seeds.py)."""
    tracker, seconds, frames = tracked(model, run, truth, grating, settings)
    error, bound, floor, stale, repeated = (frames[key] for key in ("error", "bound", "floor", "stale", "repeated"))
    placed = np.isfinite(error)
    far = placed & (np.abs(error) > FAR_PULL * bound)
    pull, tested = pulls(error, bound, frames["slide"])
    return {"ratio": float(np.nanstd(error) / np.sqrt(np.nanmean(floor[placed] ** 2))) if placed.any() else np.nan,
            "std": float(np.nanstd(error)) if placed.any() else np.nan,
            "pull": pull, "tested": tested,
            "frames": error.size, "placed": int(placed.sum()), "lost": int((~placed & ~repeated).sum()),
            "flagged": int(stale.sum()), "far": int(far.sum()), "silent": int((far & ~stale).sum()),
            "seconds": seconds, "map": int(tracker.sensor.learned().sum()),
            "print": int((tracker.print_map.learned() & ~tracker.print_map.restored).sum()),  # (this run's)
            "touched": int(tracker.sensor.touched.sum()),
            "flagged_after": float(stale[after].mean()) if after is not None and after.any() else 0.0,
            "error": error}


def todays(folder: Path, model, run, truth, label: str, mode: str):
    """Today's path (`graytrack track` without ``--engine estimator``) on the same run and mode, its score kept in
    ``folder`` by the run's frames and the model's coefficients (that path no longer changes, and it tracks a
    changing rig a few times slower than the estimator: a case made again for what only the estimator reads keeps
    it)."""
    path = folder / f"{todays_key(model, run, label, mode)}.watches.pkl"
    if path.exists():
        with open(path, "rb") as kept:
            score = pickle.load(kept)
        # (kept before the frames it placed were: made again where it lost some, the rest need none)
        if not score.lost or getattr(score, "placed_frames", None) is not None:
            return score
    score = path_scored(model, run, truth, engine="watches", **MODES[mode])
    with open(path, "wb") as kept:
        pickle.dump(score, kept)
    return score


def todays_key(model, run, label: str, mode: str) -> str:
    """The name today's score of a run is kept under (:func:`todays`)."""
    content = hashlib.md5(np.ascontiguousarray(run.frames).tobytes())
    content.update(np.ascontiguousarray(model.coeffs).tobytes())
    return hashlib.md5((label.strip() + mode + content.hexdigest()).encode()).hexdigest()[:12]


LEVEL_SCALE_HELP = ("the calibration's χ² level the estimator holds frames against, scaled (1: as calibrated; 0.99 or "
                    "1.01: which runs move on chance alone; today's path keeps its own)")


def level_scaled(model, scale: float):
    """The model with the χ² level its calibration left scaled by ``scale`` (the level the estimator holds each
    frame's residual against: today's path's, or the flat field's where calibration measured one): a change no
    physics would notice, which tells the runs whose figures turn on chance from those a change moved."""
    if scale == 1.0:
        return model
    from graytrack.core.estimator.filter import calibration_level
    from graytrack.core.estimator.flat_field import FLAT_FIELD

    info = {**model.info, "calibration_chi2": calibration_level(model) * scale}
    if isinstance(info.get(FLAT_FIELD), dict):
        info[FLAT_FIELD] = {**info[FLAT_FIELD], "level": float(info[FLAT_FIELD]["level"]) * scale}
    return model.with_changes(info=info)


def settings_of(items: list[str]) -> EstimatorSettings:
    """The estimator's settings with ``name=value`` changes (exits naming the known ones on an unknown name)."""
    changes = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in TUNABLES:
            sys.exit(f"unknown estimator setting {name!r}; known: {', '.join(TUNABLES)}")
        changes[name] = float(value)
    return EstimatorSettings().replace(**changes)


def seeded_arguments(doc: str, seeds: int, what: str, cache: str) -> tuple[argparse.Namespace, EstimatorSettings,
                                                                          int, int]:
    """The command line of a bench over seeds of scenarios and ``what`` changes (map_seeds.py, print_marks.py):
    ``--seeds`` (default ``seeds``), ``--shard K/N``, ``--only``, ``--cache`` (default ``$TMPDIR/cache``) and the
    estimator's ``name=value`` tunables. Returns the arguments (the cache made), the settings and the shard."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=seeds, help=f"seeds of each scenario and {what}")
    parser.add_argument("--shard", default="0/1", help="K/N: every N-th run from the K-th (run N side by side)")
    parser.add_argument("--only", default="", help=f"the runs whose scenario and {what} hold this text")
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / cache,
                        help="where each run's model, run and truth (and today's score) are kept")
    parser.add_argument("--level-scale", type=float, default=1.0, help=LEVEL_SCALE_HELP)
    parser.add_argument("settings", nargs="*", help="name=value of the estimator's tunables")
    args = parser.parse_args()
    if not args.level_scale > 0.0:
        sys.exit("--level-scale must be above 0")
    if args.seeds < 1:
        sys.exit("--seeds must be at least 1")
    shard, shards = (int(part) for part in args.shard.split("/"))
    args.cache.mkdir(parents=True, exist_ok=True)
    return args, settings_of(args.settings), shard, shards


def sweep_parser(doc: str) -> argparse.ArgumentParser:
    """The command line of a bench over the sweep's cases (this one, tunable_sensitivity.py): ``--cache`` (this
    bench's, shared), ``--shard K/N`` and ``--only``."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "graytrack-sweep",
                        help="where each case's model, run and truth are kept")
    parser.add_argument("--shard", default="0/1", help="K/N: every N-th case from the K-th (run N side by side)")
    parser.add_argument("--only", default="", help="cases whose label holds this text")
    return parser


def main() -> None:
    parser = sweep_parser(__doc__)
    parser.add_argument("--against", action="store_true",
                        help="also score today's path on each run (kept in the cache) and count the runs whose "
                             "error std is more than 5 %% above its (both over today's noise floor: the acceptance "
                             "of making the estimator the default)")
    parser.add_argument("--level-scale", type=float, default=1.0, help=LEVEL_SCALE_HELP)
    parser.add_argument("settings", nargs="*", help="name=value of the estimator's tunables")
    args = parser.parse_args()
    if not args.level_scale > 0.0:
        sys.exit("--level-scale must be above 0")
    settings = settings_of(args.settings)
    shard, shards = (int(part) for part in args.shard.split("/"))
    args.cache.mkdir(parents=True, exist_ok=True)
    totals = dict.fromkeys(("frames", "placed", "lost", "flagged", "far", "silent", "seconds"), 0.0)
    over, steady, worse = [], [], []
    for number, (scenario, rig_effects, later) in enumerate(CASES + PLAIN):
        label = f"{scenario} {rig_effects} {later}"
        if args.only not in label or number % shards != shard:
            continue
        model, run, truth = cached_case(args.cache, scenario, rig_effects, later)
        for mode, options in MODES.items():
            grating = "none" if options["no_reference"] else ("fuse" if options["trim"] else "check")
            score = scored(level_scaled(model, args.level_scale), run, truth, grating, settings)
            for key in totals:
                totals[key] += score[key]
            mark = " <<<" if score["silent"] > SILENT_SHARE * max(score["placed"], 1) else ""
            if mark:
                over.append(score["silent"])
            line = (f"{label[:66]:66} {mode:15} ratio {score['ratio']:6.2f} pull {score['pull']:5.2f} "
                    f"tested {score['tested']:5.2f} "
                    f"lost {score['lost']:4d} flag {100 * score['flagged'] / score['frames']:5.1f}% "
                    f"far {score['far']:4d} silent {score['silent']:4d} map {score['map']:3d} "
                    f"print {score['print']:4d}{mark}")
            if args.against:
                # both against today's floor: each path states its own (the estimator's, with the light known from
                # the frames before, is the narrower), the acceptance compares their errors on the same data
                today = todays(args.cache, model, run, truth, label, mode)
                ours, common = score["std"] / today.bound_um, ""
                if today.lost and today.placed_frames:
                    # where today's path lost frames its ratio is over those it placed: the two are compared on
                    # those (what only the estimator placed is no accuracy today's path kept)
                    ours = float(np.nanstd(score["error"][list(today.placed_frames)])) / today.bound_um
                    common = f" (both on the {len(today.placed_frames)} frames today's path placed)"
                above = ours > RATIO_KEPT * today.ratio
                line += (f" | on today's floor {ours:6.2f} today {today.ratio:6.2f} silent {today.silent:4d}{common}"
                         + (" >>>" if above else ""))
                if above:
                    worse.append(line)
            if not later:
                low, high = STEADY_PULL
                honest = score["flagged"] <= STEADY_FLAGGED * score["frames"] and low <= score["tested"] <= high \
                    and not score["map"] and not score["print"]
                steady.append(line + ("" if honest else " ***"))
            print(line, flush=True)
    placed = max(totals["placed"], 1)
    print(f"total: placed {totals['placed']:.0f}, 4+ bounds off {totals['far']:.0f}, unflagged {totals['silent']:.0f} "
          f"({100 * totals['silent'] / placed:.3f} %), flagged {totals['flagged']:.0f}, lost {totals['lost']:.0f}; "
          f"{len(over)} runs over {100 * SILENT_SHARE:.1f} % unflagged ({sum(over)} frames); "
          f"{totals['frames'] / max(totals['seconds'], 1e-9):.0f} frames/s")
    if args.against:
        print(f"against today's path: {len(worse)} runs with an error std more than "
              f"{100 * (RATIO_KEPT - 1):.0f} % above it (>>>)")
    print(f"steady: {len(steady)} runs, {sum(line.endswith('***') for line in steady)} outside the acceptance (***: "
          f"flagged over {100 * STEADY_FLAGGED:.0f} %, something learned, or the rms pull on the frames' part of the "
          f"bound outside {STEADY_PULL[0]}-{STEADY_PULL[1]})")
    for line in steady:
        print("steady:", line)


if __name__ == "__main__":
    main()
