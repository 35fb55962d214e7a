"""A steady virtual rig tracked as the daemon tracks it: how often is a stage at rest flagged stale, and why?

Nothing changes on the rig after its calibration, so every flag is a false one unless the positions
really are off: each rest is scored against the truth as well (frames 4+ bounds off it, flagged or
not). The daemon's path without its threads, so that a seed gives the same figures on any machine:
the calibration the daemon's test settings run (21 stops of 3 frames, the paper model:
tests/service/helpers.py FAST_TABLES), then one :class:`LiveTracker` with the daemon's scale watch
(service/daemon/trim.py) fed a frame at a time while the stage moves from rest to rest at
``--speed`` (frames while moving are counted apart), the grating read at the exposure.

``--share`` measures instead what the model's own stretch at a place is worth (core/place_spread.py): at
30 places, 40 frames each, the variance of the mean stretch beyond its noise over a frame's stretch variance,
against the model's coefficients over its calibration's frames (``--stop-frames`` a stop).

Run: .venv/bin/python bench/daemon_rest.py [--seeds 4] [--rests 8] [--frames 300] [--scenario paper] [--trim]
     .venv/bin/python bench/daemon_rest.py --share [--stop-frames 3]
"""

from __future__ import annotations

import argparse
import collections
import math

import numpy as np

from graytrack.core.recording import Recording
from graytrack.core.tracking import LiveTracker
from graytrack.drivers.sim.rig import VirtualRig
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.calibration_run import calibrate_recording
from graytrack.core.place_spread import COEFFICIENT_SHARE
from graytrack.core.watches.magnification import MagnificationWatch
from graytrack.service.daemon.trim import ReferenceTrim

STOPS, STOP_FRAMES = 21, 3  # the daemon's test calibration (FAST_TABLES' sweep)
FRAME_RATE_HZ = 20.0  # FAST_TABLES' camera
FAR_BOUNDS = 4.0  # a frame this many of its bounds off the truth is off


def grating(rig: VirtualRig, x_mm: np.ndarray) -> np.ndarray:
    """The grating's reading of true positions: rounded to its resolution, as the controller reports it."""
    step = rig.config.grating.resolution_mm
    return np.round(np.asarray(x_mm) / step) * step if step > 0 else np.asarray(x_mm, dtype=float)


def calibrated(rig: VirtualRig, stroke: tuple[float, float], stop_frames: int = STOP_FRAMES):
    """The daemon's stops calibration on ``rig``: STOPS stops over ``stroke``, ``stop_frames`` frames each."""
    x = np.repeat(np.linspace(*stroke, STOPS), stop_frames)
    t = np.arange(x.size) / FRAME_RATE_HZ
    frames = rig.render(x, t)
    frames = frames[:, 0, :] if frames.shape[1] == 1 else frames
    recording = Recording(frames, t, grating(rig, x), {**rig.meta(), "source": "bench/daemon_rest.py"})
    return calibrate_recording(recording, "paper").model


def rests(rng: np.random.Generator, stroke: tuple[float, float], n: int) -> np.ndarray:
    margin = 0.05 * (stroke[1] - stroke[0])
    return rng.uniform(stroke[0] + margin, stroke[1] - margin, n)


def track(model, rig: VirtualRig, targets: np.ndarray, frames_per_rest: int, speed_mm_s: float, trim: bool = False):
    """Counters of stale reasons at rest and while moving, and the frames off the truth (flagged or not);
    ``trim``: the daemon's ``[daemon] trim`` (its scale watch with a trim of its own)."""
    watch = ReferenceTrim(trim).watch_for(model)
    tracker = LiveTracker(model, float(targets[0]), watches=[watch] if watch is not None else [])
    counts = {"rest": collections.Counter(), "moving": collections.Counter()}
    frames = {"rest": 0, "moving": 0}
    off = {"flagged": 0, "unflagged": 0}
    x_now, t_now = float(targets[0]), 0.0
    half = 0.5 * rig.exposure_s
    for target in targets:
        n_move = int(math.ceil(abs(target - x_now) / speed_mm_s * FRAME_RATE_HZ))
        path = np.concatenate([np.linspace(x_now, target, n_move + 1)[1:], np.full(frames_per_rest, target)])
        velocity = np.concatenate([np.full(n_move, (target - x_now) / max(n_move, 1) * FRAME_RATE_HZ),
                                   np.zeros(frames_per_rest)])
        t = t_now + np.arange(1, path.size + 1) / FRAME_RATE_HZ
        samples = path[:, None] + velocity[:, None] * np.array([-half, 0.0, half])
        images = rig.render(samples, t)
        reading = grating(rig, path)
        for k in range(path.size):
            phase = "moving" if k < n_move else "rest"
            fix = tracker.update(images[k], float(reading[k]))
            frames[phase] += 1
            if fix.stale:
                counts[phase][fix.stale_reason] += 1
            if math.isfinite(fix.x_mm) and abs(fix.x_mm - path[k]) > FAR_BOUNDS * fix.crlb_mm:
                off["flagged" if fix.stale else "unflagged"] += 1
        x_now, t_now = float(target), float(t[-1])
    return counts, frames, off


