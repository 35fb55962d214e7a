"""A real ``graytrack serve`` on the virtual rig under pipelined HTTP requests (issue #48, docs/daemon.md
"Resource limits"): 10 loopback connections each writing ``GET /api/status`` 100 at a time without waiting
for the answers, for 20 s, reading what comes back. Prints the daemon's RSS before, at its peak during the
flood and after the connections closed, what the flood was answered, and the rig's counters (frames lost,
the stage link's failed readings, faults) over the flood against quiet windows of the same length just
before and after it.

    nice -n 5 .venv/bin/python bench/pipeline_flood.py [--connections 10] [--seconds 20] [--unread]
                                                       [--unauthorized] [--test-rig [--client-hz 200]]

``--unread``: the flood never reads its answers (the daemon's writes back up instead). ``--unauthorized``: a
stranger's flood, moves (``POST /api/stage/move``) without the token, each answered 401. ``--test-rig``: the
rig of tests/service/test_pipeline_flood.py (the tests' fast rig, 200 frames per wall second, its virtual rig
in a process of its own) instead of the embedded default that ``make run`` starts.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' daemon and client helpers

import httpx  # noqa: E402

from tests.service.helpers import ServeProcess  # noqa: E402
from tests.service.hostile import FLOOD_RIG, quiet_flood_quiet  # noqa: E402

UNAUTHORIZED = {"method": "POST", "path": "/api/stage/move", "body": b'{"target_mm": 1.0}'}  # what a stranger writes
SHOWN = ("frames", "frames_lost", "camera_dropped", "grating_errors", "faults")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connections", type=int, default=10, help="pipelining connections")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the flood (and of the quiet window)")
    parser.add_argument("--unread", action="store_true", help="the flood leaves its answers unread")
    parser.add_argument("--test-rig", action="store_true", help="the tests' fast rig instead of the default one")
    parser.add_argument("--unauthorized", action="store_true",
                        help="the flood writes moves (POST /api/stage/move) without the token instead of reads")
    parser.add_argument("--client-hz", type=float, default=None,
                        help="[daemon] requests_per_s_per_client of the test rig (default: the daemon's)")
    args = parser.parse_args()
    tables = {**FLOOD_RIG, "daemon": {"requests_per_s_per_client": args.client_hz}} if args.client_hz else FLOOD_RIG
    with tempfile.TemporaryDirectory() as folder, \
            ServeProcess(Path(folder), **tables) if args.test_rig else ServeProcess(Path(folder), True) as daemon:
        daemon.wait_state("tracking", timeout_s=300)
        request = UNAUTHORIZED if args.unauthorized else {}
        figures = quiet_flood_quiet(daemon.base, daemon.process.pid, daemon.port, args.seconds, args.connections,
                                    read_answers=not args.unread, **request)
        alive = daemon.status() is not None
        limits = [line for line in httpx.get(f"{daemon.base}/metrics", timeout=10).text.splitlines()
                  if line.startswith(("graytrack_connections_refused_total{", "graytrack_requests_paced_total "))]
        code = daemon.terminate()
    flood = figures.client
    what = "POST /api/stage/move without the token" if args.unauthorized else "GET /api/status"
    print(f"{args.connections} connections pipelining {what} for {args.seconds:g} s "
          f"({'answers unread' if args.unread else 'reading the answers'}): {flood.sent_requests:,} requests "
          f"written, {flood.answers:,} answered {dict(sorted(flood.statuses.items()))}; "
          f"{len(flood.errors)} connection errors {flood.errors[:3]}")
    print(f"RSS: {figures.rss_before_mb:.0f} MB before, peak {figures.rss_peak_mb:.0f} during "
          f"(+{figures.rss_peak_mb - figures.rss_before_mb:.1f}), {figures.rss_after_mb:.0f} a quiet window after "
          f"(+{figures.rss_after_mb - figures.rss_before_mb:.1f})")
    for name, window in (("quiet before", figures.quiet), ("flood", figures.flood),
                         ("quiet after", figures.quiet_after)):
        print(f"{name:>12} {args.seconds:g} s: " + ", ".join(f"{key} {window[key]:.0f}" for key in SHOWN))
    print("what the limits did: " + ", ".join(line.removeprefix("graytrack_") for line in limits))
    tracebacks = daemon.stderr.count("Traceback")
    print(f"daemon answering after the flood: {alive}; exit status {code}; {tracebacks} tracebacks, "
          f"{len(daemon.stderr.splitlines())} lines in its log")


if __name__ == "__main__":
    main()
