"""Running a batch: skip what is finished, submit the rest to Dask, collect rows as they finish.

Rows are collected with ``as_completed``, so a slow recording never holds up the report of the
others, and ``summary.csv`` is rewritten after each one: an interrupted batch leaves a summary of
what it finished, and its next run resumes from the markers.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from graytrack.service.batch.discover import Source
from graytrack.service.batch.jobs import Job, finished_row, one_line, run_job
from graytrack.service.batch.summary import SUMMARY, format_row, write_summary


@dataclass
class BatchOutcome:
    rows: list[dict[str, str]]
    skipped: int
    ran: int
    seconds: float
    summary: Path
    failed: list[dict[str, str]] = field(default_factory=list)


class Progress:
    """done/total, failures and the rate, one line per finished recording on stderr."""

    def __init__(self, total: int, stream: TextIO | None = None):
        self.total, self.stream = total, stream or sys.stderr
        self.started = time.perf_counter()
        self.done = self.failed = self.frames = 0

    def __call__(self, row: dict[str, str]) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        self.frames += int(row["frames"] or 0)
        elapsed = max(time.perf_counter() - self.started, 1e-9)
        left = (self.total - self.done) * elapsed / self.done
        self.stream.write(f"batch: {self.done}/{self.total} done, {self.failed} failed, "
                          f"{self.done / elapsed:.2f} rec/s, {self.frames / elapsed:.0f} frames/s, "
                          f"~{left:.0f} s left ({row['name']}: {row['status']})\n")
        self.stream.flush()


def _failed_row(job: Job, exc: BaseException) -> dict[str, str]:
    """A recording whose task died with its worker (or was lost) still gets its row."""
    return format_row({"path": str(job.source.path), "name": job.source.name, "rig": job.source.rig,
                       "calibrated_at": job.source.calibrated_at, "status": "failed",
                       "reason": f"worker: {one_line(exc)}"})


def run_batch(client: Any, kind: str, sources: list[Source], out_dir: str | Path, options: dict[str, Any],
              force: bool = False, stream: TextIO | None = None) -> BatchOutcome:
    from distributed import as_completed

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = out_dir / SUMMARY
    started = time.perf_counter()
    jobs = [Job(kind, source, str(out_dir), options) for source in sources]
    rows: dict[str, dict[str, str]] = {}
    for job in jobs:
        row = None if force else finished_row(job)
        if row is not None:
            rows[job.source.name] = row
    todo = [job for job in jobs if job.source.name not in rows]
    stream = stream or sys.stderr
    if rows:
        stream.write(f"batch: {len(rows)} of {len(jobs)} recording(s) already done, skipped (--force redoes them)\n")
    ordered = lambda: [rows[job.source.name] for job in jobs if job.source.name in rows]  # noqa: E731
    progress = Progress(len(todo), stream)
    futures = {client.submit(run_job, job, pure=False): job for job in todo}
    for future in as_completed(futures):
        job = futures[future]
        try:
            row = future.result()
        except Exception as exc:  # noqa: BLE001 - a lost worker fails this row, not the batch
            row = _failed_row(job, exc)
        rows[job.source.name] = row
        progress(row)
        write_summary(summary, ordered())
    write_summary(summary, ordered())
    final = ordered()
    return BatchOutcome(final, len(jobs) - len(todo), len(todo), time.perf_counter() - started, summary,
                        [row for row in final if row["status"] != "ok"])