def place_share(model, rig: VirtualRig, stroke: tuple[float, float], places: int = 30, frames: int = 40) -> np.ndarray:
    """At each of ``places`` rests, the model's own stretch variance there over a frame's stretch variance:
    (mean² − its noise²) / median frame σ²."""
    shares = []
    for x in np.linspace(stroke[0] + 0.2, stroke[1] - 0.2, places):
        own = MagnificationWatch(model.period_mm, record=True)
        tracker = LiveTracker(model, float(x), watches=[own])
        for image in rig.render(np.full(frames, x), np.arange(frames) / FRAME_RATE_HZ):
            tracker.update(image, float(x))
        _, m, sigma = np.array(own.record).T
        weight = sigma ** -2
        mean = float(weight @ m) / weight.sum()
        shares.append((mean * mean - 1.0 / weight.sum()) / float(np.median(sigma)) ** 2)
    return np.array(shares)


def share_main(args: argparse.Namespace) -> None:
    print(f"{'seed':>4} {'coefficients/frames':>19} {'share mean':>10} {'max':>6} {'mean / (c/f)':>12}  "
          f"(COEFFICIENT_SHARE = {COEFFICIENT_SHARE})")
    for seed in range(args.seeds):
        calibration = build_rig(args.scenario, seed=seed)
        stroke = calibration.config.stroke_mm
        model = calibrated(calibration, stroke, args.stop_frames)
        ratio = model.n_coeffs / model.info["calibration_frames"]
        shares = place_share(model, build_rig(args.scenario, seed=seed, run=1), stroke)
        print(f"{seed:>4} {ratio:>19.3f} {shares.mean():>10.3f} {shares.max():>6.3f} {shares.mean() / ratio:>12.3f}",
              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--rests", type=int, default=8, help="rest positions per seed")
    parser.add_argument("--frames", type=int, default=300, help="frames at each rest")
    parser.add_argument("--speed", type=float, default=5.0, help="mm/s between rests")
    parser.add_argument("--trim", action="store_true", help="as the daemon with [daemon] trim = true")
    parser.add_argument("--share", action="store_true", help="measure the model's own stretch at a place instead")
    parser.add_argument("--stop-frames", type=int, default=STOP_FRAMES, help="calibration frames a stop (--share)")
    args = parser.parse_args()
    if args.share:
        share_main(args)
        return
    total = {"rest": collections.Counter(), "moving": collections.Counter()}
    frames_total = {"rest": 0, "moving": 0}
    off_total = collections.Counter()
    print(f"{'seed':>4} {'rest frames':>11} {'stale at rest':>13} {'moving':>6} {'stale moving':>12} "
          f"{'off, flagged':>12} {'off, unflagged':>14}  reasons at rest")
    for seed in range(args.seeds):
        calibration = build_rig(args.scenario, seed=seed)
        stroke = calibration.config.stroke_mm
        model = calibrated(calibration, stroke)
        run = build_rig(args.scenario, seed=seed, run=1)  # the same rig, fresh noise: the run after calibration
        counts, frames, off = track(model, run, rests(np.random.default_rng(seed), stroke, args.rests),
                                    args.frames, args.speed, args.trim)
        for phase in total:
            total[phase].update(counts[phase])
            frames_total[phase] += frames[phase]
        off_total.update(off)
        print(f"{seed:>4} {frames['rest']:>11} {sum(counts['rest'].values()):>13} {frames['moving']:>6} "
              f"{sum(counts['moving'].values()):>12} {off['flagged']:>12} {off['unflagged']:>14}  "
              f"{dict(counts['rest'])}", flush=True)
    for phase in ("rest", "moving"):
        share = 100.0 * sum(total[phase].values()) / max(frames_total[phase], 1)
        reasons = ", ".join(f"{reason} {100.0 * n / frames_total[phase]:.2f} %"
                            for reason, n in total[phase].most_common())
        print(f"{phase}: {share:.2f} % of {frames_total[phase]} frames flagged ({reasons or 'none'})")
    placed = frames_total["rest"] + frames_total["moving"]
    print(f"off the truth by {FAR_BOUNDS:g}+ bounds: {off_total['flagged']} flagged, {off_total['unflagged']} "
          f"unflagged ({100.0 * off_total['unflagged'] / placed:.3f} % of {placed} frames)")


if __name__ == "__main__":
    main()
