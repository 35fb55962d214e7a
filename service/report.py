"""``report.html`` of any calibration (the closed loop's, the seed paper's or the ideal model's),
with plots where a reader would rather look than read.

One renderer for every kind: the sections a report's keys call for (the loop's before, steps and
after; a plain fit's figures), all from the report ``service/calibration_run.py`` writes. The
HTML is one self-contained file (plots embedded as PNG data, no script), because it is read on
rigs without network access, served by the daemon's history and mailed around as it is.
"""

from __future__ import annotations

import html
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graytrack.core.diagnosis.loop import DiagnosisResult, LoopModel  # noqa: E402
from graytrack.core.pixel_noise import PixelNoise  # noqa: E402
from graytrack.core.transients import summary_line  # noqa: E402
from graytrack.service.figures import MISSING, is_number, positive, shown, structure  # noqa: E402
from graytrack.service.report_kit import cell, image, page, plain_log_axis, png, table  # noqa: E402

if TYPE_CHECKING:
    from graytrack.service.calibration_run import CalibrationRun


def _residual_map(stage: LoopModel) -> tuple[np.ndarray, np.ndarray]:
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
    return png(fig)


def residual_spread(result: DiagnosisResult) -> plt.Figure:
    """Fig. 3c/4c: the residual's spread per pixel, before and after, against the noise."""
    fig, ax = plt.subplots(figsize=(11, 3.2))
    for stage, label in ((result.before, "before"), (result.after, "after")):
        ax.plot(stage.val.residual.std(axis=(0, 1)), label=label)
    ax.axhline(result.sigma_gray, color="k", ls="--", lw=1, label=f"noise σ = {shown(result.sigma_gray, 3)}")
    ax.set_xlabel("pixel u")
    ax.set_ylabel("residual std (gray)")
    ax.set_yscale("log")
    plain_log_axis(ax.yaxis)
    ax.legend()
    return fig


# title, position (mm), error (µm), and the error std and bound (µm) as report.json states them
Panel = tuple[str, np.ndarray, np.ndarray, "float | None", "float | None"]


def error_figure(panels: list[Panel]) -> plt.Figure:
    """Fig. 5: position error against the grating on held-out frames, within ±1 bound. The panels
    share their y-scale (before and after side by side compare by eye only so), and their titles
    read the figures report.json states: the page says each number once, with one value."""
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 2.75 * len(panels) + 0.5), sharex=True, sharey=True,
                             squeeze=False)
    for ax, (title, x_mm, error_um, std_um, bound_um) in zip(axes[:, 0], panels):
        ax.plot(x_mm, error_um, ".", ms=2)
        if is_number(bound_um):
            ax.fill_between(np.sort(x_mm), -bound_um, bound_um, color="0.8", label="±1 bound")
            ax.legend(loc="upper right")
        ax.set_ylabel("error (µm)")
        ax.set_title(f"{title}: error std {shown(std_um, 3, 'µm')}, bound {shown(bound_um, 3, 'µm')}"
                     f"{_lost(error_um)}", fontsize=10)
    axes[-1, 0].set_xlabel("grating position (mm)")
    return fig


def _panels(run: "CalibrationRun") -> list[Panel]:
    report = run.report
    if run.diagnosis is not None:
        return [(title, stage.figures.x_mm, stage.figures.error_um, report[key].get("error_std_um"),
                 report[key].get("crlb_um"))
                for stage, title, key in ((run.diagnosis.before, "before (seed paper's model)", "before"),
                                          (run.diagnosis.after, "after the loop", "after"))]
    held, stated = run.held_out, report.get("held_out") or {}
    return [] if held is None else [("held out", held.x_mm, held.error_um, stated.get("error_std_um"),
                                     stated.get("bound_um"))]


def _lost(error_um: np.ndarray) -> str:
    lost = int((~np.isfinite(error_um)).sum())
    return f" ({lost} of {error_um.size} frames not placed)" if lost else ""


