"""Per-frame cost of the models the closed loop gives a lab, against the plain paper model, side by side.

For each virtual-rig scenario: a calibration run, the closed loop (`graytrack diagnose`) on it, the
seed paper's model on it, and a second run tracked by both, live (`LiveTracker.update`, as the
daemon does, one frame at a time, interleaved frame by frame between the models) and in batch
(`track`, as `graytrack track` does), plus the closed loop's model on the pure-numpy evaluation
(GRAYTRACK_KERNEL=numpy: what a machine without numba gets), and both models through the one recursive
estimator (`Estimator.update`, the grating checked, interleaved frame by frame: live and batch are its one
recursion). CPU time of this thread; the
ratios are what to read on a shared machine. The first frames of each tracker (model install,
compilation) are not counted.

    .venv/bin/python bench/model_speed.py [SUBSTRING]   (of a scenario's label or an effect's name)

Then every effect family alone (drivers/sim/causes.py): a model grown with just that effect
against the seed paper's model on the same recording.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: no threaded BLAS spinning on tiny products
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from graytrack.core import kernels  # noqa: E402
from graytrack.core.calibration import calibrate  # noqa: E402
from graytrack.core.diagnosis import diagnose  # noqa: E402
from graytrack.core.estimator import Estimator  # noqa: E402
from graytrack.core.tracking import LiveTracker, track  # noqa: E402
from graytrack.drivers.sim.causes import EVERY_FORM  # noqa: E402
from graytrack.service.grown_models import model_with  # noqa: E402
from graytrack.drivers.sim.scenarios import build_rig  # noqa: E402

CLOCK = time.thread_time
RUN_SECONDS = {"paper": 20.0, "strip16": 10.0}  # each effect's tracked run: 1,000 or 500 frames
WARM_FRAMES = 20
CASES = [  # (label, scenario, rig effects, seconds of calibration)
    ("paper 1x100, dust and scratches", "paper", "dust:count=6,scratches:count=3", 20.0),
    ("paper 1x100, flicker", "paper", "flicker:mains_hz=50:depth=0.05", 20.0),
    ("strip 16x100, shot noise, tilt, PRNU", "strip16", "shot_noise,tilt:deg=2,prnu:sigma=0.02", 10.0),
    ("lab 16x128, 12 bit, vibration, PRNU, gradient, dust", "lab",
     "photon_transfer:full_well=20000:read_e=6:bits=12:black_gray=4,vibration:um=1:hz=120,prnu:sigma=0.01,"
     "gradient:per_10mm=0.05,dust:count=6", 3.0),
]


def live_costs(models: dict[str, object], frames: np.ndarray, reference: np.ndarray) -> dict[str, np.ndarray]:
    """Per-frame CPU µs of each model's LiveTracker, interleaved frame by frame."""
    trackers = {name: LiveTracker(model, x0_mm=float(reference[0])) for name, model in models.items()}
    costs = {name: [] for name in models}
    for k, (frame, grating) in enumerate(zip(frames, reference)):
        for name, tracker in trackers.items():
            started = CLOCK()
            tracker.update(frame, grating)
            if k >= WARM_FRAMES:
                costs[name].append(CLOCK() - started)
    return {name: np.array(values) * 1e6 for name, values in costs.items()}


def estimator_costs(models: dict[str, object], frames: np.ndarray, t: np.ndarray,
                    reference: np.ndarray) -> dict[str, float]:
    """Per-frame CPU µs (median) of each model's estimator, interleaved frame by frame."""
    estimators = {name: Estimator(model) for name, model in models.items()}
    costs = {name: [] for name in models}
    for k, (frame, time_s, grating) in enumerate(zip(frames, t, reference)):
        for name, estimator in estimators.items():
            started = CLOCK()
            estimator.update(frame, float(time_s), float(grating))
            if k >= WARM_FRAMES:
                costs[name].append(CLOCK() - started)
    return {name: float(np.median(values)) * 1e6 for name, values in costs.items()}


def batch_cost(model, frames: np.ndarray, reference: np.ndarray) -> float:
    """CPU µs per frame of `track` as the CLI runs it (automatic light, robust), its set-up left
    out: the cost of a run of all the frames less that of a run of one, best of three each. A
    run's set-up (the tracker's tables, the validity monitor's bound over the stroke: 30–40 ms on a
    16-row model) is paid once per recording, and on a few hundred frames it would otherwise be
    most of the figure (:func:`setup_ms` reports it)."""
    return (_best_run(model, frames, reference) - _best_run(model, frames[:1], reference[:1])) \
        / (len(frames) - 1) * 1e6


def setup_ms(model, frames: np.ndarray, reference: np.ndarray) -> float:
    """CPU ms of `track` on one frame: what every run pays before its frames."""
    return _best_run(model, frames[:1], reference[:1]) * 1e3


