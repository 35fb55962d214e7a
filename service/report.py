"""Writing the closed loop's report: ``report.json``, ``report.html`` with plots, ``model.json``.

The HTML is one self-contained file (plots embedded as PNG data), because it is read on rigs
without network access and mailed around as it is.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graytrack.core.diagnosis.loop import DiagnosisResult, Stage  # noqa: E402
from graytrack.core.files import write_atomic  # noqa: E402
from graytrack.core.models import save_model  # noqa: E402
from graytrack.core.pixel_noise import PixelNoise  # noqa: E402
from graytrack.core.transients import summary_line  # noqa: E402
from graytrack.service.figures import MISSING, is_number, positive, shown  # noqa: E402


def _png(figure: plt.Figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    plt.close(figure)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _residual_map(stage: Stage) -> tuple[np.ndarray, np.ndarray]:
    """Held-out residual (row mean) ordered by position: rows of the image are frames."""
    order = np.argsort(stage.val.data.x_mm)
    return stage.val.residual.mean(axis=1)[order], stage.val.data.x_mm[order]


def residual_maps(result: DiagnosisResult) -> str:
    """Fig. 3b/4b of the paper: residual over position × pixel, before and after."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    before, x = _residual_map(result.before)
    limit = float(np.percentile(np.abs(before), 99)) or 1.0
    for ax, stage, title in zip(axes, (result.before, result.after), ("before (seed paper's model)", "after the loop")):
        image, x = _residual_map(stage)
        shown = ax.imshow(image, aspect="auto", cmap="coolwarm", vmin=-limit, vmax=limit, origin="lower",
                          extent=(0, image.shape[1], x[0], x[-1]), interpolation="nearest")
        ax.set_xlabel("pixel u")
        ax.set_title(f"residual, {title}")
    axes[0].set_ylabel("position (mm)")
    fig.colorbar(shown, ax=axes, label="gray")
    return _png(fig)


def residual_spread(result: DiagnosisResult) -> str:
    """Fig. 3c/4c: the residual's spread per pixel, before and after, against the noise."""
    fig, ax = plt.subplots(figsize=(11, 3.2))
    for stage, label in ((result.before, "before"), (result.after, "after")):
        ax.plot(stage.val.residual.std(axis=(0, 1)), label=label)
    ax.axhline(result.sigma_gray, color="k", ls="--", lw=1, label=f"noise σ = {shown(result.sigma_gray, 3)}")
    ax.set_xlabel("pixel u")
    ax.set_ylabel("residual std (gray)")
    ax.set_yscale("log")
    ax.legend()
    return _png(fig)


def error_plot(result: DiagnosisResult) -> str:
    """Fig. 5: displacement error against the grating, before and after, with the noise floor."""
    fig, axes = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True)
    for ax, stage, title in zip(axes, (result.before, result.after), ("before", "after")):
        figs = stage.figures
        ax.plot(figs.x_mm, figs.error_um, ".", ms=2)
        ax.fill_between(np.sort(figs.x_mm), -figs.crlb_um, figs.crlb_um, color="0.8", label="±1 CRLB")
        ax.set_ylabel("error (µm)")
        ax.set_title(f"{title}: std {shown(figs.error_std_um, 3, 'µm')}, noise floor {shown(figs.crlb_um, 3, 'µm')}"
                     f"{_lost(figs.error_um)}", fontsize=10)
        ax.legend(loc="upper right")
    axes[-1].set_xlabel("grating position (mm)")
    return _png(fig)


def _lost(error_um: np.ndarray) -> str:
    lost = int((~np.isfinite(error_um)).sum())
    return f" ({lost} of {error_um.size} frames not placed)" if lost else ""


def _cell(text: str) -> str:
    return f"<td>{html.escape(text)}</td>"


def _rows(report: dict) -> str:
    cells = []
    for step in report["steps"] + report["rejected"]:
        cells.append("<tr>" + "".join(_cell(str(step.get(key, ""))) for key in ("effect", "family", "evidence"))
                     + _cell(shown(step.get("rmse_gray"), 4)) + _cell(shown(step.get("error_std_um"), 3))
                     + _cell(str(step.get("decision", ""))) + "</tr>")
    return "\n".join(cells) or "<tr><td colspan=6>nothing added: the residual holds no structure beyond noise</td></tr>"


