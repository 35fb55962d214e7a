"""``graytrack history DIR… [--out FILE]``: each rig's calibrations against time, drift pointed out."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "history", help="τ_w, α·d, noise, held-out error and effects of each rig against calibration time (HTML)")
    parser.add_argument("folders", nargs="+", metavar="DIR",
                        help="output folders of `graytrack batch calibrate|diagnose` (their summary.csv)")
    parser.add_argument("--out", default=None, help="HTML file to write (default: DIR/history.html of the first DIR)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from graytrack.service.batch.history import load_calibrations
    from graytrack.service.batch.history_report import write_history

    rigs = load_calibrations(args.folders)
    first = Path(args.folders[0])
    out = Path(args.out) if args.out else (first.parent if first.is_file() else first) / "history.html"
    path, found = write_history(rigs, out)
    print(f"history {sum(len(c) for c in rigs.values())} calibration(s) of {len(rigs)} rig(s): "
          f"{', '.join(f'{rig} ({len(c)})' for rig, c in rigs.items())}")
    for change in found:
        print(f"  changed {change.text()}")
    if not found:
        print("  no change beyond the calibrations' uncertainty")
    print(f"wrote   {path}")
    return 0
