"""Tracker throughput: the plain tracker, with per-frame gain/offset, with robust weights, the live
per-frame cost, a plain-numpy Gauss–Newton loop, and calibration time, side by side in one run.

Every variant solves the same frames with the same calibrated paper model, interleaved and
best-of-N, timed in CPU time of this process (time.process_time): on a shared machine the wall
clock also counts other processes' turns; the ratios are what to read.
Two kinds of tracked frames: clean (the common case: the light and the pixels as calibrated) and
disturbed (light 20 % dimmer with 10 gray of ambient light, one pixel stuck at 255: every frame
then needs the light re-solved and a pixel set aside).
Run: .venv/bin/python bench/track_speed.py
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.models import FourierModel
from graytrack.core.recording import Recording
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


def best_times(jobs: dict[str, Callable[[], object]]) -> dict[str, float]:
    """Best-of-REPEATS wall time of each job, the jobs interleaved within each repeat."""
    best = {name: float("inf") for name in jobs}
    for _ in range(REPEATS):
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
        best = best_times(jobs)
        plain = best["clean     plain (calibrated light)"]
        print(f"\n{n_rows} row(s): calibration {calib_s:.2f} s")
        for name, seconds in best.items():
            print(f"  {name:40s} {N_FRAMES / seconds:9.0f} frames/s  {seconds / N_FRAMES * 1e6:6.1f} us/frame"
                  f"  {seconds / plain:5.2f}x plain")
        live = min((live_us(model, frames, x0) for frames in (val.frames,) * 3), key=lambda t: np.percentile(t, 50))
        live_bad = min((live_us(model, frames, x0) for frames in (bad,) * 3), key=lambda t: np.percentile(t, 50))
        for label, times in (("clean", live), ("disturbed", live_bad)):
            print(f"  live update, {label:9s} (auto + robust)      p50 {np.percentile(times, 50):6.1f} us"
                  f"  p99 {np.percentile(times, 99):6.1f} us  (batch plain {plain / N_FRAMES * 1e6:.1f} us/frame)")
        ours = track(model, val).x_mm
        agree = np.abs(ours - plain_numpy_track(model, val.frames, x0)).max() * 1e3
        dist = track(model, bad, reference=val.reference, light="auto", robust=True)
        error = dist.error_um(val.reference)
        print(f"  max disagreement with plain numpy GN {agree:.4f} um; disturbed frames: placed "
              f"{np.isfinite(error).mean():.1%}, error rms {np.sqrt(np.nanmean(error**2)):.3f} um"
              f" vs bound {np.nanmean(dist.crlb_mm) * 1e3:.3f} um")


if __name__ == "__main__":
    main()
