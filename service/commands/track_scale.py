"""``graytrack track``'s camera-against-grating check and its ``--trim`` (the daemon's, run offline).

When the recording carries its grating reading, the tracked positions are followed frame by frame
by the same monitor the daemon runs (core/reference_monitor.py): a drift of the line camera −
grating is a ``scale`` warning on stderr and a flag in the CSV; ``--trim`` applies the online trim
as the daemon would have, causally, so what a live trim would have given can be measured on a file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording
    from graytrack.core.tracking import TrackResult

COLUMNS = ("scale_stale", "trim_um", "trim_sigma_um")  # appended to the CSV, after the contract's


@dataclass
class ScaleCheck:
    columns: dict[str, "np.ndarray"]
    lines: list[str] = field(default_factory=list)  # for stdout
    warning: str | None = None  # for stderr


def check(recording: "Recording", model: "FourierModel", result: "TrackResult", grating: "np.ndarray",
          trim: bool = False) -> ScaleCheck:
    """Follow the run against its grating; with ``trim`` the result's positions are trimmed in place.

    No grating in the recording: the columns are NaN and nothing is said.
    """
    import numpy as np

    from graytrack.core.noise import reference_resolution_mm
    from graytrack.core.reference_monitor import ReferenceMonitor, TrimEvent, follow, scale_tells

    n = result.x_mm.size
    if not scale_tells(model):
        empty = {name: np.full(n, np.nan) for name in COLUMNS}
        return ScaleCheck(empty, ["scale   not checked: the model errs beyond its bound on its own calibration"])
    if not np.isfinite(grating).any():
        empty = {name: np.full(n, np.nan) for name in COLUMNS}
        lines = ["scale   no grating reading in the recording: camera against grating not checked"] if trim else []
        return ScaleCheck(empty, lines)
    # the grating's step: as the recording says, else as its readings show (their grid)
    step = float(recording.meta.get("grating_resolution_mm", 0.0) or 0.0) or reference_resolution_mm(grating)
    monitor = ReferenceMonitor.for_model(model, step)
    usable = result.locked.copy()
    if result.stale_reason is not None:  # frames stale for what the images show: their cause, not a scale
        usable &= ~(result.stale & (result.stale_reason != "") & (result.stale_reason != "scale"))
    followed = follow(monitor, result.x_mm, grating, result.crlb_mm, usable, trim=trim)
    if trim:
        result.x_mm[:] = followed.x_mm
        if result.stale_reason is not None:  # the tracker's own scale watch knew no trim: the trimmed line holds
            cleared = (result.stale_reason == "scale") & ~followed.stale
            result.stale[cleared], result.stale_reason[cleared] = False, ""
    columns = {"scale_stale": followed.stale.astype(int), "trim_um": followed.trim_um,
               "trim_sigma_um": followed.trim_sigma_um}
    lines, warning = [], None
    flags = [(k, e) for k, e in followed.events if isinstance(e, str)]
    trims = [(k, e) for k, e in followed.events if isinstance(e, TrimEvent)]
    final = followed.final
    if final is not None:
        lines.append(f"scale   last window: {final.describe()}; frames flagged {int(followed.stale.sum())}")
    for k, event in trims[:10]:
        lines.append(f"  frame {k}: {event.message}")
    if flags:
        first, message = flags[0]
        remedy = "trimmed (--trim)" if trim else "recalibrate, or track with --trim to correct against the grating"
        warning = (f"warning: scale: from frame {first} on, {message}: the target or the camera moved along the axis "
                   f"since calibration; {remedy}")
    return ScaleCheck(columns, lines, warning)
