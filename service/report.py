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

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graytrack.core.diagnosis.loop import DiagnosisResult, Stage  # noqa: E402
from graytrack.core.files import write_atomic  # noqa: E402
from graytrack.core.models import save_model  # noqa: E402
from graytrack.core.pixel_noise import PixelNoise  # noqa: E402


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
    ax.axhline(result.sigma_gray, color="k", ls="--", lw=1, label=f"noise σ = {result.sigma_gray:.3f}")
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
        ax.set_title(f"{title}: std {figs.error_std_um:.3f} µm, noise floor {figs.crlb_um:.3f} µm", fontsize=10)
        ax.legend(loc="upper right")
    axes[-1].set_xlabel("grating position (mm)")
    return _png(fig)


def _rows(report: dict) -> str:
    cells = []
    for step in report["steps"] + report["rejected"]:
        cells.append(
            "<tr>" + "".join(f"<td>{html.escape(str(step[key]))}</td>" for key in
                             ("effect", "family", "evidence", "rmse_gray", "error_std_um", "decision")) + "</tr>"
        )
    return "\n".join(cells) or "<tr><td colspan=6>nothing added: the residual holds no structure beyond noise</td></tr>"


def _findings(report: dict) -> str:
    """What the data showed beyond model terms: pixels set aside, and the noise model behind the bound."""
    bad = report.get("findings", {}).get("bad_pixels") or []
    items = "".join(f"<li>row {item['row']}, pixel {item['pixel']}: {html.escape(str(item['reason']))}</li>"
                    for item in bad)
    pixels = (f"<p>{len(bad)} pixel(s) set aside (masked in model.json):</p><ul>{items}</ul>" if bad
              else "<p>No pixel set aside: every pixel sees the target as the others do.</p>")
    curve = report["noise"].get("pixel_noise") or {}
    if curve.get("signal_dependent"):
        model = PixelNoise(**{key: curve[key] for key in PixelNoise.__dataclass_fields__})
        sigmas = ", ".join(f"{float(model.sigma(level)):.3f} at {level:g}" for level in (32.0, 128.0, 224.0))
        noise = (f"<p>Noise grows with the signal (photon transfer): σ²(y) = {curve['read_var']:.4f} + "
                 f"{curve['quant_var']:.4f} + {curve['shot_gain']:.5f}·(y − {curve['dark_gray']:.1f}) gray²; "
                 f"σ = {sigmas} gray. Calibration and tracking weight each sample by 1/σ²(y), and the bound uses it.</p>")
    else:
        noise = f"<p>Noise is one σ = {report['noise']['gray']:.3f} gray for every gray level.</p>"
    chi2 = curve.get("calibration_chi2")
    level = f"<p>Calibration χ² per sample: {chi2:.3f} (1 when the model and the noise model hold).</p>" if chi2 else ""
    return f"<h2>Pixels and noise</h2>{pixels}{noise}{level}"


def render_html(result: DiagnosisResult, report: dict) -> str:
    before, after, noise = report["before"], report["after"], report["noise"]
    images = {"maps": residual_maps(result), "spread": residual_spread(result), "error": error_plot(result)}
    reference_line = (f"<p>The grating readout comes in steps of {noise['reference_resolution_um']:.3f} µm: against it "
                      f"no sensor can show less than {noise['floor_um']:.3f} µm.</p>"
                      if noise.get("reference_resolution_um") else "")
    remaining = "".join(f"<li>{html.escape(item['text'])} (z = {item['z']})</li>" for item in report["remaining_evidence"])
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>graytrack diagnosis</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;width:100%}}td,th{{border:1px solid #ccc;padding:4px 6px;font-size:13px;vertical-align:top}}
th{{background:#f3f3f3}}.big{{font-size:20px}}</style></head><body>
<h1>graytrack closed loop</h1>
<p class="big">held-out error std <b>{before['error_std_um']:.3f} µm</b> → <b>{after['error_std_um']:.3f} µm</b>
(noise floor, Cramér–Rao: {noise['crlb_um']:.3f} µm; per-pixel noise σ = {noise['gray']:.3f} gray)</p>
<table><tr><th></th><th>model</th><th>rmse (gray)</th><th>error std (µm)</th><th>error max (µm)</th><th>mean (µm)</th></tr>
<tr><td>before</td><td>{html.escape(before['model'])}</td><td>{before['rmse_gray']}</td><td>{before['error_std_um']}</td><td>{before['error_max_um']}</td><td>{before['error_mean_um']}</td></tr>
<tr><td>after</td><td>{html.escape(after['model'])}</td><td>{after['rmse_gray']}</td><td>{after['error_std_um']}</td><td>{after['error_max_um']}</td><td>{after['error_mean_um']}</td></tr></table>
{reference_line}<p>Held out: {html.escape(report['heldout'])}. Final model (model.json): {html.escape(report['final_model'])}.</p>
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


def write_report(result: DiagnosisResult, folder: str | os.PathLike[str]) -> dict[str, Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    report = result.report()
    paths = {"json": folder / "report.json", "html": folder / "report.html", "model": folder / "model.json"}
    save_model(result.final_model, paths["model"])
    write_atomic(paths["json"], json.dumps(report, indent=1, allow_nan=False, default=float))
    write_atomic(paths["html"], render_html(result, report))
    return paths
