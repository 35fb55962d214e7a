"""Can a light field of a frame's own ride through a moving shadow? What the frames allow, by degree.

A cable's shadow (`moving_shadow`) darkens a soft-edged band that crosses the field in about 50
frames: its shape is new on every frame, so a field following it must be solved per frame. This
prints, over the frames the shadow is in view, what such a field gives when started from the truth:
Legendre degree 0 (a uniform gain and offset, what the tracker answers with) up to 10, the error
against the truth and the joint solve's bound (the Schur complement of x with every field term),
and the frame's χ² against the calibration's level; then the same after the shadow has left (the
price of the field's freedom on a frame that needs none).

    .venv/bin/python bench/shadow_fields.py [SCENARIO] [SHADOW-SPEC]
"""

from __future__ import annotations

import sys

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.solvers import field_basis, field_solve, gauss_newton
from graytrack.core.tracking import Tracker
from graytrack.drivers.sim.scenarios import build_rig

DEGREES = (0, 2, 3, 4, 5, 6, 8, 10)


def main(scenario: str = "paper", shadow: str = "moving_shadow:passes=1:start_s=2") -> None:
    calibration, _ = build_rig(scenario, "", seed=3).record(20.0)
    model = calibrate(calibration, "paper").model
    tracker = Tracker(model, light="auto")
    rig = build_rig(scenario, shadow, seed=3, run=1)
    run, truth = rig.record(4.0)
    shown = np.nonzero(rig.config.illumination.shadow.in_view(truth.t_s, rig.geometry.x_mm))[0]
    frames = np.asarray(run.frames, dtype=np.float64)
    batch = tracker.batch(tracker.prepare(frames), 1 if frames.ndim == 2 else frames.shape[1])
    after = shown.max() + 20
    print(f"{scenario}, {shadow}: shadow in view on frames {shown.min()}..{shown.max()}; "
          f"calibration χ² {tracker.chi2_calibration:.2f}")
    print(f"{'degree':>6} {'error rms µm':>12} {'bound rms µm':>12} {'bound max':>9} {'χ² median':>9}"
          f" | after it left: {'bound µm':>8} {'χ²':>5}")
    for degree in DEGREES:
        basis = field_basis(model.n_rows, model.n_pixels, degree) if degree else None
        rows = []
        for k in [*shown, after]:
            uniform = gauss_newton(batch, k, truth.x_mm[k], True, tracker.settings)
            solution = field_solve(tracker.evaluator, batch.frames[k], batch.weights(k), basis, uniform,
                                   tracker.settings) if degree else uniform
            rows.append(((solution.x_mm - truth.x_mm[k]) * 1e3, 1e3 / np.sqrt(solution.information), solution.chi2))
        table = np.array(rows)
        inside, last = table[:-1], table[-1]
        print(f"{degree:6d} {np.sqrt(np.mean(inside[:, 0] ** 2)):12.1f} {np.sqrt(np.mean(inside[:, 1] ** 2)):12.2f}"
              f" {inside[:, 1].max():9.1f} {np.median(inside[:, 2]):9.2f} | {last[1]:22.2f} {last[2]:5.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
