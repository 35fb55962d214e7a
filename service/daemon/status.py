"""The status document (``GET /api/status``), made from a :class:`RigSnapshot`.

Nothing here is stored: the state, the rate and the position are derived from the newest data
and its age at the instant of the snapshot, so a stopped frame loop cannot leave a frozen
"tracking" behind. A figure older than ``stale_after_s`` is withdrawn (``null``, ``stale: true``)
instead of shown. This module reads the snapshot only, never the rig: what it shows is what one
instant of the parts said (:mod:`snapshot`).
"""

from __future__ import annotations

from typing import Any

from graytrack import __version__
from graytrack.core.frame_record import FIT
from graytrack.service.daemon.snapshot import RigSnapshot


def document(snapshot: RigSnapshot) -> dict[str, Any]:
    """The JSON body of ``GET /api/status`` (docs/contracts.md; its schema is ``graytrack.wire.Status``)."""
    loop, grating, devices = snapshot.frame_loop, snapshot.grating, snapshot.devices
    last = loop.last_message if loop is not None else None
    fresh = snapshot.newest_fresh
    return {
        "state": snapshot.state,
        "calibrated": snapshot.calibrated,
        "position_mm": last["x_mm"] if fresh else None,
        "locked": bool(last["locked"]) if fresh else None,
        "crlb_um": last.get("crlb_um") if fresh else None,
        # the tracker's per-frame fit figures (core/frame_record.py: gain, offset, rejected samples, χ², stale model)
        "fit": {key: last[key] for key in FIT if key in last} if fresh else None,
        "stale": last is not None and not fresh,
        "model_stale": snapshot.model_stale is not None,
        "stale_reason": snapshot.model_stale,
        "age_ms": round(loop.seconds_since_tracked * 1e3, 1) if last is not None else None,
        "grating_mm": grating.fresh_mm if grating is not None else None,
        "grating_age_ms": round(grating.silent_s * 1e3, 1) if grating is not None and grating.silent_s is not None
        else None,
        "moving": grating.moving if grating is not None else None,
        "target_mm": snapshot.target_mm,
        "velocity_mm_s": snapshot.velocity_mm_s,
        "reason": snapshot.reason,
        "faults": dict(snapshot.faults),
        "model": snapshot.model,
        "limits_mm": list(devices.limits_mm) if devices is not None else None,
        "frame_rate_hz": round(loop.frame_rate_hz, 2) if loop is not None else 0.0,
        "frames": loop.counters.frames if loop is not None else 0,
        "dropped": loop.counters.dropped if loop is not None else 0,
        "calibration": dict(snapshot.job) if snapshot.job is not None else None,
        "active_calibration": dict(snapshot.active_calibration) if snapshot.active_calibration is not None else None,
        "trim": dict(loop.trim) if loop is not None else None,  # camera against grating
        "slide": dict(loop.slide) if loop is not None and loop.slide is not None else None,  # without a grating
        "texture": dict(snapshot.texture) if snapshot.texture is not None else None,  # learned on the print
        # learned on the sensor's side (the estimator's map: service/daemon/sensor_map_store.py)
        "sensor_map": dict(snapshot.sensor_map) if snapshot.sensor_map is not None else None,
        # learned on the print by the estimator (service/daemon/print_map_store.py)
        "print_map": dict(snapshot.print_map) if snapshot.print_map is not None else None,
        "simulated": snapshot.simulated,
        "startup": None,  # the warm-up's step before the rig opens: the route adds it (service/daemon/startup.py)
        "uptime_s": round(snapshot.uptime_s, 3),
        "version": __version__,
    }
