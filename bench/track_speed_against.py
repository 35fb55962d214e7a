"""bench/track_speed.py on this checkout and on another revision, in turns, side by side with ratios.

The machine is shared: two runs taken apart mix the loads of two moments, and their ratio says as
much about the neighbours as about the code. This runs the bench (``plain`` by default) on this tree
and on ``REF`` (exported by ``git archive`` into a temporary folder; the child's editable-install
finder pointed at it) alternately, ``ROUNDS`` times each, and prints every row's best figure of both:
frames/s (higher is better) and live µs (lower is better), with the ratio this tree / REF.

Run: .venv/bin/python bench/track_speed_against.py [REF=main] [ROUNDS=3] [PART=plain]
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the child's imports of graytrack.* resolved in ROOT (the editable install maps them to the checkout it was
# installed from, which need not be this one: another worktree run with the same interpreter)
PRELUDE = """
import os, runpy, sys
import __editable___graytrack_0_1_0_finder as finder
installed = os.path.dirname(finder.MAPPING["graytrack"])
for key, value in list(finder.MAPPING.items()):
    finder.MAPPING[key] = value.replace(installed, {root!r}, 1)
sys.argv = ["bench/track_speed.py", {part!r}]
runpy.run_path("bench/track_speed.py", run_name="__main__")
"""
ROW = re.compile(r"^\s+(.+?)\s+([\d.]+) (frames/s|us)\b")
HEADING = re.compile(r"^(\d+) row\(s\)")


def figures(root: str, part: str) -> dict[str, tuple[float, str]]:
    """One run of the bench in ``root``: {row: (value, unit)}; live rows are read as their p50."""
    code = PRELUDE.format(root=root, part=part)
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True).stdout
    rows, heading = {}, ""
    for line in out.splitlines():
        if (match := HEADING.match(line)) is not None:
            heading = f"{match.group(1)} row "
        elif "live update" in line and (p50 := re.search(r"p50\s+([\d.]+) us", line)) is not None:
            rows[heading + line.split("p50")[0].strip()] = (float(p50.group(1)), "us")
        elif (match := ROW.match(line)) is not None:
            rows[heading + match.group(1)] = (float(match.group(2)), match.group(3))
    return rows


def main() -> None:
    ref = sys.argv[1] if len(sys.argv) > 1 else "main"
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    part = sys.argv[3] if len(sys.argv) > 3 else "plain"
    with tempfile.TemporaryDirectory() as root:
        archive = subprocess.run(["git", "archive", ref], cwd=HERE, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", root], input=archive, check=True)
        best: dict[str, dict[str, tuple[float, str]]] = {"this": {}, "ref": {}}
        for _ in range(rounds):
            for name, tree in (("ref", root), ("this", HERE)):
                for row, (value, unit) in figures(tree, part).items():
                    kept = best[name].get(row)
                    better = kept is None or (value > kept[0] if unit == "frames/s" else value < kept[0])
                    best[name][row] = (value, unit) if better else kept
    print(f"best of {rounds} alternating runs of bench/track_speed.py {part}: {ref} against this tree")
    print(f"{'row':60} {ref:>14} {'this tree':>14} {'this/' + ref:>10}")
    for row, (value, unit) in best["this"].items():
        before = best["ref"].get(row)
        if before is None:
            continue
        ratio = value / before[0] if unit == "frames/s" else before[0] / value  # >1: faster
        print(f"{row:60.60} {before[0]:10.1f} {unit:>3} {value:10.1f} {unit:>3} {ratio:9.2f}x")


if __name__ == "__main__":
    main()
