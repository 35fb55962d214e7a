"""The lens's magnification drifting during a run: tracked as `graytrack track` does, scored against the truth.

Calibrate (`--model paper`) on a run of the rig as it was; measure a second session in which the
magnification drifts (``magnification_drift``: a warm-up ramp or a temperature cycle, the optical
axis well off the ROI so the image slides while the stage stands). For each case: the error std
over the rms bound (against the truth, not the grating), the share of frames flagged and their
reasons, and the placed frames 4+ of their own bounds off the truth left unflagged — with the
grating read, with ``--trim``, and with ``--no-reference`` (no grating while running: each bound
carries the slide a magnification could give the image, core/slide.py, the axis undeclared; ``slide``
is the median over the unflagged placed frames of each one's bound over its noise floor).

    .venv/bin/python bench/magnification_drift.py [CASE-SUBSTRING]
"""

from __future__ import annotations

import collections
import sys
import time

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.slide import SlideWatch, carry
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.commands.track_scale import check, scale_watch

FAR_PULL = 4.0  # as bench/robustness_sweep.py: a placed frame this many of its bounds off is wrong
RAMP = "magnification_drift:ppm=1500:ramp_s=10"
CYCLE = "magnification_drift:ppm=1500:cycle_s=6"
CASES = [(scenario, drift, seed) for scenario in ("paper", "strip16") for drift in (RAMP, CYCLE) for seed in (3, 5)] + [
    ("paper", "magnification_drift:ppm=-800:ramp_s=4:start_s=3", 3),
    ("strip16", "magnification_drift:ppm=3000:axis_px=-500:ramp_s=10", 4),
    ("paper", "", 3), ("strip16", "", 3),  # steady: nothing drifts
]
MODES = {"grating": dict(trim=False, reference=True), "--trim": dict(trim=True, reference=True),
         "--no-reference": dict(trim=False, reference=False)}


def measured(model, run, truth, trim: bool, reference: bool) -> dict:
    """Tracked as `graytrack track` does (with ``--trim``, or ``--no-reference``), scored against the truth."""
    grating = run.reference if reference else np.full(run.n_frames, np.nan)
    watch = scale_watch(run, model, grating, trim)
    slide = None if watch is not None else SlideWatch.for_model(model)  # as `track` does without a grating
    result = track(model, run.frames, grating, light="auto", robust=True, watches=[watch or slide])
    floor_um = result.crlb_mm * 1e3
    scale = check(run, model, result, trim, watch).columns["scale_stale"] == 1
    carry(result, slide)
    error = (result.x_mm - truth.x_mm) * 1e3
    if not reference:  # acquired on the image alone: its origin is known up to whole periods
        period_um = model.period_mm * 1e3
        error -= period_um * np.round(np.nanmedian(error) / period_um)
    bound_um = result.crlb_mm * 1e3
    placed = np.isfinite(error)
    flagged = result.stale | scale
    far = placed & (np.abs(error) > FAR_PULL * bound_um)
    reasons = collections.Counter(r for r, f in zip(result.stale_reason, flagged) if f)
    return {"ratio": float(np.nanstd(error) / np.sqrt(np.nanmean(bound_um ** 2))),
            "rms_ratio": float(np.sqrt(np.nanmean(error ** 2)) / np.sqrt(np.nanmean(bound_um ** 2))),
            "flagged": float(flagged.mean()), "silent": float((far & ~flagged).sum() / max(placed.sum(), 1)),
            "reasons": dict(reasons.most_common(3)),
            "slide": float(np.median(bound_um[placed & ~flagged] / floor_um[placed & ~flagged]))
            if (placed & ~flagged).any() else float("nan")}


def main(selection: str = "") -> None:
    chosen = [case for case in CASES if selection in f"{case[0]} {case[1]} seed={case[2]}"]
    for scenario, drift, seed in chosen:
        started = time.perf_counter()
        model = calibrate(build_rig(scenario, "", seed=seed).record(20.0)[0], "paper").model  # the rig before
        run, truth = build_rig(scenario, drift, seed=seed, run=1).record(10.0)
        label, cells = f"{scenario} {drift} seed={seed}", []
        for mode, options in MODES.items():
            m = measured(model, run, truth, **options)
            cells.append(f"{mode}: {m['ratio']:.2f}x (rms {m['rms_ratio']:.2f}x) flagged {100 * m['flagged']:.0f} % "
                         f"{m['reasons']} silent-far {100 * m['silent']:.1f} %"
                         + (f" slide {m['slide']:.2f}x" if not options["reference"] else ""))
        print(f"{label} ({time.perf_counter() - started:.0f} s)\n    " + "\n    ".join(cells), flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
