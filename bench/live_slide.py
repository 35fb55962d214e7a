"""The daemon on a rig without a grating under bench/magnification_drift.py's drifts, scored against the truth.

Each case's run streamed through the daemon's frame loop (tests/service/helpers.py stream_through_daemon:
the tracker built and switched in as for an installed model) with ``[daemon] grating = false``: the
pairing dropped, each streamed bound carrying the slide a magnification change could give the image
(service/daemon/slide.py; the axis undeclared, 300 px) — and, as the daemon did before, the same
stream without a grating and without the slide. For each: the share of streamed frames flagged, the
placed frames 4+ of their own bounds off the truth left unflagged, and the median streamed slide σ.
Then the same run as ``track --no-reference --chunk-frames 120`` (core/chunked.py, in this process)
with each chunk's slide carried, and without.

    nice -n 10 .venv/bin/python bench/live_slide.py [CASE-SUBSTRING]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' daemon helpers and the drift bench

import numpy as np  # noqa: E402

from bench.magnification_drift import CASES, FAR_PULL  # noqa: E402
from graytrack.core.calibration import calibrate  # noqa: E402
from graytrack.core.chunked import track_chunked  # noqa: E402
from graytrack.drivers.sim.scenarios import build_rig  # noqa: E402
from graytrack.service.daemon.slide import LiveSlide  # noqa: E402
from tests.service.helpers import stream_through_daemon  # noqa: E402


def streamed(model, run, truth, slide: LiveSlide | None) -> dict:
    """The run's frames through the daemon without a grating (``slide``: the slide carried), scored."""
    if slide is None:  # the daemon before: no grating paired, nothing carried
        run.reference[:] = np.nan
    messages, _, _ = stream_through_daemon(model, run, trim_enabled=False, slide=slide)
    fixes = [m for m in messages if m.get("x_mm") is not None and math.isfinite(m["x_mm"])]
    error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in fixes])
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.median(error) / period_um)  # the image alone: origin up to whole periods
    bound = np.array([m["crlb_um"] for m in fixes])
    flagged = np.array([bool(m["stale"]) for m in fixes])
    slide_um = np.array([m.get("slide_sigma_um", np.nan) for m in fixes])
    return {"placed": len(fixes), "flagged": float(flagged.mean()),
            "silent": int(((np.abs(error) > FAR_PULL * bound) & ~flagged).sum()),
            "slide_um": float(np.nanmedian(slide_um)) if np.isfinite(slide_um).any() else float("nan")}


def chunked(model, run, truth, slide: bool) -> dict:
    """The run tracked in chunks of 120 frames without a grating (``slide``: each chunk carrying it), scored."""
    result, _ = track_chunked(model, run.frames, np.full(run.n_frames, np.nan), 120, light="auto", robust=True,
                              slide=slide)
    error = (result.x_mm - truth.x_mm) * 1e3
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.nanmedian(error) / period_um)
    placed = np.isfinite(error)
    silent = placed & (np.abs(error) > FAR_PULL * result.crlb_mm * 1e3) & ~result.stale
    return {"placed": int(placed.sum()), "flagged": float(result.stale.mean()), "silent": int(silent.sum()),
            "slide_um": float(np.nanmedian(result.slide_sigma_um)) if slide else float("nan")}


def main(selection: str = "") -> None:
    chosen = [case for case in CASES if selection in f"{case[0]} {case[1]} seed={case[2]}"]
    for scenario, drift, seed in chosen:
        started = time.perf_counter()
        model = calibrate(build_rig(scenario, "", seed=seed).record(20.0)[0], "paper").model  # the rig before
        cells = []
        for mode, score in (("slide", lambda r, t: streamed(model, r, t, LiveSlide())),
                            ("before", lambda r, t: streamed(model, r, t, None)),
                            ("chunks slide", lambda r, t: chunked(model, r, t, True)),
                            ("chunks before", lambda r, t: chunked(model, r, t, False))):
            m = score(*build_rig(scenario, drift, seed=seed, run=1).record(10.0))
            cells.append(f"{mode}: flagged {100 * m['flagged']:.0f} % silent-far {m['silent']} of {m['placed']} "
                         f"({100 * m['silent'] / m['placed']:.1f} %)"
                         + (f" slide median {m['slide_um']:.2f} um" if math.isfinite(m["slide_um"]) else ""))
        print(f"{scenario} {drift} seed={seed} ({time.perf_counter() - started:.0f} s)\n    " + "\n    ".join(cells),
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "")
