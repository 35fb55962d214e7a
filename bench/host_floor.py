"""The host's own latency floor: how late a thread that nothing in the guest can delay wakes up.

A thread at SCHED_FIFO above every other thread of the machine, pinned to one core, sleeps 1 ms
again and again; its lateness past each deadline is what the kernel and the hypervisor add (timer
interrupts, a vCPU descheduled by the host: the ``steal`` column of /proc/stat), not what the
daemon's own threads cost: none of them can keep it off its core. A stream's message cannot be
later than its pipeline's own time by less than this, so a p99 goal below the pipeline's median
plus this floor's p99 is out of reach on that machine whatever the daemon does.

``bench/stream_latency.py`` runs it beside every round, on the daemon's core, one level above the
daemon's priority, so the two figures come from the same seconds.

Run: .venv/bin/python bench/host_floor.py [--seconds 20] [--core N] [--priority 20] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

PERIOD_S = 0.001  # the daemon's frame period at 1,000 frames/s


def steal_jiffies() -> int:
    """Time the hypervisor ran other guests while this one's vCPUs were runnable (all cores, jiffies)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) if len(fields) > 8 else 0


def raise_to(priority: int) -> str:
    """SCHED_FIFO at ``priority`` for the calling process; says what it got."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        return "normal"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return f"normal ({exc.strerror or exc})"
    return f"FIFO {priority}"


def wake_lateness(seconds: float) -> np.ndarray:
    """Lateness (ms) of every 1 ms sleep over ``seconds``, on the calling thread as it is scheduled."""
    late: list[float] = []
    end = time.monotonic() + seconds
    while True:
        before = time.monotonic()
        if before >= end:
            break
        time.sleep(PERIOD_S)
        late.append(time.monotonic() - before - PERIOD_S)
    return np.asarray(late) * 1e3


def summary(late_ms: np.ndarray, steal: int, seconds: float) -> dict[str, float]:
    """The figures a stream's tail is compared with."""
    ticks = os.sysconf("SC_CLK_TCK")
    return {"wakes": int(late_ms.size), "p50": float(np.percentile(late_ms, 50)),
            "p99": float(np.percentile(late_ms, 99)), "p999": float(np.percentile(late_ms, 99.9)),
            "max": float(late_ms.max()), "over_2ms": int((late_ms > 2.0).sum()), "over_5ms": int((late_ms > 5.0).sum()),
            "steal_pct": 100.0 * steal / ticks / (seconds * (os.cpu_count() or 1))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--core", type=int, default=max(os.sched_getaffinity(0)),
                        help="the core probed (default: the last)")
    parser.add_argument("--priority", type=int, default=20, help="SCHED_FIFO level (0: normal)")
    parser.add_argument("--json", action="store_true", help="one JSON line (bench/stream_latency.py reads it)")
    args = parser.parse_args()
    os.sched_setaffinity(0, {args.core})
    scheduled = raise_to(args.priority)
    steal0, start = steal_jiffies(), time.monotonic()
    late = wake_lateness(args.seconds)
    figures = summary(late, steal_jiffies() - steal0, time.monotonic() - start)
    if args.json:
        print(json.dumps(figures))
        return
    print(f"core {args.core}, {scheduled}, load average {Path('/proc/loadavg').read_text().split()[0]}: "
          f"{figures['wakes']} wakes of 1 ms, late p50 {figures['p50']:.3f} ms, p99 {figures['p99']:.3f} ms, "
          f"p99.9 {figures['p999']:.2f} ms, max {figures['max']:.2f} ms; {figures['over_2ms']} over 2 ms, "
          f"{figures['over_5ms']} over 5 ms; host steal {figures['steal_pct']:.2f} % of the machine's CPU time")


if __name__ == "__main__":
    main()
