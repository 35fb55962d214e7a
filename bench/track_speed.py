"""Tracker throughput: the plain tracker, with per-frame gain/offset, with robust weights, the live
per-frame cost, a plain-numpy Gauss–Newton loop, and calibration time, side by side in one run.

Every variant solves the same frames with the same calibrated paper model, interleaved and
best-of-N, timed in CPU time of this process (time.process_time): on a shared machine the wall
clock also counts other processes' turns; the ratios are what to read.
Two kinds of tracked frames: clean (the common case: the light and the pixels as calibrated) and
disturbed (light 20 % dimmer with 10 gray of ambient light, one pixel stuck at 255: every frame
then needs the light re-solved and a pixel set aside).
Then every model (``models``): each effect family alone (a model grown with it on a recording of its
cause, drivers/sim/causes.py) and the closed loop's model of every virtual-rig scenario, each
against the seed paper's model fitted on the same recording and a plain-numpy Gauss–Newton loop
on the same frames: batch ``track`` per frame, ``LiveTracker.update`` p50 (the two models
interleaved frame by frame), and ``graytrack track`` end to end (the CLI in this process: load,
track, χ², validity monitor, scale check, CSV) in frames/s, best of a few interleaved runs.

Run: .venv/bin/python bench/track_speed.py [plain|models] [SUBSTRING of a model's label]
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import time
from typing import Callable

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.models import FourierModel
from graytrack.core.recording import Recording
from graytrack.core.estimator import track as estimate
from graytrack.core.tracking import LiveTracker, track
from graytrack.drivers.sim import paper

N_FRAMES = 1000
REPEATS = 15
CLOCK = time.process_time
VARIANTS = {  # name: (light, robust)
    "plain (calibrated light)": ("fixed", False),
    "gain/offset every frame": ("free", False),
    "robust weights": ("fixed", True),
    "gain/offset + robust (auto)": ("auto", True),
}


def sweep(n_rows: int, seed: int) -> Recording:
    x_mm = np.linspace(0.0, paper.STROKE_MM, N_FRAMES) + 0.001 * seed
    frames = paper.paper_frames(x_mm, n_rows=n_rows, rng=np.random.default_rng(seed))
    return Recording(frames.astype(np.float32), np.arange(N_FRAMES) * 1e-3, x_mm,
                     {"pixel_pitch_mm": paper.PIXEL_PITCH_MM, "period_mm": 8.6})


def disturbed(rec: Recording) -> np.ndarray:
    frames = rec.frames * np.float32(0.8) + np.float32(10.0)
    frames[..., 37] = 255.0
    return frames


def plain_numpy_track(model: FourierModel, frames: np.ndarray, x0: float, iterations: int = 5) -> np.ndarray:
    """The textbook loop: per frame, per iteration, evaluate the Fourier series and its slope."""
    weights = model.spatial_weights()[0, :, :, 0]  # (n, 2M+1): per-pixel a_h, b_h, B
    u = np.arange(model.n_pixels)
    line = frames.reshape(frames.shape[0], -1, model.n_pixels).mean(axis=1)
    omega = 2 * np.pi / model.period_mm
    out, x = np.empty(len(line)), x0
    for k, y in enumerate(line):
        for _ in range(iterations):
            theta = omega * (x + model.pixel_pitch_mm * u)
            value, slope = weights[:, 0].copy(), np.zeros_like(theta)
            for h in range(1, model.harmonics + 1):
                s, c = np.sin(h * theta), np.cos(h * theta)
                value += weights[:, 2 * h - 1] * s + weights[:, 2 * h] * c
                slope += h * omega * (weights[:, 2 * h - 1] * c - weights[:, 2 * h] * s)
            dx = slope @ (y - value) / (slope @ slope)
            x += dx
            if abs(dx) < 1e-6:
                break
        out[k] = x
    return out


def live_us(model: FourierModel, frames: np.ndarray, x0: float) -> np.ndarray:
    """Per-frame wall time of LiveTracker.update (its defaults: light auto, robust), µs."""
    live = LiveTracker(model, x0_mm=x0)
    times = np.empty(len(frames))
    for k, frame in enumerate(frames):
        start = CLOCK()
        live.update(frame)
        times[k] = CLOCK() - start
    return times * 1e6


def estimator_us(model: FourierModel, frames: np.ndarray, t: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-frame CPU time of the estimator's live update (core/estimator/), µs."""
    from graytrack.core.estimator import Estimator

    live = Estimator(model)
    times = np.empty(len(frames))
    for k, frame in enumerate(frames):
        start = CLOCK()
        live.update(frame, float(t[k]), float(reference[k]))
        times[k] = CLOCK() - start
    return times * 1e6


