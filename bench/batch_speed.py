"""``graytrack batch`` throughput on 1 and 2 local Dask workers, and what an archive would cost.

1. The same set of virtual-rig recordings goes through ``batch diagnose`` (or ``--kind``) on a
   local cluster of 1 and then 2 worker processes, in one run, so the ratio holds on a shared
   machine even when the absolute figures do not: recordings/s and frames/s, cluster start apart.
2. The per-recording cost is measured on the 1-worker cluster (each task's own time: load,
   compute, write) at two recording lengths and fitted as a + b·frames; the arithmetic for
   1,000 recordings × 10⁴ frames on N workers uses it with the parallel efficiency of step 1.

Run: .venv/bin/python bench/batch_speed.py [--kind diagnose|calibrate] [--recordings 8] [--frames 400]
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np

from graytrack.core.recording import save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.batch.cluster import dask_client
from graytrack.service.batch.discover import discover
from graytrack.service.batch.runner import run_batch

FRAME_RATE_HZ = 50.0  # the paper scenario's
ARCHIVE = (1000, 10_000)  # recordings × frames each


def make_recordings(folder: Path, count: int, frames: int, first_seed: int = 0) -> list[Path]:
    paths = []
    for index in range(count):
        rec, _ = build_rig("paper", seed=first_seed + index).record(frames / FRAME_RATE_HZ)
        paths.append(save(rec, folder / f"rec{first_seed + index:03d}.npz"))
    return paths


def run(client, kind: str, folder: Path, out: Path):
    outcome = run_batch(client, kind, discover([str(folder)]), out, {}, force=True, stream=io.StringIO())
    if outcome.failed:
        raise SystemExit(f"{len(outcome.failed)} recording(s) failed: {outcome.failed[0]['reason']}")
    return outcome


def task_cost(client, kind: str, tmp: Path, frames: int, repeats: int = 2) -> float:
    """Median seconds of one recording's task on a worker (load, compute, write outputs)."""
    make_recordings(tmp / f"cost{frames}", repeats, frames, first_seed=100)
    outcome = run(client, kind, tmp / f"cost{frames}", tmp / f"cost{frames}_out")
    return float(np.median([float(row["seconds"]) for row in outcome.rows]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("diagnose", "calibrate"), default="diagnose")
    parser.add_argument("--recordings", type=int, default=8)
    parser.add_argument("--frames", type=int, default=400)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        make_recordings(tmp / "set", args.recordings, args.frames)
        print(f"batch {args.kind}: {args.recordings} paper-rig recordings × {args.frames} frames × 100 px, "
              f"local cluster of processes (1 thread each)")
        rates, costs = {}, {}
        short, long = 250, 2000
        for workers in (1, 2):
            started = time.perf_counter()
            with dask_client(None, workers) as client:
                start_s = time.perf_counter() - started
                outcome = run(client, args.kind, tmp / "set", tmp / f"out{workers}")
                if workers == 1:
                    costs = {n: task_cost(client, args.kind, tmp, n) for n in (short, long)}
            frames = sum(int(row["frames"]) for row in outcome.rows)
            rates[workers] = len(outcome.rows) / outcome.seconds
            print(f"  {workers} worker(s): {rates[workers]:6.2f} recordings/s, {frames / outcome.seconds:8.0f} frames/s "
                  f"(batch {outcome.seconds:.2f} s; cluster start {start_s:.2f} s, not counted)")
        efficiency = rates[2] / (2 * rates[1])
        print(f"  2 workers vs 1: {rates[2] / rates[1]:.2f}x (parallel efficiency {efficiency:.0%} on this machine)")

        per_frame = (costs[long] - costs[short]) / (long - short)
        fixed = costs[short] - per_frame * short
        print(f"per-recording cost (one task on a worker): {costs[short]:.2f} s at {short} frames, "
              f"{costs[long]:.2f} s at {long} frames")
        n_rec, n_frames = ARCHIVE
        per_recording = fixed + per_frame * n_frames
        print(f"  → cost(frames) = {fixed:.2f} s + {per_frame * 1e3:.3f} ms × frames; "
              f"at {n_frames:,} frames: {per_recording:.1f} s")
        total = n_rec * per_recording
        print(f"{n_rec:,} recordings × {n_frames:,} frames = {n_rec} × {per_recording:.1f} s = {total / 3600:.1f} "
              f"CPU-hours; on N workers ≈ {total / 3600:.1f} h / (N × efficiency):")
        for workers in (1, 2, 8, 32, 128):
            eff = 1.0 if workers == 1 else efficiency
            print(f"  N = {workers:3d}: {total / (workers * eff) / 3600:7.2f} h"
                  + ("" if workers <= 2 else f"  (assuming the {efficiency:.0%} efficiency measured at N = 2)"))


if __name__ == "__main__":
    main()
