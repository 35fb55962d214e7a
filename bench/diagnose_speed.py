"""Time of the closed loop on 1,000 calibration frames × 16 rows × 100 px, on one core.

BLAS threads are pinned to one before numpy loads, so the figure is the one-core figure the issue
asks for. Progress goes to stderr as the command line shows it.
Run: .venv/bin/python bench/diagnose_speed.py
"""

from __future__ import annotations

import os

for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[variable] = "1"

import time  # noqa: E402

from graytrack.core.diagnosis import diagnose  # noqa: E402
from graytrack.drivers.sim.scenarios import build_rig  # noqa: E402
from graytrack.service.progress import ProgressBar  # noqa: E402

CASES = (
    "rows:n=16,tilt:deg=10,gradient:per_10mm=0.05",
    "rows:n=16,prnu:sigma=0.02,flicker:mains_hz=60:depth=0.03",
)


def main() -> None:
    for effects in CASES:
        rig = build_rig("paper", effects, seed=1)
        recording, _ = rig.record(20.0)
        start = time.perf_counter()
        result = diagnose(recording, progress=ProgressBar("diagnose"))
        seconds = time.perf_counter() - start
        report = result.report()
        print(f"{recording.frames.shape} {effects}: {seconds:.1f} s on one core; "
              f"steps {[step['effect'] for step in report['steps']]}; error std "
              f"{report['before']['error_std_um']:.3f} -> {report['after']['error_std_um']:.3f} um "
              f"(bound {report['noise']['crlb_um']:.3f} um)")


if __name__ == "__main__":
    main()