def _rows(report: dict) -> str:
    cells = []
    for step in report["steps"] + report["rejected"]:
        cells.append("<tr>" + "".join(cell(str(step.get(key, ""))) for key in ("effect", "family", "evidence"))
                     + cell(shown(step.get("rmse_gray"), 4)) + cell(shown(step.get("error_std_um"), 3))
                     + cell(str(step.get("decision", ""))) + "</tr>")
    return "\n".join(cells) or "<tr><td colspan=6>nothing added: the residual holds no structure beyond noise</td></tr>"


def _findings(report: dict) -> str:
    """What the data showed beyond model terms: pixels set aside, and the noise model behind the bound."""
    bad = report.get("findings", {}).get("bad_pixels") or []
    items = "".join(f"<li>row {shown(item.get('row'), 0)}, pixel {shown(item.get('pixel'), 0)}: "
                    f"{html.escape(str(item.get('reason', '')))}</li>" for item in bad)
    pixels = (f"<p>{len(bad)} pixel(s) set aside (masked in model.json):</p><ul>{items}</ul>" if bad
              else "<p>No pixel set aside: every pixel sees the target as the others do.</p>")
    curve = (report.get("noise") or {}).get("pixel_noise") or {}
    fields = PixelNoise.__dataclass_fields__
    if curve.get("signal_dependent") and all(key in curve and curve[key] is not None for key in fields):
        model = PixelNoise(**{key: curve[key] for key in fields})
        sigmas = ", ".join(f"{shown(model.sigma(level), 3)} at {level:g}" for level in (32.0, 128.0, 224.0))
        noise = (f"<p>Noise grows with the signal (photon transfer): σ²(y) = {shown(curve['read_var'], 4)} + "
                 f"{shown(curve['quant_var'], 4)} + {shown(curve['shot_gain'], 5)}·(y − "
                 f"{shown(curve['dark_gray'], 1)}) "
                 f"gray²; σ = {sigmas} gray. Calibration and tracking weight each sample by 1/σ²(y), and the bound "
                 "uses it.</p>")
    else:
        sigma = shown((report.get("noise") or {}).get("gray"), 3)
        noise = f"<p>Noise is one σ = {sigma} gray for every gray level.</p>"
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
            f"frames is {shown(found.get('crlb_um'), 3, 'µm')}, not the "
            f"{shown((report.get('noise') or {}).get('crlb_um'), 3, 'µm')} "
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
                    f"(target {shown(e.get('x_mm'), 3, 'mm')}), peak {shown(e.get('peak_gray'), 0)} gray, "
                    f"{e['samples']} samples</li>"
                    for e in found.get("events", []))
    more = int(found["count"]) - len(found.get("events", []))
    tail = f"<li>and {more} more</li>" if more > 0 else ""
    sentence = summary_line(found)
    return f"<p>{html.escape(sentence[0].upper() + sentence[1:])}:</p><ul>{items}{tail}</ul>"


def _figures_table(report: dict) -> str:
    """The loop's before and after; a plain fit's figures in gray levels and its geometry."""
    if "before" in report and "after" in report:
        def figures_row(label: str, entry: dict) -> str:
            return ("<tr>" + cell(label) + cell(structure(entry.get("model")))
                    + cell(shown(entry.get("rmse_gray"), 4))
                    + "".join(cell(shown(entry.get(key), 3))
                              for key in ("error_std_um", "crlb_um", "error_max_um", "error_mean_um"))
                    + cell(shown(entry.get("lost_frames"), 0)) + "</tr>")

        return ("<table><tr><th></th><th>model</th><th>rmse (gray)</th><th>error std (µm)</th><th>bound (µm)</th>"
                "<th>error max (µm)</th><th>mean (µm)</th><th>frames not placed</th></tr>"
                f"{figures_row('before', report['before'])}{figures_row('after', report['after'])}</table>"
                + _missing_note(report["before"], report["after"]))
    rows = [("model", structure(report.get("model"))),
            ("fit rms / noise", f"{shown(report.get('rmse_gray'), 3)} / {shown(report.get('sigma_gray'), 3)} gray"),
            ("frames", shown(report.get("frames"), 0)), ("stroke", shown(report.get("stroke_mm"), 3, "mm")),
            ("period τ", shown(report.get("period_mm"), 5, "mm")),
            ("pixel pitch α·d", shown(report.get("pixel_pitch_mm"), 6, "mm")),
            ("iterations", shown(report.get("iterations"), 0))]
    return ("<table>" + "".join(f"<tr><th>{html.escape(label)}</th>{cell(str(value))}</tr>" for label, value in rows)
            + "</table>")


