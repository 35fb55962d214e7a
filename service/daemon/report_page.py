"""``report.html`` of a daemon calibration (paper model): what the page's history opens.

A small static document (no script: the daemon's pages allow none), the figures a user acts on
first: the held-out error in µm next to its Cramér–Rao bound, then the fit in gray levels.
"""

from __future__ import annotations

import html
from typing import Any


def _row(label: str, value: Any) -> str:
    return f"<tr><th>{html.escape(label)}</th><td>{html.escape(str(value))}</td></tr>"


def render(calibration_id: str, report: dict[str, Any]) -> str:
    held = report.get("held_out") or {}
    quality = ("not measured (too few stops to hold half of them out)" if not held else
               f"{held['error_std_um']:.3f} µm (Cramér–Rao bound {held['bound_um']:.3f} µm; {held.get('method', '')})")
    rows = [
        _row("held-out error std", quality),
        _row("model", report.get("model", "")),
        _row("fit rms / noise", f"{report.get('rmse_gray', float('nan')):.3f} / {report.get('sigma_gray', float('nan')):.3f} gray"),
        _row("frames", report.get("frames", "")),
        _row("stroke", f"{report.get('stroke_mm', float('nan')):.3f} mm"),
        _row("period τ", f"{report.get('period_mm', float('nan')):.5f} mm"),
        _row("pixel pitch α·d", f"{report.get('pixel_pitch_mm', float('nan')):.6f} mm"),
        _row("iterations", report.get("iterations", "")),
    ]
    return ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>graytrack calibration {html.escape(calibration_id)}</title>"
            "<link rel=\"stylesheet\" href=\"/static/style.css\"></head><body><main class=\"report\">"
            f"<h1>Calibration {html.escape(calibration_id)}</h1>"
            f"<p class=\"big\">held-out error <b>{held.get('error_std_um', float('nan')):.2f} µm</b> "
            f"· bound {held.get('bound_um', float('nan')):.2f} µm</p>"
            f"<table>{''.join(rows)}</table>"
            "<p class=\"muted\">Files: <a href=\"report.json\">report.json</a> · <a href=\"model.json\">model.json</a>"
            " · <a href=\"recording.npz\">recording.npz</a> (a recording for <code>graytrack diagnose</code>)</p>"
            "</main></body></html>")
