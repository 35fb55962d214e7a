"""What the frames far off the grating are named: a wrong model against a lens's slide.

A model of another rig (its period or its pixel pitch 1 % or 5 % off) places the camera tens to
hundreds of µm off the grating; so does a lens whose magnification drifts with the optical axis far
off the ROI. The first is the model's ``scale`` (core/watches/far_off.py), the second the lens's
``magnification`` (the scale watch names the far-off judgement it carries with what drifted its line,
core/watches/scale.py). For each wrong model, at rest and in a sweep, on the paper rig and the 16-row
strip, tracked as ``track`` does (its own scale watch) and as the command does (the watch handed in):
the share of settled frames flagged and their reasons. The lens's far slide is
``bench/magnification_drift.py "axis_px=-500"``.

    .venv/bin/python bench/far_off_names.py [SCENARIO]
"""

from __future__ import annotations

import collections
import sys

from graytrack.core.calibration import calibrate
from graytrack.core.tracking import track
from graytrack.core.watches.far_off import WINDOW
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.sim.stage import oscillation
from graytrack.service.commands.track_scale import scale_watch

WRONG = [("period_mm", 1.01), ("period_mm", 1.05), ("pixel_pitch_mm", 1.01), ("pixel_pitch_mm", 1.05)]
SETTLED = WINDOW + 10  # frames before the far-off judgement's window is full, and some


def main(selection: str = "") -> None:
    for scenario in [name for name in ("paper", "strip16") if selection in name]:
        model = calibrate(build_rig(scenario, "", seed=3).record(20.0)[0], "paper").model
        for key, factor in WRONG:
            wrong = model.with_changes(**{key: getattr(model, key) * factor}, coeffs=model.coeffs)
            for trajectory in ("rest", "sweep"):
                motion = {"trajectory": oscillation(5.0, 0.0, 1.0)} if trajectory == "rest" else {}
                run, _ = build_rig(scenario, "", seed=3, run=1).record(4.0, **motion)
                for mode in ("track", "command"):
                    watch = scale_watch(run, wrong, run.reference) if mode == "command" else None
                    result = track(wrong, run, light="auto", robust=True, watches=[watch] if watch else [])
                    named = collections.Counter(result.stale_reason[SETTLED:].tolist()).most_common(4)
                    print(f"{scenario:8} {key} ×{factor} {trajectory:5} {mode:7} flagged "
                          f"{100 * result.stale[SETTLED:].mean():3.0f} % {dict(named)}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
