"""Tracker throughput next to a plain-numpy Gauss–Newton loop, and calibration time.

Both trackers solve the same frames with the same calibrated paper model in the same run, so the
ratio holds on a noisy shared machine even when the absolute figures do not.
Run: .venv/bin/python bench/track_speed.py
"""

from __future__ import annotations

import time

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.models import FourierModel
from graytrack.core.recording import Recording
from graytrack.core.tracking import track
from graytrack.drivers.sim import paper

N_FRAMES = 1000


def sweep(n_rows: int, seed: int) -> Recording:
    x_mm = np.linspace(0.0, paper.STROKE_MM, N_FRAMES) + 0.001 * seed
    frames = paper.paper_frames(x_mm, n_rows=n_rows, rng=np.random.default_rng(seed))
    return Recording(frames.astype(np.float32), np.arange(N_FRAMES) * 1e-3, x_mm,
                     {"pixel_pitch_mm": paper.PIXEL_PITCH_MM, "period_mm": 8.6})


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


def best_of(function, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    print(f"frames per run: {N_FRAMES}, 100 px, paper model (M=5, cubic in u)")
    for n_rows in (1, 16):
        cal, val = sweep(n_rows, 1), sweep(n_rows, 2)
        start = time.perf_counter()
        result = calibrate(cal, "paper")
        calib_s = time.perf_counter() - start
        model = result.model
        ours = best_of(lambda: track(model, val))
        plain = best_of(lambda: plain_numpy_track(model, val.frames, val.reference[0]))
        agree = np.abs(track(model, val).x_mm - plain_numpy_track(model, val.frames, val.reference[0])).max() * 1e3
        print(f"{n_rows:2d} row(s): graytrack {N_FRAMES / ours:9.0f} frames/s | plain numpy GN {N_FRAMES / plain:8.0f} frames/s"
              f" | ratio {plain / ours:5.1f}x | max disagreement {agree:.4f} um | calibration {calib_s:.2f} s")


if __name__ == "__main__":
    main()