def _best_run(model, frames: np.ndarray, reference: np.ndarray, repeats: int = 3) -> float:
    track(model, frames[:WARM_FRAMES], reference=reference[:WARM_FRAMES], light="auto", robust=True)
    best = float("inf")
    for _ in range(repeats):
        started = CLOCK()
        track(model, frames, reference=reference, light="auto", robust=True)
        best = min(best, CLOCK() - started)
    return best


def numpy_live(model, frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    compiled, kernels.COMPILED = kernels.COMPILED, False
    try:
        return live_costs({"numpy": model}, frames, reference)["numpy"]
    finally:
        kernels.COMPILED = compiled


def main(selection: str = "") -> None:
    baseline = None  # the plain one-row model's live p50, what every model is held to (within 4x)
    print(f"{'recording':52} {'closed loop adds':36} {'live p50 plain/loop µs':>24} {'ratio':>6} "
          f"{'p99 loop':>9} {'vs 1-row':>8} {'track plain/loop µs':>21} {'ratio':>6} {'set-up ms':>10} "
          f"{'numpy p50':>10} {'estimator p50 plain/loop µs':>28} {'ratio':>6}")
    for label, scenario, rig_effects, seconds in CASES:
        if selection not in label:
            continue
        calibration, _ = build_rig(scenario, rig_effects, seed=3).record(seconds)
        run, _ = build_rig(scenario, rig_effects, seed=3, run=1).record(min(seconds / 2, 3.0))
        loop = diagnose(calibration)
        models = {"plain": calibrate(calibration, "paper").model, "loop": loop.final_model}
        live = live_costs(models, run.frames, run.reference)
        p50 = {name: float(np.median(values)) for name, values in live.items()}
        if baseline is None and scenario == "paper":
            baseline = p50["plain"]
        batch = {name: batch_cost(model, run.frames, run.reference) for name, model in models.items()}
        setup = {name: setup_ms(model, run.frames, run.reference) for name, model in models.items()}
        fallback = float(np.median(numpy_live(models["loop"], run.frames, run.reference)))
        estimated = estimator_costs(models, run.frames, run.t, run.reference)
        added = ",".join(step.effect for step in loop.steps) or "-"
        print(f"{label:52.52} {added:36.36} {p50['plain']:11.1f} /{p50['loop']:9.1f} "
              f"{p50['loop'] / p50['plain']:6.2f} {np.percentile(live['loop'], 99):9.1f} "
              f"{p50['loop'] / baseline if baseline else float('nan'):8.2f} "
              f"{batch['plain']:9.1f} /{batch['loop']:9.1f} {batch['loop'] / batch['plain']:6.2f} "
              f"{setup['plain']:4.0f} /{setup['loop']:4.0f} {fallback:10.1f} "
              f"{estimated['plain']:15.1f} /{estimated['loop']:9.1f} {estimated['loop'] / estimated['plain']:6.2f}",
              flush=True)


def per_effect(selection: str = "") -> None:
    """Every effect family alone: a model grown with it, against the seed paper's model fitted on
    the same recording of its cause, live and batch (drivers/sim/causes.py)."""
    print(f"\n{'effect (its cause on the rig)':62} {'live p50 plain/effect µs':>25} {'ratio':>6} "
          f"{'track plain/effect µs':>22} {'ratio':>6} {'estimator plain/effect µs':>26} {'ratio':>6}")
    for name, cause in EVERY_FORM.items():
        if selection not in name:
            continue
        model, _, calibration = model_with(name, seconds=8.0 if cause.scenario == "paper" else 4.0, pitch_search=True)
        # a run long enough that a frame's cost stands out of the run's set-up (the set-up is left out)
        run, _ = build_rig(cause.scenario, cause.effects, seed=5, run=2).record(RUN_SECONDS[cause.scenario])
        models = {"plain": calibrate(calibration, "paper").model, "effect": model}
        live = live_costs(models, run.frames, run.reference)
        p50 = {key: float(np.median(values)) for key, values in live.items()}
        batch = {key: batch_cost(m, run.frames, run.reference) for key, m in models.items()}
        estimated = estimator_costs(models, run.frames, run.t, run.reference)
        print(f"{name + ' (' + cause.effects + ')':62.62} {p50['plain']:12.1f} /{p50['effect']:9.1f} "
              f"{p50['effect'] / p50['plain']:6.2f} {batch['plain']:10.1f} /{batch['effect']:9.1f} "
              f"{batch['effect'] / batch['plain']:6.2f} {estimated['plain']:13.1f} /{estimated['effect']:9.1f} "
              f"{estimated['effect'] / estimated['plain']:6.2f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
    per_effect(sys.argv[1] if len(sys.argv) > 1 else "")