def _findings(report: dict) -> str:
    """What the data showed beyond model terms: pixels set aside, and the noise model behind the bound."""
    bad = report.get("findings", {}).get("bad_pixels") or []
    items = "".join(f"<li>row {shown(item.get('row'), 0)}, pixel {shown(item.get('pixel'), 0)}: "
                    f"{html.escape(str(item.get('reason', '')))}</li>" for item in bad)
    pixels = (f"<p>{len(bad)} pixel(s) set aside (masked in model.json):</p><ul>{items}</ul>" if bad
              else "<p>No pixel set aside: every pixel sees the target as the others do.</p>")
    curve = report["noise"].get("pixel_noise") or {}
    fields = PixelNoise.__dataclass_fields__
    if curve.get("signal_dependent") and all(key in curve and curve[key] is not None for key in fields):
        model = PixelNoise(**{key: curve[key] for key in fields})
        sigmas = ", ".join(f"{shown(model.sigma(level), 3)} at {level:g}" for level in (32.0, 128.0, 224.0))
        noise = (f"<p>Noise grows with the signal (photon transfer): σ²(y) = {shown(curve['read_var'], 4)} + "
                 f"{shown(curve['quant_var'], 4)} + {shown(curve['shot_gain'], 5)}·(y − {shown(curve['dark_gray'], 1)}) "
                 f"gray²; σ = {sigmas} gray. Calibration and tracking weight each sample by 1/σ²(y), and the bound "
                 "uses it.</p>")
    else:
        noise = f"<p>Noise is one σ = {shown(report['noise'].get('gray'), 3)} gray for every gray level.</p>"
    chi2 = curve.get("calibration_chi2")
    level = (f"<p>Calibration χ² per sample: {shown(chi2, 3)} (1 when the model and the noise model hold).</p>"
             if chi2 is not None else "")
    transients = _transients(report.get("findings", {}).get("transients"))
    return f"<h2>Pixels and noise</h2>{pixels}{transients}{noise}{level}{_compression(report)}"


def _compression(report: dict) -> str:
    """A JPEG stream's quantisation limits what the frames hold: said next to the bound it lowers."""
    found = (report.get("findings") or {}).get("compression")
    if not found:
        return ""
    return (f"<p>The frames come from a JPEG (MJPEG) stream at quality ≈ {shown(found.get('quality'), 0)}: the "
            f"quantisation of its 8×8 blocks is an error the model cannot know; with it the bound on the held-out "
            f"frames is {shown(found.get('crlb_um'), 3, 'µm')}, not the {shown(report['noise'].get('crlb_um'), 3, 'µm')} "
            "of the sensor's noise alone. Stream uncompressed frames (a raw pixel format) to reach the latter.</p>")


def _missing_note(*entries: dict) -> str:
    """Why a figure reads "—": said once, only when one does."""
    keys = ("rmse_gray", "error_std_um", "error_max_um", "error_mean_um")
    if all(is_number(entry.get(key)) for entry in entries for key in keys):
        return ""
    return (f"<p>{MISSING}: no such figure (a model that places none of the held-out frames has no error; "
            "one frame it cannot place leaves the maximum unbounded).</p>")


def geometry_banner(report: dict) -> str:
    """The rig's geometry, said before any figure: a refusal (nothing below is a usable model) or
    the likely causes of a doubt (core/geometry_check.py)."""
    check = report.get("geometry") or {}
    if check.get("status") == "refused":
        return (f'<p class="big" style="color:#a00"><b>Refused: {html.escape(str(check.get("message")))}</b>. '
                "The loop stopped: the figures below are those of the seed paper's model on these images, "
                "and no model.json was written.</p>")
    if check.get("status") == "doubtful":
        items = "".join(f"<li>{html.escape(str(text))}</li>" for text in check.get("warnings") or [])
        return f'<p style="color:#a60"><b>Geometry doubtful:</b></p><ul>{items}</ul>'
    return ""


