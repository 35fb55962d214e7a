"""``GET /metrics``: the daemon's counters and gauges in the Prometheus text format (v0.0.4).

Hand-written because the set is small and fixed, and the rig has no business pulling in a
client library for it (the tests parse it with ``prometheus_client``'s own parser). The rules
kept here, which docs/daemon.md lists family by family:

* base units in names and values: a position is ``_meters`` (the API's mm × 1e-3), a bound too;
* counters end in ``_total``; a rate is left to ``rate()`` over a counter (``graytrack_frames_total``),
  the ``graytrack_frame_rate_hertz`` gauge is the daemon's own windowed figure, for the status page's peers;
* every family has HELP and TYPE and is present in every scrape, whatever the state: a figure
  that does not exist now (no fresh frame, no fit) is NaN, never a missing line, and a labelled
  family has every label value from the first scrape (calibration outcomes, states, causes);
* label values and HELP text are escaped.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

from graytrack.core.validity import FAMILIES
from graytrack.service.daemon import status as status_doc
from graytrack.service.daemon.broadcast import Broadcaster
from graytrack.service.daemon.jobs import FINAL
from graytrack.service.daemon.limits import ConnectionLimits
from graytrack.service.daemon.snapshot import RigSnapshot

STATES = ("starting", "idle", "calibrating", "tracking", "fault", "stopping")
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
NAN = float("nan")

# the tracker's per-frame fit figures (status["fit"]): key, family, help
FIT_FAMILIES = (
    ("chi2", "graytrack_fit_chi2", "reduced chi-square of the newest frame's fit (NaN: no fresh fit)"),
    ("rejected_px", "graytrack_fit_rejected_pixels", "pixels the newest frame's fit rejected (NaN: no fresh fit)"),
    ("transient_px", "graytrack_fit_transient_pixels",
     "samples of the newest frame set aside as a transient, glint or dust (NaN: no fresh fit)"),
    ("focus_px2", "graytrack_fit_focus_square_pixels",
     "change of blur variance since calibration in square pixels (NaN: not estimated)"),
    ("stale", "graytrack_fit_stale", "1 when the tracker flags the model as stale: recalibrate (NaN: no fresh fit)"),
)

Sample = tuple[Mapping[str, str], float | int | bool | None]


def escape_label(value: str) -> str:
    """A label value as the text format wants it: backslash, double quote and newline escaped."""
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def escape_help(text: str) -> str:
    """HELP text escapes backslash and newline (a quote is literal there)."""
    return text.replace("\\", "\\\\").replace("\n", "\\n")


def number(value: float | int | bool | None) -> str:
    """A sample value: None and NaN are ``NaN``, infinities ``+Inf``/``-Inf``, anything else a float."""
    value = NAN if value is None else float(value)
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(value)


def family(name: str, kind: str, help_text: str, samples: Iterable[Sample]) -> list[str]:
    """One family's HELP, TYPE and sample lines; a counter's name must end in ``_total``."""
    if kind == "counter" and not name.endswith("_total"):
        raise ValueError(f"counter {name} must end in _total")
    lines = [f"# HELP {name} {escape_help(help_text)}", f"# TYPE {name} {kind}"]
    for labels, value in samples:
        text = ",".join(f'{key}="{escape_label(str(label))}"' for key, label in labels.items())
        lines.append(f"{name}{{{text}}} {number(value)}" if text else f"{name} {number(value)}")
    return lines


def gauge(name: str, help_text: str, value: float | int | bool | None) -> list[str]:
    return family(name, "gauge", help_text, [({}, value)])


def counter(name: str, help_text: str, value: float | int) -> list[str]:
    return family(name, "counter", help_text, [({}, value)])


def _scaled(value: float | None, factor: float) -> float:
    return NAN if value is None else value * factor


def render(snapshot: RigSnapshot, broadcaster: Broadcaster, limits: ConnectionLimits) -> str:
    """The scrape of one instant: the status document and the counters of the same snapshot."""
    status = status_doc.document(snapshot)
    loop, grating, devices = snapshot.frame_loop, snapshot.grating, snapshot.devices
    stats = loop.counters if loop is not None else None
    fit = status.get("fit") or {}
    out: list[str] = []
    out += family("graytrack_state", "gauge", "1 for the daemon's current state",
                  [({"state": s}, status["state"] == s) for s in STATES])
    out += gauge("graytrack_calibrated", "1 when a model is installed", status["calibrated"])
    out += gauge("graytrack_position_meters", "last tracked position (NaN when stale or not placed)",
                 _scaled(status["position_mm"], 1e-3))
    out += gauge("graytrack_crlb_meters", "Cramer-Rao bound of the last tracked frame (NaN when stale)",
                 _scaled(status["crlb_um"], 1e-6))
    out += gauge("graytrack_locked", "1 when the tracker is locked on the last tracked frame (NaN when stale)",
                 status["locked"])
    out += gauge("graytrack_frame_rate_hertz",
                 "frames per second since the last outage, over up to 200 frames (0 when stale); "
                 "Prometheus graphs rate(graytrack_frames_total)",
                 status["frame_rate_hz"])
    out += gauge("graytrack_stale", "1 when the newest tracked frame is older than stale_after_s", status["stale"])
    out += gauge("graytrack_healthy", "1 when frames are being tracked now (/healthz 200 unless the model is stale)",
                 snapshot.tracking_fresh)
    out += counter("graytrack_frames_total", "camera frames received", stats.frames if stats else 0)
    out += counter("graytrack_frames_tracked_total", "frames tracked", stats.tracked if stats else 0)
    out += counter("graytrack_frames_unplaced_total", "tracked frames that could not be placed",
                   stats.unplaced if stats else 0)
    out += counter("graytrack_lock_events_total", "lock losses and re-acquisitions", stats.lock_events if stats else 0)
    out += counter("graytrack_camera_dropped_frames_total", "frames the camera lost or skipped",
                   devices.camera_dropped if devices else 0)
    out += counter("graytrack_frames_dropped_total", "gaps in the camera's frame_id sequence (the stream's dropped)",
                   stats.dropped if stats else 0)
    out += counter("graytrack_tracking_errors_total", "frames the tracker raised on",
                   stats.tracking_errors if stats else 0)
    out += counter("graytrack_worker_crashes_total", "worker loops restarted after an exception",
                   (loop.crashes if loop else 0) + (grating.crashes if grating else 0))
    out += counter("graytrack_camera_errors_total", "camera errors other than timeouts",
                   stats.camera_errors if stats else 0)
    out += counter("graytrack_grating_reads_total", "POS? readings", grating.reads if grating else 0)
    out += counter("graytrack_grating_errors_total", "failed POS? readings", grating.errors if grating else 0)
    out += counter("graytrack_stage_reconnects_total", "serial port reopened",
                   devices.stage_reconnects if devices else 0)
    out += counter("graytrack_faults_total", "faults raised", snapshot.faults_raised)
    out += family("graytrack_calibrations_total", "counter",
                  "calibrations ended, by outcome (interrupted: found unfinished at start-up)",
                  [({"outcome": outcome}, snapshot.calibrations_finished.get(outcome, 0)) for outcome in FINAL])
    out += gauge("graytrack_websocket_clients", "connected /ws/position clients", broadcaster.clients)
    out += counter("graytrack_websocket_messages_total", "position messages sent", broadcaster.sent)
    out += counter("graytrack_websocket_dropped_total", "messages dropped for slow clients", broadcaster.dropped)
    out += family("graytrack_connections_refused_total", "counter",
                  "connections and requests the resource limits refused, by why: refused (503/1013 beyond "
                  "max_connections or max_connections_per_client), dropped (closed at once beyond twice either), "
                  "timed_out (408, request_timeout_s), oversized (431, or a WebSocket message closed 1009), "
                  "stalled (closed: its answers not read within request_timeout_s)",
                  [({"why": why}, value) for why, value in limits.counters().items()])
    out += counter("graytrack_requests_paced_total", "requests that waited for the request budget "
                   "(requests_per_s_per_client, requests_per_s, serving_share)", limits.paced)
    share = limits.budget.share
    if share is not None:
        out += counter("graytrack_serving_cpu_seconds_total", "CPU seconds spent serving clients (the event loop "
                       "and the request threads, the stream's deliveries apart): what serving_share bounds",
                       share.used_s)
        out += gauge("graytrack_serving_share", "the share of a core serving may take now: serving_share, cut "
                     "while the frame loop loses frames (the rig first) and grown back after", share.share)
        out += counter("graytrack_serving_share_cuts_total", "times a frame the rig lost cut serving's share",
                       share.cuts)
        out += gauge("graytrack_request_cpu_seconds", "the mean CPU of one request, from the last busy window "
                     "(what a waiting request is charged)", share.cost_s)
    out += family("graytrack_model_stale", "gauge",
                  "1 for the family of causes the model is stale for (all 0: it holds)",
                  [({"reason": cause}, status.get("stale_reason") == cause) for cause in FAMILIES])
    for key, name, help_text in FIT_FAMILIES:
        out += gauge(name, help_text, fit.get(key))
    out += gauge("graytrack_uptime_seconds", "seconds since start", status["uptime_s"])
    return "\n".join(out) + "\n"
