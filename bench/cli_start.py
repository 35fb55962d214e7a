"""Start-up time of the command line: `graytrack track --help` next to bare Python and numpy.

The parser is built for every command, so whatever a command module imports at its top is paid
by every invocation. The last line times importing, eagerly, what the commands import when they
run (numerics, plotting, the hardware configuration): what `--help` used to cost. Wall time and
the child's CPU time are both printed: on a loaded machine the CPU time is the steadier figure.
Run: .venv/bin/python bench/cli_start.py
"""

from __future__ import annotations

import resource
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


def timed(argv: list[str]) -> tuple[float, float]:
    """(wall, CPU) seconds of one run of ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    for argv in CASES.values():  # warm the file cache once
        timed(argv)
    medians = {}
    for name, argv in CASES.items():
        runs = [timed(argv) for _ in range(REPEATS)]
        medians[name] = tuple(statistics.median(values) for values in zip(*runs))
        wall, cpu = medians[name]
        print(f"{name:<36} wall {wall * 1e3:6.0f} ms, CPU {cpu * 1e3:6.0f} ms (medians of {REPEATS})")
    eager, lazy = medians["every command's run-time imports"], medians["graytrack track --help"]
    print(f"`track --help` starts {eager[0] / lazy[0]:.1f}x faster (wall; {eager[1] / lazy[1]:.1f}x CPU) "
          "than importing every command's numerics")


if __name__ == "__main__":
    main()
