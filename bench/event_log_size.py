"""The event log's file under its retention (``[daemon] events_max_count``): it stops growing.

Writes ``--events`` move events (the commonest kind, ≈ 140 B of message and details) through the
daemon's :class:`EventLog` onto a fresh record in a temporary directory, and prints the size of
``record.sqlite`` plus its WAL as they go: it grows until ``--max-count`` events are kept, then
stays flat (the compaction's freed pages are reused by the next events).

Run: .venv/bin/python bench/event_log_size.py [--events 300000] [--max-count 100000]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from graytrack.service.daemon.event_log import EventLog
from graytrack.service.daemon.history import LabHistory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=300_000)
    parser.add_argument("--max-count", type=int, default=100_000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "record.sqlite"
        history = LabHistory(path)
        log = EventLog(history, lambda: None, lambda reason: None, max_age_days=90.0, max_count=args.max_count)
        started, step = time.perf_counter(), max(1, args.events // 6)
        for i in range(args.events):
            target = i % 1000 / 100
            log.write("move", f"move to {target:g} mm", target_mm=target)
            if (i + 1) % step == 0:
                size = os.path.getsize(path) + os.path.getsize(f"{path}-wal")
                print(f"{i + 1:>9} events written: record + WAL {size / 1e6:6.1f} MB")
        kept = history.events(limit=1)[0]["id"]
        history.close()
    print(f"{args.events} events in {time.perf_counter() - started:.0f} s; the oldest kept has id {kept} "
          f"(max_count {args.max_count})")


if __name__ == "__main__":
    main()