def _headline(report: dict) -> str:
    """The figure a reader acts on first: the held-out error in µm next to its bound."""
    noise, held = report.get("noise") or {}, report.get("held_out") or {}
    sigma = f"; per-pixel noise σ = {shown(noise.get('gray'), 3, 'gray')}"
    if "before" in report and "after" in report:
        before, after = report["before"].get("error_std_um"), report["after"].get("error_std_um")
        return (f"<p class=\"big\">held-out error std <b>{shown(before, 3, 'µm')}</b> → "
                f"<b>{shown(after, 3, 'µm')}</b> (bound "
                f"{shown(noise.get('crlb_um'), 3, 'µm')}{sigma})</p>")
    if not held:
        return f"<p class=\"big\">held-out error: not measured (too few stops to hold half of them out){sigma}</p>"
    return (f"<p class=\"big\">held-out error std <b>{shown(held.get('error_std_um'), 3, 'µm')}</b> "
            f"(bound {shown(held.get('bound_um'), 3, 'µm')}; {html.escape(str(held.get('method')))}{sigma})</p>")


def bound_definition(report: dict) -> str:
    """What "bound" means on this page, said once; where the loop's models have bounds of their own,
    why they differ (a model that solves the light per frame spends information on it)."""
    text = ("<b>Bound</b>: the Cramér–Rao bound, the position error std that the pixel noise alone allows on "
            "the held-out frames (the rms of each frame's bound) for the model that tracks them; an error std "
            "at the bound is all a model can do.")
    before, after = (report.get("before") or {}).get("crlb_um"), (report.get("after") or {}).get("crlb_um")
    if is_number(before) and is_number(after) and shown(before, 3) != shown(after, 3):
        text += (f" Each model has its own: {shown(before, 3, 'µm')} for the seed paper's model, "
                 f"{shown(after, 3, 'µm')} for the final one" + (
                     ", whose gain and offset per frame cost information (solved, they are no longer known)"
                     if "per-frame gain/offset" in str(report.get("final_model")) else "")
                 + ". Each error is judged against its own model's bound.")
    return f'<p class="note">{text}</p>'


def _geometry_line(run: "CalibrationRun") -> str:
    """τ and α·d of the model written, once; for the loop, which model that is and how it relates to
    the figures above (the same structure, fitted without the held-out frames)."""
    if "heldout" not in run.report:  # a plain fit: its table states τ and α·d
        return ""
    model = run.model
    return (f"<p>Final model (model.json): {html.escape(structure(model.describe()))}, τ = {model.period_mm:.4f} mm, "
            f"α·d = {model.pixel_pitch_mm:.5f} mm, fitted on every calibration frame; the figures above are of the "
            f"same structure fitted without the held-out frames ({html.escape(str(run.report['heldout']))}).</p>")


def _injected(report: dict) -> str:
    """A simulated recording's effects, which no model was told about, beside what the loop found:
    the demo's point, stated where its result is."""
    recording = report.get("recording") or {}
    injected = recording.get("simulated_effects") or []
    if not injected:
        return ""
    items = "".join(f"<li>{html.escape(str(effect))}</li>" for effect in injected)
    added = ", ".join(str(step.get("effect", "")).replace("_", " ") for step in report.get("steps") or [])
    found = (f"<p>The loop added: {html.escape(added)}.</p>" if added
             else "<p>The loop added nothing.</p>" if "steps" in report else "")
    return (f"<h2>Recording</h2><p>Recorded on the virtual rig ({html.escape(str(recording.get('scenario', '')))} "
            "scenario) with these effects switched on; no model was told about them:</p>"
            f"<ul id=\"injected\">{items}</ul>{found}")


SEED_MODELS = {"ideal": "ideal sine", "paper": "seed paper's model"}


