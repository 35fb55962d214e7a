"""Two runs of bench/estimator_sweep.py side by side: what a change moved, run by run.

A change of the estimator is judged on the whole sweep (``estimator_sweep.py --against``, both shards, their
outputs saved), before and after it. This reads the two saved outputs (each one file or several shards' files,
joined by commas) and prints the totals of each (runs above today's path, frames 4+ bounds off unflagged, frames
flagged, steady runs outside the acceptance) and every run whose error over today's noise floor moved by more than
``--tolerance`` (relative), whose unflagged frames changed, or that crossed today's path (``>>>``):

    .venv/bin/python bench/sweep_diff.py BEFORE_0.txt,BEFORE_1.txt AFTER_0.txt,AFTER_1.txt [--tolerance 0.05]

Each line: the mode, the run, the estimator's ratio before → after (over today's floor where the outputs were made
with ``--against``, else over its own), today's, the unflagged frames before → after, the share flagged, and the
``>>>`` mark before → after.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

LABEL, MODE = 67, 16  # the widths estimator_sweep.py prints a run's label and mode in (with their separating space)
_NUMBER = r"([-\d.]+|nan)"


@dataclass(frozen=True)
class Run:
    ratio: float  # the estimator's error std over today's noise floor (``--against``), else over its own
    today: float  # today's path's, where the output has it (NaN: none)
    silent: int  # frames 4+ bounds off unflagged
    flagged: float  # % of the run's frames
    above: bool  # more than 5 % above today's path (``>>>``)


@dataclass(frozen=True)
class Sweep:
    runs: dict[tuple[str, str], Run]  # by (mode, run's label)
    totals: dict[str, float]
    steady_outside: int


def _value(pattern: str, line: str, default: float = float("nan")) -> float:
    found = re.search(pattern, line)
    return float(found.group(1)) if found else default


def read(paths: list[Path]) -> Sweep:
    """The runs, totals and steady runs outside the acceptance of one sweep's output files (its shards)."""
    runs: dict[tuple[str, str], Run] = {}
    totals = dict.fromkeys(("above", "silent", "flagged", "lost"), 0.0)
    steady_outside = 0
    for path in paths:
        for line in path.read_text().splitlines():
            if line.startswith("total:"):
                totals["silent"] += _value(r"unflagged (\d+)", line, 0.0)
                totals["flagged"] += _value(r", flagged (\d+)", line, 0.0)
                totals["lost"] += _value(r"lost (\d+)", line, 0.0)
            elif line.startswith("against today's path:"):
                totals["above"] += _value(r": (\d+) runs", line, 0.0)
            elif line.startswith("steady:"):
                steady_outside += line.endswith("***")
            elif " ratio " in line and len(line) > LABEL + MODE:
                against = "on today's floor" in line
                runs[(line[LABEL:LABEL + MODE].strip(), line[:LABEL].strip())] = Run(
                    ratio=_value(r"on today's floor\s+" + _NUMBER if against else r"ratio\s+" + _NUMBER, line),
                    today=_value(r" today\s+" + _NUMBER, line),
                    silent=int(_value(r"silent\s+(\d+)", line, 0.0)),
                    flagged=_value(r"flag\s+" + _NUMBER + "%", line),
                    above=line.rstrip().endswith(">>>"))
    return Sweep(runs, totals, steady_outside)


def moved(before: Run, after: Run, tolerance: float) -> bool:
    """Whether a run moved: its ratio by more than ``tolerance`` (relative), its unflagged frames, or its mark."""
    scale = max(abs(before.ratio), 1e-12)
    return (abs(after.ratio - before.ratio) > tolerance * scale or after.silent != before.silent
            or after.above != before.above)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", help="the sweep's output before the change (shards' files joined by commas)")
    parser.add_argument("after", help="the sweep's output after it")
    parser.add_argument("--tolerance", type=float, default=0.05, help="relative change of a run's ratio shown")
    args = parser.parse_args(argv)
    sweeps = []
    for given in (args.before, args.after):
        paths = [Path(part) for part in given.split(",") if part]
        missing = [str(path) for path in paths if not path.is_file()]
        if missing:
            print(f"sweep_diff: no such file: {', '.join(missing)}", file=sys.stderr)
            return 2
        sweeps.append(read(paths))
    before, after = sweeps
    for name, sweep in (("before", before), ("after", after)):
        totals = sweep.totals
        print(f"{name:6}: {len(sweep.runs)} runs, {totals['above']:.0f} above today's path, unflagged 4+ bounds off "
              f"{totals['silent']:.0f}, flagged {totals['flagged']:.0f}, lost {totals['lost']:.0f}, steady runs "
              f"outside the acceptance {sweep.steady_outside}")
    shown = 0
    for key, was in before.runs.items():
        now = after.runs.get(key)
        if now is None or not moved(was, now, args.tolerance):
            continue
        shown += 1
        mode, label = key
        print(f"{mode:15} {label[:60]:60} {was.ratio:7.2f} → {now.ratio:7.2f} (today {now.today:6.2f}) "
              f"unflagged {was.silent} → {now.silent} flagged {was.flagged:.1f} → {now.flagged:.1f} % "
              f"{'>>>' if was.above else '   '} → {'>>>' if now.above else '   '}")
    missing = sorted(set(before.runs) ^ set(after.runs))
    print(f"{shown} runs moved beyond {100 * args.tolerance:.0f} % or in their marks"
          + (f"; {len(missing)} runs in one output only" if missing else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
