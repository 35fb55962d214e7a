"""``graytrack batch`` throughput on 1 and 2 local Dask workers, and what an archive would cost.

1. The same set of virtual-rig recordings goes through ``batch diagnose`` (or ``--kind``) on a
   local cluster of 1 and then 2 worker processes, in one run, so the ratio holds on a shared
   machine even when the absolute figures do not: recordings/s and frames/s, cluster start apart.
   Each cluster size runs twice, alternating, and the better run counts: on a shared machine the
   other load comes and goes. Beside each run: the CPU time the workers actually got, in cores
   (their process time over the batch's wall time), and the load average; a ratio below 2 with
   the workers getting less than 2 cores says the machine was busy, not that Dask was; the
   efficiency used below is therefore per CPU-second received (Dask's own overhead).
2. The per-recording cost is measured in CPU seconds (``time.process_time``, insensitive to other
   load) of one recording's work in this process at two lengths, fitted as a + b·frames; the
   arithmetic for 1,000 recordings × 10⁴ frames on N workers uses it with the parallel
   efficiency of step 1.

Run: .venv/bin/python bench/batch_speed.py [--kind diagnose|calibrate] [--recordings 8] [--frames 400]
"""

from __future__ import annotations

import argparse
import importlib
import io
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from graytrack.core.recording import save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.batch.cluster import dask_client
from graytrack.service.batch.discover import discover
from graytrack.service.batch.jobs import Job, run_job
from graytrack.service.batch.runner import run_batch

FRAME_RATE_HZ = 50.0  # the paper scenario's
ARCHIVE = (1000, 10_000)  # recordings × frames each


def make_recordings(folder: Path, count: int, frames: int, first_seed: int = 0) -> list[Path]:
    paths = []
    for index in range(count):
        rec, _ = build_rig("paper", seed=first_seed + index).record(frames / FRAME_RATE_HZ)
        paths.append(save(rec, folder / f"rec{first_seed + index:03d}.npz"))
    return paths


def warm_up(client) -> None:
    """Import the work's modules on every worker first: a worker's first task would pay for it."""
    for module in ("graytrack.core.diagnosis", "graytrack.service.report", "graytrack.service.commands.track"):
        client.run(importlib.import_module, module)


def run(client, kind: str, folder: Path, out: Path):
    outcome = run_batch(client, kind, discover([str(folder)]), out, {}, force=True, stream=io.StringIO())
    if outcome.failed:
        raise SystemExit(f"{len(outcome.failed)} recording(s) failed: {outcome.failed[0]['reason']}")
    return outcome


def task_cost(kind: str, tmp: Path, frames: int, repeats: int = 2) -> float:
    """Median CPU seconds of one recording's work (load, compute, write outputs), no Dask."""
    times = []
    for path in make_recordings(tmp / f"cost{frames}", repeats, frames, first_seed=100):
        start = time.process_time()
        row = run_job(Job(kind, discover([str(path)])[0], str(tmp / "cost_out"), {}))
        times.append(time.process_time() - start)
        if row["status"] != "ok":
            raise SystemExit(f"cost run failed: {row['reason']}")
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("diagnose", "calibrate"), default="diagnose")
    parser.add_argument("--recordings", type=int, default=6)
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        make_recordings(tmp / "set", args.recordings, args.frames)
        print(f"batch {args.kind}: {args.recordings} paper-rig recordings × {args.frames} frames × 100 px, "
              f"local cluster of processes (1 thread each)")
        rates: dict[int, float] = {}
        per_core: dict[int, float] = {}  # recordings per CPU-second the workers received
        for attempt, workers in enumerate((1, 2, 1, 2)):
            started = time.perf_counter()
            with dask_client(None, workers) as client:
                warm_up(client)
                start_s = time.perf_counter() - started
                cpu_before = client.run(time.process_time)
                outcome = run(client, args.kind, tmp / "set", tmp / f"out{attempt}")
                cpu_after = client.run(time.process_time)
            cores = sum(cpu_after[w] - cpu_before[w] for w in cpu_after) / outcome.seconds
            frames = sum(int(row["frames"]) for row in outcome.rows)
            rate = len(outcome.rows) / outcome.seconds
            rates[workers] = max(rates.get(workers, 0.0), rate)
            per_core[workers] = max(per_core.get(workers, 0.0), rate / cores)
            print(f"  {workers} worker(s), run {attempt // 2 + 1}: {rate:6.2f} recordings/s, "
                  f"{frames / outcome.seconds:8.0f} frames/s (batch {outcome.seconds:.2f} s; cluster start and "
                  f"imports {start_s:.2f} s, not counted); the workers got {cores:.2f} core(s) of CPU "
                  f"(load average {os.getloadavg()[0]:.1f})")
        measured = per_core[2] / per_core[1]
        efficiency = min(measured, 1.0)  # above 100 % is run-to-run noise, not a gain
        print(f"  best of each: 2 workers vs 1 = {rates[2] / rates[1]:.2f}x in wall time on this machine "
              f"({os.cpu_count()} cores, shared); per CPU-second received: {per_core[1]:.2f} vs {per_core[2]:.2f} "
              f"recordings, efficiency {measured:.0%} (what N workers with a core each keep of N×)")

        short, long = 250, 2000
        costs = {n: task_cost(args.kind, tmp, n) for n in (short, long)}
        per_frame = (costs[long] - costs[short]) / (long - short)
        fixed = costs[short] - per_frame * short
        print(f"per-recording cost (CPU time, one process): {costs[short]:.2f} s at {short} frames, "
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
                  + ("" if workers == 1 else f"  (N cores, the {efficiency:.0%} per-CPU efficiency measured at N = 2)"))


if __name__ == "__main__":
    main()
