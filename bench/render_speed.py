"""Render speed of the virtual rig: frames per second on one core and the real-time factor.

Acceptance (issue 3): ≥ 10× real time for a 16-row × 100-px strip at 1,000 frames/s. Prints one
line per case; the figure that matters is the first (the highspeed scenario: paper field, 16 rows,
1 kHz, moving fast so every frame is motion-blur integrated).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: no threaded BLAS
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

from graytrack.drivers.sim.scenarios import build_rig  # noqa: E402

CASES = [
    ("highspeed", (), 5.0),
    ("strip16", ("frame_rate:hz=1000",), 5.0),
    ("highspeed", ("tilt:deg=0.3", "prnu", "dsnu", "flicker", "vignetting", "quantize:bits=8"), 5.0),
    ("highspeed", ("gradient:per_10mm=0.05:curvature=0.02",), 5.0),
    ("highspeed", ("dust",), 1.0),
    ("lab", ("frame_rate:hz=1000",), 1.0),
]


def main() -> None:
    print(f"{'scenario':<10} {'effects':<58} {'frames':>7} {'R×n':>8} {'frames/s':>10} {'× real time':>12}")
    for scenario, effects, seconds in CASES:
        rig = build_rig(scenario, list(effects), seed=0)
        rig.record(0.05)  # warm-up
        start = time.perf_counter()
        rec, _ = rig.record(seconds)
        elapsed = time.perf_counter() - start
        fps = rec.n_frames / elapsed
        label = ",".join(effects) or "-"
        print(f"{scenario:<10} {label:<58.58} {rec.n_frames:>7} {rig.n_rows:>3}×{rig.n_pixels:<4} {fps:>10.0f} "
              f"{fps / rig.frame_rate_hz:>11.1f}×")


if __name__ == "__main__":
    main()