def best_times(jobs: dict[str, Callable[[], object]], repeats: int = REPEATS) -> dict[str, float]:
    """Best-of-``repeats`` CPU time of each job, the jobs interleaved within each repeat."""
    best = {name: float("inf") for name in jobs}
    for _ in range(repeats):
        for name, job in jobs.items():
            start = CLOCK()
            job()
            best[name] = min(best[name], CLOCK() - start)
    return best


def main() -> None:
    print(f"frames per run: {N_FRAMES}, 100 px, paper model (M=5, cubic in u); best of {REPEATS}, interleaved")
    for n_rows in (1, 16):
        cal, val = sweep(n_rows, 1), sweep(n_rows, 2)
        start = time.perf_counter()
        model = calibrate(cal, "paper").model
        calib_s = time.perf_counter() - start
        x0 = float(val.reference[0])
        bad = disturbed(val)
        jobs: dict[str, Callable[[], object]] = {}
        for name, (light, robust) in VARIANTS.items():
            jobs[f"clean     {name}"] = lambda light=light, robust=robust: track(model, val, light=light, robust=robust)
        jobs["disturbed gain/offset + robust (auto)"] = lambda: track(model, bad, reference=val.reference,
                                                                      light="auto", robust=True)
        jobs["clean     plain numpy GN"] = lambda: plain_numpy_track(model, val.frames, x0)
        # the one recursive estimator (core/estimator/), batch and as the command runs it
        jobs["clean     estimator"] = lambda: estimate(model, val.frames, val.t, val.reference)
        jobs["disturbed estimator"] = lambda: estimate(model, bad, val.t, val.reference)
        folder = tempfile.TemporaryDirectory()
        jobs["clean     graytrack track (CLI, all of it)"] = cli_seconds(model, val, folder.name, "paper")
        jobs["clean     graytrack track --engine estimator"] = cli_seconds(model, val, folder.name, "estimator",
                                                                           ("--engine", "estimator"))
        for name in ("clean     graytrack track (CLI, all of it)", "clean     graytrack track --engine estimator",
                     "clean     estimator"):
            jobs[name]()  # its imports and compilations before the clock
        best = best_times(jobs)
        folder.cleanup()
        plain = best["clean     plain (calibrated light)"]
        print(f"\n{n_rows} row(s): calibration {calib_s:.2f} s")
        for name, seconds in best.items():
            print(f"  {name:42s} {N_FRAMES / seconds:9.0f} frames/s  {seconds / N_FRAMES * 1e6:6.1f} us/frame"
                  f"  {seconds / plain:5.2f}x plain")
        live = min((live_us(model, frames, x0) for frames in (val.frames,) * 3), key=lambda t: np.percentile(t, 50))
        live_bad = min((live_us(model, frames, x0) for frames in (bad,) * 3), key=lambda t: np.percentile(t, 50))
        for label, times in (("clean", live), ("disturbed", live_bad)):
            print(f"  live update, {label:9s} (auto + robust)      p50 {np.percentile(times, 50):6.1f} us"
                  f"  p99 {np.percentile(times, 99):6.1f} us  (batch plain {plain / N_FRAMES * 1e6:.1f} us/frame)")
        for label, frames in (("clean", val.frames), ("disturbed", bad)):
            times = min((estimator_us(model, frames, val.t, val.reference) for _ in range(3)),
                        key=lambda t: np.percentile(t, 50))
            print(f"  live estimator, {label:9s}                   p50 {np.percentile(times, 50):6.1f} us"
                  f"  p99 {np.percentile(times, 99):6.1f} us")
        ours = track(model, val).x_mm
        agree = np.abs(ours - plain_numpy_track(model, val.frames, x0)).max() * 1e3
        dist = track(model, bad, reference=val.reference, light="auto", robust=True)
        error = dist.error_um(val.reference)
        print(f"  max disagreement with plain numpy GN {agree:.4f} um; disturbed frames: placed "
              f"{np.isfinite(error).mean():.1%}, error rms {np.sqrt(np.nanmean(error**2)):.3f} um"
              f" vs bound {np.nanmean(dist.crlb_mm) * 1e3:.3f} um")


SCENARIO_SECONDS = {"paper": 10.0, "clean": 10.0, "strip16": 6.0, "lab": 3.0, "highspeed": 1.0}  # of calibration
MODEL_REPEATS = 3
RUN_FRAMES = 1000  # frames of each tracked run (the CLI's fixed costs spread as over a real recording)
LIVE_WARM = 20  # frames of each live tracker not counted (model install, first acquisition)