def _seed_table(report: dict) -> str:
    """The demo's comparison on the clean paper rig (``seed_table``, written by ``graytrack demo``):
    each plain model's figures, computed as the paper did, beside the paper's own; the same digits as
    the terminal's table."""
    seed = report.get("seed_table")
    if not seed:
        return ""
    rows = [(SEED_MODELS.get(row["kind"], row["kind"]), shown(row["rmse_gray"], 3), shown(row["period_mm"], 4),
             shown(row["error_mean_um"], 2), shown(row["error_std_um"], 3), shown(row["bound_um"], 3),
             shown(row["frames"] - row["placed"], 0),
             shown((row.get("paper") or {}).get("rmse_gray"), 3),
             f"{shown((row.get('paper') or {}).get('error_mean_um'), 2)} ± "
             f"{shown((row.get('paper') or {}).get('error_std_um'), 1)}") for row in seed["rows"]]
    header = ("model", "rmse (gray)", "period (mm)", "error mean (µm)", "error std (µm)", "bound (µm)",
              "frames not placed", "paper: rmse (gray)", "paper: error (µm)")
    return (f"<h2>The seed paper's rig: ideal sine and the paper's model</h2><p>Recorded on the virtual rig "
            f"({html.escape(str(seed.get('scenario')))} scenario, seed {html.escape(str(seed.get('seed')))}, no "
            f"effects): {shown(seed.get('calibration_frames'), 0)} calibration and "
            f"{shown(seed.get('measured_frames'), 0)} held-out frames; {html.escape(str(seed.get('protocol')))}. "
            "The bound is the rms of the held-out frames' bounds for each model.</p>"
            + table(header, rows).replace("<table>", '<table id="seed-table">', 1))


TITLES = {"auto": "graytrack closed loop", "paper": "graytrack calibration: seed paper's model",
          "ideal": "graytrack calibration: ideal sine"}


def render_html(run: "CalibrationRun", name: str = "") -> str:
    """The report page of a calibration: every section its report has the keys for. ``name``: the
    calibration's id, in the title (the daemon's history opens many)."""
    report = run.report
    noise = report.get("noise") or {}
    images = {"error": png(error_figure(panels))} if (panels := _panels(run)) else {}
    if run.diagnosis is not None:
        images = {"maps": residual_maps(run.diagnosis), "spread": png(residual_spread(run.diagnosis)), **images}
    reference_line = (f"<p>The grating readout comes in steps of {shown(noise['reference_resolution_um'], 3, 'µm')}: "
                      "measured against it, no error std can fall below the <b>readout floor</b> √(bound² + "
                      f"step²/12) = {shown(noise.get('floor_um'), 3, 'µm')}.</p>"
                      if positive(noise.get("reference_resolution_um")) else "")
    steps = ("<h2>Effects tried, in order</h2><table><tr><th>effect</th><th>physical family</th><th>evidence in the "
             f"residual</th><th>rmse</th><th>error std</th><th>decision</th></tr>{_rows(report)}</table>"
             if "steps" in report else "")
    plots = "".join(image(title, images[key]) for key, title in (("maps", "Residual over position and pixel"),
                                                                  ("spread", "Residual spread per pixel"),
                                                                  ("error", "Displacement error against the grating"))
                    if key in images)
    remaining = ""
    if "remaining_evidence" in report:
        items = "".join(f"<li>{html.escape(str(item.get('text')))} (z = {shown(item.get('z'), 1)})</li>"
                        for item in report["remaining_evidence"])
        remaining = f"<h2>Structure still in the residual</h2><ul>{items or '<li>none beyond noise</li>'}</ul>"
    title = TITLES.get(run.kind, "graytrack calibration") + (f" — {name}" if name else "")
    return page(title, f"""{geometry_banner(report)}
{_headline(report)}
{_figures_table(report)}
{bound_definition(report)}
{reference_line}{_geometry_line(run)}
{_seed_table(report)}
{_injected(report)}
{_findings(report)}
{steps}
{plots}
{remaining}
<p class="note">Files: <a href="report.json">report.json</a> · <a href="model.json">model.json</a></p>""")
