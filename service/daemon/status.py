"""The status document (``GET /api/status``) and the health answer, derived from the parts at read time.

Nothing here is stored: the state, the rate and the position are computed from the newest data
and its age when asked, so a stopped frame loop cannot leave a frozen "tracking" behind. A
figure older than ``stale_after_s`` is withdrawn (``null``, ``stale: true``) instead of shown.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from graytrack import __version__
from graytrack.core.frame_record import FIT
from graytrack.service.daemon.supervision import sentence

if TYPE_CHECKING:
    from graytrack.service.daemon.rig import Rig

JOB_FIELDS = ("id", "state", "progress", "message", "error")


def state(rig: "Rig") -> str:
    """stopping > fault > starting > calibrating > tracking > idle (module doc of ``rig``)."""
    if rig.closing.is_set():
        return "stopping"
    if rig.faults.snapshot():
        return "fault"
    if rig.acquisition is None:
        return "starting"
    if rig.job is not None and rig.job.active:
        return "calibrating"
    return "tracking" if rig.model is not None else "idle"


def tracking_fresh(rig: "Rig") -> bool:
    """Frames are being tracked now (what ``/healthz`` answers 200 for)."""
    acquisition = rig.acquisition
    return (acquisition is not None and rig.model is not None and acquisition.tracker is not None
            and acquisition.seconds_since_tracked() <= rig.settings.daemon.stale_after_s
            and not rig.faults.snapshot())


def status(rig: "Rig") -> dict[str, Any]:
    faults = rig.faults.snapshot()
    acquisition, grating = rig.acquisition, rig.grating
    stale_after = rig.settings.daemon.stale_after_s
    last = acquisition.stats.last_message if acquisition is not None else None
    fresh = last is not None and acquisition is not None and acquisition.seconds_since_tracked() <= stale_after
    job = rig.job
    rate = acquisition.frame_rate_hz(stale_after) if acquisition is not None else 0.0
    model_stale = acquisition.model_stale if acquisition is not None and rig.model is not None else None
    return {
        "state": state(rig),
        "calibrated": rig.model is not None,
        "position_mm": last["x_mm"] if fresh else None,
        "locked": bool(last["locked"]) if fresh else None,
        "crlb_um": last.get("crlb_um") if fresh else None,
        # the tracker's per-frame fit figures (core/frame_record.py: gain, offset, rejected samples, χ², stale model)
        "fit": {key: last[key] for key in FIT if key in last} if fresh else None,
        "stale": last is not None and not fresh,
        "model_stale": model_stale is not None,
        "stale_reason": model_stale,
        "age_ms": round(acquisition.seconds_since_tracked() * 1e3, 1) if last is not None and acquisition else None,
        "grating_mm": grating.fresh_mm(stale_after) if grating is not None else None,
        "grating_age_ms": round(silent * 1e3, 1) if grating is not None and (silent := grating.silent_s()) is not None
        else None,
        "moving": rig.readings.moving() if grating is not None else None,
        "target_mm": rig.stage.target_mm,
        "velocity_mm_s": rig.stage.velocity_mm_s,
        "reason": sentence(faults),
        "faults": faults,
        "model": rig.model.describe() if rig.model is not None else None,
        "limits_mm": list(rig.hardware.stage.limits()) if rig.hardware is not None else None,
        "frame_rate_hz": round(rate, 2),
        "frames": acquisition.stats.frames if acquisition is not None else 0,
        "dropped": acquisition.stats.dropped if acquisition is not None else 0,
        "calibration": None if job is None else {key: job.to_dict()[key] for key in JOB_FIELDS},
        "active_calibration": rig.active_calibration(),
        "trim": acquisition.trim.status() if acquisition is not None else None,  # camera against grating
        "simulated": rig.settings.simulated,
        "uptime_s": round(time.monotonic() - rig.started_at, 3),
        "version": __version__,
    }
