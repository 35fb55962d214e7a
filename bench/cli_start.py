"""Start-up time of the command line: `graytrack track --help` next to bare Python and numpy.

The parser is built for every command, so whatever a command module imports at its top is paid
by every invocation. The last line times importing, eagerly, what the commands import when they
run (numerics, plotting, the hardware configuration): what `--help` used to cost.
Run: .venv/bin/python bench/cli_start.py
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

EAGER = ("import graytrack.service.report, graytrack.core.calibration, graytrack.core.diagnosis, "
         "graytrack.core.tracking, graytrack.drivers.config, graytrack.drivers.sim.scenarios")
CASES = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
    "graytrack track --help": [sys.executable, "-m", "graytrack", "track", "--help"],
    "every command's run-time imports": [sys.executable, "-c", EAGER],
}
REPEATS = 7


def wall_seconds(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    for argv in CASES.values():  # warm the file cache once
        wall_seconds(argv)
    medians = {name: statistics.median(wall_seconds(argv) for _ in range(REPEATS)) for name, argv in CASES.items()}
    for name, seconds in medians.items():
        print(f"{name:<36} {seconds * 1e3:7.0f} ms (median of {REPEATS})")
    ratio = medians["every command's run-time imports"] / medians["graytrack track --help"]
    print(f"`track --help` starts {ratio:.1f}x faster than importing every command's numerics")


if __name__ == "__main__":
    main()