def _transients(found: dict | None) -> str:
    """Transients (glints, passing dust) set aside sample by sample: how many, in which frames, where."""
    if not found or not is_number(found.get("count")) or not found.get("count"):
        return "<p>No transient found (glint, reflection, passing dust).</p>"
    items = "".join(f"<li>frames {e['frames'][0]}–{e['frames'][1]}, row {e['row']}, pixel {e['pixel']} "
                    f"(target {shown(e.get('x_mm'), 3, 'mm')}), peak {shown(e.get('peak_gray'), 0)} gray, {e['samples']} samples</li>"
                    for e in found.get("events", []))
    more = int(found["count"]) - len(found.get("events", []))
    tail = f"<li>and {more} more</li>" if more > 0 else ""
    sentence = summary_line(found)
    return f"<p>{html.escape(sentence[0].upper() + sentence[1:])}:</p><ul>{items}{tail}</ul>"


def render_html(result: DiagnosisResult, report: dict) -> str:
    before, after, noise = report["before"], report["after"], report["noise"]
    images = {"maps": residual_maps(result), "spread": residual_spread(result), "error": error_plot(result)}
    reference_line = (f"<p>The grating readout comes in steps of {shown(noise['reference_resolution_um'], 3, 'µm')}: "
                      f"against it no sensor can show less than {shown(noise.get('floor_um'), 3, 'µm')}.</p>"
                      if positive(noise.get("reference_resolution_um")) else "")
    remaining = "".join(f"<li>{html.escape(str(item.get('text')))} (z = {shown(item.get('z'), 1)})</li>"
                        for item in report["remaining_evidence"])

    def figures_row(label: str, entry: dict) -> str:
        return ("<tr>" + _cell(label) + _cell(str(entry.get("model", ""))) + _cell(shown(entry.get("rmse_gray"), 4))
                + "".join(_cell(shown(entry.get(key), 3)) for key in ("error_std_um", "error_max_um", "error_mean_um"))
                + _cell(shown(entry.get("lost_frames"), 0)) + "</tr>")

    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>graytrack diagnosis</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;width:100%}}td,th{{border:1px solid #ccc;padding:4px 6px;font-size:13px;vertical-align:top}}
th{{background:#f3f3f3}}.big{{font-size:20px}}</style></head><body>
<h1>graytrack closed loop</h1>
{geometry_banner(report)}
<p class="big">held-out error std <b>{shown(before.get('error_std_um'), 3, 'µm')}</b> → <b>{shown(after.get('error_std_um'), 3, 'µm')}</b>
(noise floor, Cramér–Rao: {shown(noise.get('crlb_um'), 3, 'µm')}; per-pixel noise σ = {shown(noise.get('gray'), 3, 'gray')})</p>
<table><tr><th></th><th>model</th><th>rmse (gray)</th><th>error std (µm)</th><th>error max (µm)</th><th>mean (µm)</th><th>frames not placed</th></tr>
{figures_row('before', before)}
{figures_row('after', after)}</table>
{_missing_note(before, after)}{reference_line}<p>Held out: {html.escape(str(report['heldout']))}. Final model (model.json): {html.escape(str(report['final_model']))}.</p>
{_findings(report)}
<h2>Effects tried, in order</h2>
<table><tr><th>effect</th><th>physical family</th><th>evidence in the residual</th><th>rmse</th><th>error std</th><th>decision</th></tr>
{_rows(report)}</table>
<h2>Residual over position and pixel</h2><img alt="residual maps" src="data:image/png;base64,{images['maps']}">
<h2>Residual spread per pixel</h2><img alt="residual spread" src="data:image/png;base64,{images['spread']}">
<h2>Displacement error against the grating</h2><img alt="error" src="data:image/png;base64,{images['error']}">
<h2>Structure still in the residual</h2><ul>{remaining or '<li>none beyond noise</li>'}</ul>
</body></html>
"""


def write_report(result: DiagnosisResult, folder: str | os.PathLike[str],
                 report: dict[str, Any] | None = None) -> dict[str, Path]:
    """report.json, report.html and model.json of a closed-loop run in ``folder``. ``report``: the
    report to write when the caller added to ``result.report()`` (the daemon's summary and held-out
    figures), so that the file is what the caller keeps, never read back."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    report = result.report() if report is None else report
    paths = {"json": folder / "report.json", "html": folder / "report.html", "model": folder / "model.json"}
    if result.refused:  # a model of a wrongly set-up rig is not written, and an older one not left to look current
        paths.pop("model").unlink(missing_ok=True)
    else:
        save_model(result.final_model, paths["model"])
    write_atomic(paths["json"], json.dumps(report, indent=1, allow_nan=False, default=float))
    write_atomic(paths["html"], render_html(result, report))
    return paths
