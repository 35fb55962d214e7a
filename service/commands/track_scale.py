"""``graytrack track``'s camera-against-grating check and its ``--trim`` (the daemon's, run offline).

When the recording carries its grating reading, the tracker's scale watch (core/watches/scale.py,
the one the daemon runs) follows the positions frame by frame: a drift of the line camera − grating
is a ``scale`` warning on stderr and a flag in the CSV; with ``--trim`` the watch carries the online
trim as the daemon's does, causally, so what a live trim would have given can be measured on a
file, each trimmed position's bound with the trim's uncertainty and lag.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording
    from graytrack.core.tracking import TrackResult
    from graytrack.core.watches.scale import ScaleWatch

COLUMNS = ("scale_stale", "trim_um", "trim_sigma_um")  # appended to the CSV, after the contract's


@dataclass
class ScaleCheck:
    columns: dict[str, "np.ndarray"]
    lines: list[str] = field(default_factory=list)  # for stdout
    warning: str | None = None  # for stderr


def scale_watch(recording: "Recording", model: "FourierModel", grating: "np.ndarray",
                trim: bool = False) -> "ScaleWatch | None":
    """The tracker's scale watch for this run, with the trim of ``--trim``, to hand to ``track(...,
    watches=)``: the one monitor of camera against grating (None: the model or the run cannot tell)."""
    import numpy as np

    from graytrack.core.noise import reference_resolution_mm
    from graytrack.core.reference_monitor import scale_tells
    from graytrack.core.watches.scale import ScaleWatch

    if not scale_tells(model) or not np.isfinite(grating).any():
        return None
    # the grating's step: as the recording says, else as its readings show (their grid)
    step = float(recording.meta.get("grating_resolution_mm", 0.0) or 0.0) or reference_resolution_mm(grating)
    return ScaleWatch.for_model(model, step, trim=trim, log=True)


def check(recording: "Recording", model: "FourierModel", result: "TrackResult", trim: bool = False,
          watch: "ScaleWatch | None" = None) -> ScaleCheck:
    """What the run's scale watch (:func:`scale_watch`, handed to the tracker) saw; with ``trim`` the
    result's positions are trimmed in place and their bounds carry what the trim adds (its
    uncertainty and lag). A watch the tracker was not handed (tracked in chunks) follows the
    result's positions now. No watch (no grating): the columns are NaN and nothing is said."""
    import numpy as np

    from graytrack.core.reference_monitor import drift_message, scale_tells

    n = result.x_mm.size
    empty = {name: np.full(n, np.nan) for name in COLUMNS}
    if not scale_tells(model):
        return ScaleCheck(empty, ["scale   not checked: the model errs beyond its bound on its own calibration"])
    if watch is not None and watch.log is not None and not watch.log:
        _follow(watch, result, recording)
    if watch is None or watch.log is None or len(watch.log) != n:
        lines = ["scale   no grating reading in the recording: camera against grating not checked"] if trim else []
        return ScaleCheck(empty, lines)
    flagged = np.array([applied.flagged for applied in watch.log])
    trim_um = np.array([applied.trim_um for applied in watch.log])
    sigma_um = np.array([applied.sigma_um for applied in watch.log])
    if trim:
        placed = np.isfinite(result.x_mm)
        result.x_mm[placed] -= trim_um[placed] * 1e-3
        result.crlb_mm[:] = np.sqrt(result.crlb_mm ** 2 + (sigma_um * 1e-3) ** 2)
    columns = {"scale_stale": flagged.astype(int), "trim_um": trim_um, "trim_sigma_um": sigma_um}
    lines, warning = [], None
    final = watch.monitor.estimate
    if final is not None:
        lines.append(f"scale   last window: {final.describe()}; frames flagged {int(flagged.sum())}")
    for k, event in watch.events[:10]:
        lines.append(f"  frame {k}: {event.message}")
    drifted = np.array([applied.drifted for applied in watch.log])
    if drifted.any():  # the line moved (single frames off it are the stale warning's)
        first = int(np.argmax(drifted))
        remedy = "trimmed (--trim)" if trim else "recalibrate, or track with --trim to correct against the grating"
        warning = (f"warning: scale: from frame {first} on, {drift_message(watch.monitor)}: the target or the camera "
                   f"moved along the axis since calibration; {remedy}")
    return ScaleCheck(columns, lines, warning)


def _follow(watch: "ScaleWatch", result: "TrackResult", recording: "Recording") -> None:
    """The watch over a result tracked without it (in chunks): its placed frames, in order."""
    import numpy as np

    information = np.where(result.crlb_mm > 0, (watch.bound_scale / result.crlb_mm) ** 2, np.nan)
    suspect = result.stale & (result.stale_reason != "") & (result.stale_reason != "scale") \
        if result.stale_reason is not None else np.zeros(result.x_mm.size, dtype=bool)
    for k in range(result.x_mm.size):
        watch.step(bool(suspect[k]), bool(result.locked[k]), float(result.x_mm[k]), float(recording.reference[k]),
                   float(information[k]))