def every_model(selection: str = "") -> list[tuple[str, FourierModel, FourierModel, Recording]]:
    """(label, model, the seed paper's model fitted on the same calibration, a run to track) for
    each effect family and each virtual-rig scenario's closed-loop model."""
    from graytrack.core.diagnosis import diagnose
    from graytrack.drivers.sim.causes import EVERY_FORM
    from graytrack.service.grown_models import model_with
    from graytrack.drivers.sim.scenarios import build_rig, list_scenarios

    def run_of(scenario: str, effects: str, seed: int) -> Recording:
        rig = build_rig(scenario, effects, seed=seed, run=1)
        rec, _ = rig.record(RUN_FRAMES / rig.frame_rate_hz)
        return Recording(rec.frames[:RUN_FRAMES], rec.t[:RUN_FRAMES], rec.reference[:RUN_FRAMES], rec.meta)

    cases = []
    for name, cause in EVERY_FORM.items():
        label = f"effect {name} ({cause.scenario}: {cause.effects})"
        if selection in label:
            model, _, calibration = model_with(name, seconds=8.0 if cause.scenario == "paper" else 4.0,
                                               pitch_search=True)
            cases.append((label, model, calibrate(calibration, "paper").model,
                          run_of(cause.scenario, cause.effects, 5)))
    for scenario in list_scenarios():
        seconds = SCENARIO_SECONDS.get(scenario, 3.0)
        calibration, _ = build_rig(scenario, seed=3).record(seconds)
        loop = diagnose(calibration) if selection in f"closed loop {scenario}" else None
        if loop is None:
            continue
        added = ",".join(step.effect for step in loop.steps) or "nothing"
        cases.append((f"closed loop {scenario} (adds {added})", loop.final_model,
                      calibrate(calibration, "paper").model, run_of(scenario, "", 3)))
    return cases


def cli_seconds(model: FourierModel, run: Recording, folder: str, name: str,
                extra: tuple[str, ...] = ()) -> Callable[[], float]:
    """A job running ``graytrack track [extra]`` on ``run`` with ``model`` in this process (its output muted)."""
    from graytrack.core.models.io import save_model
    from graytrack.core.recording import save
    from graytrack.service.cli import main as cli

    recording, model_path = os.path.join(folder, "run.npz"), os.path.join(folder, f"{name}.json")
    if not os.path.exists(recording):
        save(run, recording)
    save_model(model, model_path)
    argv = ["track", recording, "--model", model_path, "--out", os.path.join(folder, f"{name}.csv"), *extra]

    def job() -> None:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            cli(argv)
    return job


def live_p50(models: dict[str, FourierModel], run: Recording) -> dict[str, float]:
    """p50 CPU µs of each model's LiveTracker.update, the models interleaved frame by frame."""
    trackers = {name: LiveTracker(model, x0_mm=float(run.reference[0])) for name, model in models.items()}
    costs: dict[str, list[float]] = {name: [] for name in models}
    for k, (frame, grating) in enumerate(zip(run.frames, run.reference)):
        for name, tracker in trackers.items():
            start = CLOCK()
            tracker.update(frame, grating)
            if k >= LIVE_WARM:
                costs[name].append(CLOCK() - start)
    return {name: float(np.median(values)) * 1e6 for name, values in costs.items()}


def models_main(selection: str = "") -> None:
    print(f"\nevery model against the seed paper's model on the same frames (CPU µs per frame; CLI frames/s; "
          f"best of {MODEL_REPEATS}, interleaved)")
    print(f"{'model':78} {'rows':>4} {'track plain/model':>18} {'ratio':>6} {'live p50 plain/model':>21} "
          f"{'ratio':>6} {'CLI frames/s plain/model':>25} {'numpy GN':>9} {'model/numpy':>11}")
    for label, model, plain, run in every_model(selection):
        n = run.n_frames
        x0 = float(run.reference[0])
        with tempfile.TemporaryDirectory() as folder:
            jobs = {
                "track plain": lambda: track(plain, run, light="auto", robust=True),
                "track model": lambda: track(model, run, light="auto", robust=True),
                "cli plain": cli_seconds(plain, run, folder, "plain"),
                "cli model": cli_seconds(model, run, folder, "model"),
                "numpy": lambda: plain_numpy_track(plain, run.frames, x0),
            }
            jobs["cli plain"](), jobs["cli model"]()  # compiled and cached before the clock runs
            best = {name: seconds / n * 1e6 for name, seconds in best_times(jobs, MODEL_REPEATS).items()}
        live = live_p50({"plain": plain, "model": model}, run)
        rows = 1 if run.frames.ndim == 2 else run.frames.shape[1]
        print(f"{label:78.78} {rows:4d} {best['track plain']:8.1f} /{best['track model']:8.1f} "
              f"{best['track model'] / best['track plain']:6.2f} {live['plain']:10.1f} /{live['model']:8.1f} "
              f"{live['model'] / live['plain']:6.2f} {1e6 / best['cli plain']:12.0f} /{1e6 / best['cli model']:10.0f} "
              f"{best['numpy']:9.1f} {best['track model'] / best['numpy']:11.2f}", flush=True)


if __name__ == "__main__":
    part = sys.argv[1] if len(sys.argv) > 1 else ""
    if part in ("", "plain"):
        main()
    if part in ("", "models"):
        models_main(sys.argv[2] if len(sys.argv) > 2 else "")
