"""``report.html`` of a daemon calibration (paper model): what the page's history opens.

A small static document (no script: the daemon's pages allow none), the figures a user acts on
first: the held-out error in µm next to its Cramér–Rao bound, then the fit in gray levels.
"""

from __future__ import annotations

import html
from typing import Any

from graytrack.core.transients import summary_line
from graytrack.service.figures import shown


def _row(label: str, value: Any) -> str:
    return f"<tr><th>{html.escape(label)}</th><td>{html.escape(str(value))}</td></tr>"


def _geometry(check: dict[str, Any]) -> str:
    """The geometry check's verdict (core/geometry_check.py): ok, or each doubt it found."""
    if check.get("status") == "doubtful":
        return "doubtful: " + "; ".join(check.get("warnings") or [check.get("message", "")])
    return str(check.get("status", "not checked"))


def render(calibration_id: str, report: dict[str, Any]) -> str:
    held = report.get("held_out") or {}
    quality = ("not measured (too few stops to hold half of them out)" if not held else
               f"{shown(held.get('error_std_um'), 3, 'µm')} (Cramér–Rao bound {shown(held.get('bound_um'), 3, 'µm')}; "
               f"{held.get('method', '')})")
    rows = [
        _row("held-out error std", quality),
        _row("model", report.get("model", "")),
        _row("fit rms / noise", f"{shown(report.get('rmse_gray'), 3)} / {shown(report.get('sigma_gray'), 3)} gray"),
        _row("frames", shown(report.get("frames"), 0)),
        _row("stroke", shown(report.get("stroke_mm"), 3, "mm")),
        _row("period τ", shown(report.get("period_mm"), 5, "mm")),
        _row("pixel pitch α·d", shown(report.get("pixel_pitch_mm"), 6, "mm")),
        _row("iterations", shown(report.get("iterations"), 0)),
        _row("geometry", _geometry(report.get("geometry") or {})),
        _row("transients", _transients(report.get("findings", {}).get("transients"))),
    ]
    return ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>graytrack calibration {html.escape(calibration_id)}</title>"
            "<link rel=\"stylesheet\" href=\"/static/style.css\"></head><body><main class=\"report\">"
            f"<h1>Calibration {html.escape(calibration_id)}</h1>"
            f"<p class=\"big\">held-out error <b>{shown(held.get('error_std_um'), 2, 'µm')}</b> "
            f"· bound {shown(held.get('bound_um'), 2, 'µm')}</p>"
            f"<table>{''.join(rows)}</table>"
            "<p class=\"muted\">Files: <a href=\"report.json\">report.json</a> · <a href=\"model.json\">model.json</a>"
            " · <a href=\"recording.npz\">recording.npz</a> (a recording for <code>graytrack diagnose</code>)</p>"
            "</main></body></html>")


def _transients(found: dict[str, Any] | None) -> str:
    """Glints and passing dust the calibration set aside, sample by sample (their pixels kept):
    the sentence the command line prints, so the page and the terminal say the same."""
    return summary_line(found).removeprefix("transients: ")
