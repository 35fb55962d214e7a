"""A real ``graytrack serve`` (the virtual rig, 200 frames per wall second) under hostile local clients
(issue #38, docs/daemon.md "Resource limits"): prints the daemon's RSS and what each client got.

1. 30 WebSockets on /ws/position, each declaring a 15 MiB frame and sending 14 MiB of it:
   RSS before, while they are open, and after they close;
2. a real client on the stream while N idle connections (default 1,000) are open: its rate and the
   seq gaps before and during, and how many of the idle ones the daemon refused or closed;
3. M slowloris connections (default 500) trickling a request head a byte every 0.5 s: when the
   daemon closed each, against ``[daemon] request_timeout_s``.

    nice -n 10 .venv/bin/python bench/hostile_clients.py [--idle 1000] [--slow 500] [--timeout 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' daemon and client helpers

import numpy as np  # noqa: E402

from tests.service.helpers import ServeProcess  # noqa: E402
from tests.service.hostile import (Slowloris, StreamReader, big_frame_clients, close_code,  # noqa: E402
                                   close_counting_open, gaps, idle_sockets, raise_fd_limit, rss_mb)

SETTLE_S = 2.0
WINDOW_S = 5.0


def big_frames(daemon: ServeProcess, n: int) -> None:
    pid = daemon.process.pid
    before = rss_mb(pid)
    started = time.monotonic()
    clients = big_frame_clients(daemon.port, n)
    took = time.monotonic() - started
    during = rss_mb(pid)
    codes = {close_code(c.received) for c in clients}
    sent = np.array([c.sent for c in clients]) / 2**20
    for c in clients:
        c.close()
    time.sleep(SETTLE_S)
    after = rss_mb(pid)
    print(f"{n} WebSockets declaring 15 MiB frames: RSS {before:.0f} MB before, "
          f"{during:.0f} during (+{during - before:.1f}), {after:.0f} after closing (+{after - before:.1f}); "
          f"each sent {sent.min():.2f}-{sent.max():.2f} MiB "
          f"before the daemon cut it off ({took:.1f} s for all); close frames seen: {sorted(codes, key=str)}")


def idle(daemon: ServeProcess, n: int, timeout_s: float) -> None:
    with StreamReader(daemon.port) as reader:
        time.sleep(1.0)
        t0 = time.monotonic()
        time.sleep(WINDOW_S)
        quiet, quiet_rate = reader.window(t0, time.monotonic())
        before = rss_mb(daemon.process.pid)
        opened_at = time.monotonic()
        socks = idle_sockets(daemon.port, n)
        opened = time.monotonic()
        time.sleep(WINDOW_S)
        loaded, loaded_rate = reader.window(opened_at, time.monotonic())
        during = rss_mb(daemon.process.pid)
        time.sleep(max(0.0, opened_at + timeout_s + 1.0 - time.monotonic()))
        still_open = close_counting_open(socks)
    print(f"stream alone: {quiet_rate:.1f} messages/s, {gaps(quiet)} seq gaps over {len(quiet)} messages")
    print(f"with {len(socks)} idle connections opened in {opened - opened_at:.1f} s: {loaded_rate:.1f} messages/s, "
          f"{gaps(loaded)} seq gaps over {len(loaded)} messages (reader error: {reader.error}); RSS {before:.0f} -> "
          f"{during:.0f} MB; {still_open} of them still open {timeout_s + 1:g} s after they opened")


def slowloris(daemon: ServeProcess, n: int, timeout_s: float) -> None:
    attack = Slowloris(daemon.port, n, interval_s=0.5)
    before = rss_mb(daemon.process.pid)
    attack.run(give_up_s=3 * timeout_s + 10)
    after = rss_mb(daemon.process.pid)
    times = np.array([t for t in attack.closed_after_s if t is not None])
    answered = sum(a.startswith(b"HTTP/1.1 408") for a in attack.answers)
    refused = sum(a.startswith(b"HTTP/1.1 503") for a in attack.answers)
    never = sum(t is None for t in attack.closed_after_s)
    if len(times):
        print(f"{n} slowloris connections (request_timeout_s = {timeout_s:g}): {len(times)} closed, after "
              f"{times.min():.2f}-{times.max():.2f} s (median {np.median(times):.2f}); {answered} answered 408, "
              f"{refused} 503; {never} still open after {3 * timeout_s + 10:g} s; RSS {before:.0f} -> {after:.0f} MB")
    else:
        print(f"{n} slowloris connections: none closed in {3 * timeout_s + 10:g} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", type=int, default=30, help="WebSockets declaring 15 MiB frames")
    parser.add_argument("--idle", type=int, default=1000, help="idle connections during the stream")
    parser.add_argument("--slow", type=int, default=500, help="slowloris connections")
    parser.add_argument("--timeout", type=float, default=5.0, help="[daemon] request_timeout_s of the daemon")
    parser.add_argument("--legacy", action="store_true", help="a daemon without the limits' settings (older code)")
    args = parser.parse_args()
    raise_fd_limit(args.idle + args.slow + 256)
    daemon_table = {} if args.legacy else {"request_timeout_s": args.timeout}
    with tempfile.TemporaryDirectory() as folder, ServeProcess(Path(folder), daemon=daemon_table) as daemon:
        daemon.wait_state("tracking", timeout_s=120)
        time.sleep(SETTLE_S)
        big_frames(daemon, args.big)
        idle(daemon, args.idle, args.timeout)
        slowloris(daemon, args.slow, args.timeout)
        print(f"daemon still answering: {daemon.status() is not None}")


if __name__ == "__main__":
    main()
