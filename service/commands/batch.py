"""``graytrack batch {track,diagnose,calibrate} PATHS… --out DIR [--scheduler ADDRESS] [--workers N]``.

The single commands over many recordings on Dask: each recording's outputs go to ``DIR/<name>/``
as the single command writes them, one row per recording to ``DIR/summary.csv``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from graytrack.service.batch.cluster import add_cluster_arguments, dask_client, distributed_module
from graytrack.service.batch.discover import discover

HELP = {
    "track": "track every recording (model: --model, else model.json beside the recording)",
    "diagnose": "the closed loop on every recording: report.json, report.html, model.json each",
    "calibrate": "calibrate every recording: model.json each",
}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "batch", help="run track, diagnose or calibrate over many recordings on a Dask cluster (graytrack[cluster])",
        description="PATHS are recordings, folders or globs; a daemon's data directory contributes its "
                    "calibrations/*/recording.npz. Without --scheduler a local cluster of processes is started.")
    kinds = parser.add_subparsers(dest="kind", metavar="WORK", required=True)
    for kind, text in HELP.items():
        sub = kinds.add_parser(kind, help=text)
        sub.add_argument("paths", nargs="+", metavar="PATHS", help="recordings, folders or globs")
        sub.add_argument("--out", required=True, metavar="DIR", help="DIR/<name>/ per recording and DIR/summary.csv")
        sub.add_argument("--force", action="store_true", help="redo recordings whose outputs are already complete")
        add_cluster_arguments(sub)
        if kind == "track":
            sub.add_argument("--model", default=None, help="model file for every recording")
            sub.add_argument("--no-reference", action="store_true", help="track on the image alone")
        if kind == "calibrate":
            sub.add_argument("--model", choices=("ideal", "paper", "auto"), default="paper", help="model kind")
        sub.set_defaults(func=run)


def options(args: argparse.Namespace) -> dict:
    """What the work depends on besides the recording: resume redoes a recording when it changes."""
    if args.kind == "track":
        return {"model": str(Path(args.model).resolve()) if args.model else None, "no_reference": args.no_reference}
    if args.kind == "calibrate":
        return {"model": args.model}
    return {}


def run(args: argparse.Namespace) -> int:
    from graytrack.service.batch.runner import run_batch

    distributed_module()  # say how to install Dask before looking at anything else
    sources = discover(args.paths)
    with dask_client(args.scheduler, args.workers) as client:
        outcome = run_batch(client, args.kind, sources, args.out, options(args), force=args.force)
    frames = sum(int(row["frames"] or 0) for row in outcome.rows)
    print(f"batch   {args.kind}: {len(outcome.rows)} recording(s), {outcome.ran} run, {outcome.skipped} skipped, "
          f"{len(outcome.failed)} failed, {frames} frames in {outcome.seconds:.1f} s")
    for row in outcome.failed:
        print(f"  failed {row['path']}: {row['reason']}")
    print(f"wrote   {outcome.summary}")
    return 1 if outcome.failed else 0
