"""``GET /metrics``: the daemon's counters and gauges in the Prometheus text format (v0.0.4).

Hand-written because the set is small and fixed, and the rig has no business pulling in a
client library for it. Names follow Prometheus conventions (``_total`` counters, base units).
"""

from __future__ import annotations

import math
from typing import Iterable

from graytrack.core.validity import FAMILIES
from graytrack.service.daemon import status as rig_status
from graytrack.service.daemon.broadcast import Broadcaster
from graytrack.service.daemon.rig import Rig

STATES = ("starting", "idle", "calibrating", "tracking", "fault", "stopping")
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


def _metric(name: str, kind: str, help_text: str, samples: Iterable[tuple[str, float]]) -> list[str]:
    lines = [f"# HELP {name} {help_text}", f"# TYPE {name} {kind}"]
    for labels, value in samples:
        text = "NaN" if value is None or (isinstance(value, float) and math.isnan(value)) else repr(float(value))
        lines.append(f"{name}{labels} {text}")
    return lines


def render(rig: Rig, broadcaster: Broadcaster) -> str:
    status = rig.status()
    acquisition, grating = rig.acquisition, rig.grating
    stats = acquisition.stats if acquisition is not None else None
    hardware = rig.hardware
    camera = hardware.camera.stats if hardware is not None else None
    link = hardware.stage.link.stats if hardware is not None else None
    position = status["position_mm"]
    out: list[str] = []
    out += _metric("graytrack_state", "gauge", "1 for the daemon's current state",
                   [(f'{{state="{s}"}}', float(status["state"] == s)) for s in STATES])
    out += _metric("graytrack_calibrated", "gauge", "1 when a model is installed", [("", float(status["calibrated"]))])
    out += _metric("graytrack_position_mm", "gauge", "last tracked position",
                   [("", float("nan") if position is None else position)])
    out += _metric("graytrack_crlb_um", "gauge", "Cramer-Rao bound of the last tracked frame",
                   [("", float("nan") if status["crlb_um"] is None else status["crlb_um"])])
    out += _metric("graytrack_frame_rate_hz", "gauge", "frames per second over the last frames (0 when stale)",
                   [("", status["frame_rate_hz"])])
    out += _metric("graytrack_stale", "gauge", "1 when the newest tracked frame is older than stale_after_s",
                   [("", float(status["stale"]))])
    out += _metric("graytrack_healthy", "gauge", "1 when frames are being tracked now (/healthz 200)",
                   [("", float(rig_status.tracking_fresh(rig)))])
    out += _metric("graytrack_frames_total", "counter", "camera frames received", [("", stats.frames if stats else 0)])
    out += _metric("graytrack_frames_tracked_total", "counter", "frames tracked", [("", stats.tracked if stats else 0)])
    out += _metric("graytrack_frames_unplaced_total", "counter", "tracked frames that could not be placed",
                   [("", stats.unplaced if stats else 0)])
    out += _metric("graytrack_lock_events_total", "counter", "lock losses and re-acquisitions",
                   [("", stats.lock_events if stats else 0)])
    out += _metric("graytrack_camera_dropped_frames_total", "counter", "frames the camera lost or skipped",
                   [("", camera.dropped if camera else 0)])
    out += _metric("graytrack_frames_dropped_total", "counter", "gaps in the camera's frame_id sequence (the stream's dropped)",
                   [("", stats.dropped if stats else 0)])
    out += _metric("graytrack_tracking_errors_total", "counter", "frames the tracker raised on",
                   [("", stats.tracking_errors if stats else 0)])
    out += _metric("graytrack_worker_crashes_total", "counter", "worker loops restarted after an exception",
                   [("", (acquisition.crashes if acquisition else 0) + (grating.crashes if grating else 0))])
    out += _metric("graytrack_camera_errors_total", "counter", "camera errors other than timeouts",
                   [("", stats.camera_errors if stats else 0)])
    out += _metric("graytrack_grating_reads_total", "counter", "POS? readings", [("", grating.reads if grating else 0)])
    out += _metric("graytrack_grating_errors_total", "counter", "failed POS? readings",
                   [("", grating.errors if grating else 0)])
    out += _metric("graytrack_stage_reconnects_total", "counter", "serial port reopened",
                   [("", link.reconnects if link else 0)])
    out += _metric("graytrack_faults_total", "counter", "faults raised", [("", rig.faults.raised)])
    out += _metric("graytrack_calibrations_total", "counter", "calibration sweeps finished by outcome",
                   [(f'{{outcome="{k}"}}', v) for k, v in sorted(rig.calibrations_finished.items())])
    out += _metric("graytrack_websocket_clients", "gauge", "connected /ws/position clients",
                   [("", broadcaster.clients)])
    out += _metric("graytrack_websocket_messages_total", "counter", "position messages sent",
                   [("", broadcaster.sent)])
    out += _metric("graytrack_websocket_dropped_total", "counter", "messages dropped for slow clients",
                   [("", broadcaster.dropped)])
    out += _metric("graytrack_model_stale", "gauge", "1 for the family of causes the model is stale for (all 0: it holds)",
                   [(f'{{reason="{family}"}}', float(status.get("stale_reason") == family)) for family in FAMILIES])
    fit = status.get("fit") or {}
    for key, help_text in (("chi2", "reduced chi-square of the newest frame's fit"),
                           ("rejected_px", "pixels the newest frame's fit rejected"),
                           ("transient_px", "samples of the newest frame set aside as a transient (glint, dust)"),
                           ("focus", "change of blur variance since calibration, px^2 (NaN: not estimated)"),
                           ("stale", "1 when the tracker flags the model as stale (recalibrate)")):
        if key in fit:
            out += _metric(f"graytrack_fit_{key}", "gauge", help_text,
                           [("", float("nan") if fit[key] is None else float(fit[key]))])
    out += _metric("graytrack_uptime_seconds", "gauge", "seconds since start", [("", status["uptime_s"])])
    return "\n".join(out) + "\n"
