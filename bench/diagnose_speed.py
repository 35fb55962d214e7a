"""Time of the closed loop on 16-row strips, on one core: 1,000 calibration frames × 16 rows × 100 px
of the paper's rig with rows of their own, and the lab strip (1,200 frames × 16 × 128), clean and
with a sensor gamma nobody declared (whose target-map trials, with every structure grown before
them, once took 11 minutes a step).

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

CASES = (  # (scenario, effects, seconds recorded)
    ("paper", "rows:n=16,tilt:deg=10,gradient:per_10mm=0.05", 20.0),
    ("paper", "rows:n=16,prnu:sigma=0.02,flicker:mains_hz=60:depth=0.03", 20.0),
    ("lab", "", 6.0),
    ("lab", "sensor_gamma:gamma=0.9", 6.0),
)


def main() -> None:
    for scenario, effects, seconds_recorded in CASES:
        rig = build_rig(scenario, effects, seed=1)
        recording, _ = rig.record(seconds_recorded)
        start = time.perf_counter()
        result = diagnose(recording, progress=ProgressBar("diagnose"))
        seconds = time.perf_counter() - start
        report = result.report()
        print(f"{scenario} {recording.frames.shape} {effects or '-'}: {seconds:.1f} s on one core; "
              f"steps {[step['effect'] for step in report['steps']]}; error std "
              f"{report['before']['error_std_um']:.3f} -> {report['after']['error_std_um']:.3f} um "
              f"(bound {report['noise']['crlb_um']:.3f} um)")


if __name__ == "__main__":
    main()
